/*
 * pins.h - the pin map of the reference firmware, per MCU.
 *
 * One table shared by the AVR hardware layer (hal_avr.c) and the emulated-board harness
 * (firmware/emulator/), so the harness drives exactly the pins the firmware reads.
 * A pin is a port letter and a bit: PIN_x_PORT is a bare letter (A, B, C, ...), so the
 * hardware layer can paste it into a register name (PORTC, DDRC, PINC) and the harness
 * can turn it into a character ('C') for simavr's AVR_IOCTL_IOPORT_GETIRQ.
 *
 * Electrical conventions (the table builder's page, firmware/README.md, shows the wiring):
 *   inputs   active LOW: an optocoupler's transistor pulls the pin to GND when the signal
 *            is active; the MCU's internal pull-up holds it HIGH otherwise (open = inactive).
 *   outputs  active HIGH: torch relay driver, ohmic-sense enable relay, Z enable is LOW
 *            (most stepper drivers' ENA- input enables the driver when pulled low).
 *   Z        STEP pulses on a rising edge; DIR HIGH = up (Z increasing).
 *   arc      ADC channel PIN_ARC_ADC, AVcc (5 V) reference, 10 bits; the arc voltage
 *            reaches it divided by DTHC_ARC_DIVIDER (the plasma cutter's CNC port, 1:50 by
 *            default) through an isolation amplifier of gain 1. Or, in the Mega's
 *            DTHC_ARC_VTOF build (make -C firmware: build/atmega2560-vtof), the output of
 *            an isolated voltage-to-frequency card (THCAD type) on PIN_ARC_VTOF, Timer5's
 *            clock input T5, counted on its rising edges (firmware/avr/arc_vtof.c). The
 *            Nano has no such option: its T1 pin (PD5, D5) is the OHMIC input.
 */
#ifndef DTHC_PINS_H
#define DTHC_PINS_H

#if defined(__AVR_ATmega2560__) || defined(DTHC_PINS_ATMEGA2560)
/* Arduino Mega 2560. Inputs on PORTA (digital 22..29) in protocol bit order. */
#define PIN_ARC_OK_PORT A
#define PIN_ARC_OK_BIT 0 /* D22 */
#define PIN_OHMIC_PORT A
#define PIN_OHMIC_BIT 1 /* D23 */
#define PIN_FLOAT_PORT A
#define PIN_FLOAT_BIT 2 /* D24 */
#define PIN_BREAKAWAY_PORT A
#define PIN_BREAKAWAY_BIT 3 /* D25 */
#define PIN_THC_UP_PORT A
#define PIN_THC_UP_BIT 4 /* D26 */
#define PIN_THC_DOWN_PORT A
#define PIN_THC_DOWN_BIT 5 /* D27 */
#define PIN_ESTOP_PORT A
#define PIN_ESTOP_BIT 6 /* D28 */
#define PIN_Z_LIMIT_MIN_PORT A
#define PIN_Z_LIMIT_MIN_BIT 7 /* D29 */
#define PIN_Z_LIMIT_MAX_PORT C
#define PIN_Z_LIMIT_MAX_BIT 7 /* D30 */
/* Outputs on PORTC (digital 37..34). */
#define PIN_STEP_PORT C
#define PIN_STEP_BIT 0 /* D37 */
#define PIN_DIR_PORT C
#define PIN_DIR_BIT 1 /* D36 */
#define PIN_TORCH_PORT C
#define PIN_TORCH_BIT 2 /* D35 */
#define PIN_OHMIC_ENABLE_PORT C
#define PIN_OHMIC_ENABLE_BIT 3 /* D34 */
#define PIN_Z_ENABLE_PORT C
#define PIN_Z_ENABLE_BIT 4 /* D33 */
#define PIN_ARC_ADC 0 /* A0 */
#define PIN_ARC_VTOF_PORT L
#define PIN_ARC_VTOF_BIT 2 /* D47, T5: a V-to-F card's output (the DTHC_ARC_VTOF build) */
#define DTHC_HAS_THC_UPDOWN 1
#define DTHC_HAS_Z_LIMIT_INPUTS 1

#elif defined(__AVR_ATmega328P__) || defined(DTHC_PINS_ATMEGA328P)
/* Arduino Nano / Uno (reduced build: no THC up/down or Z limit switch inputs). */
#define PIN_ARC_OK_PORT D
#define PIN_ARC_OK_BIT 4 /* D4 */
#define PIN_OHMIC_PORT D
#define PIN_OHMIC_BIT 5 /* D5 */
#define PIN_FLOAT_PORT D
#define PIN_FLOAT_BIT 6 /* D6 */
#define PIN_BREAKAWAY_PORT D
#define PIN_BREAKAWAY_BIT 7 /* D7 */
#define PIN_ESTOP_PORT B
#define PIN_ESTOP_BIT 0 /* D8 */
#define PIN_STEP_PORT D
#define PIN_STEP_BIT 2 /* D2 */
#define PIN_DIR_PORT D
#define PIN_DIR_BIT 3 /* D3 */
#define PIN_TORCH_PORT B
#define PIN_TORCH_BIT 1 /* D9 */
#define PIN_OHMIC_ENABLE_PORT B
#define PIN_OHMIC_ENABLE_BIT 2 /* D10 */
#define PIN_Z_ENABLE_PORT B
#define PIN_Z_ENABLE_BIT 3 /* D11 */
#define PIN_ARC_ADC 0 /* A0 */
#define DTHC_HAS_THC_UPDOWN 0
#define DTHC_HAS_Z_LIMIT_INPUTS 0
#if defined(DTHC_ARC_VTOF) && DTHC_ARC_VTOF
#error "pins.h: the Nano build has no V-to-F arc input (its T1 pin, PD5, is the OHMIC input)"
#endif

#else
#error "pins.h: no pin map for this MCU (atmega2560 and atmega328p are mapped)"
#endif

/* Front end and axis (both builds; overridable with -D at build time). */
#ifndef DTHC_ARC_DIVIDER
#define DTHC_ARC_DIVIDER 50 /* arc volts per ADC-input volt (the cutter's 1:50 CNC port) */
#endif
#ifndef DTHC_ADC_REF_MV
#define DTHC_ADC_REF_MV 5000
#endif
#ifndef DTHC_Z_STEPS_PER_MM
#define DTHC_Z_STEPS_PER_MM 200 /* 5 um per step: a 5 mm lead screw at 200 steps/rev */
#endif
#ifndef DTHC_Z_MIN_UM
#define DTHC_Z_MIN_UM 0
#endif
#ifndef DTHC_Z_MAX_UM
#define DTHC_Z_MAX_UM 100000
#endif
#ifndef DTHC_Z_BOOT_UM
#define DTHC_Z_BOOT_UM 60000 /* Z at power-on, until homed (unhomed: park it here) */
#endif
#ifndef DTHC_Z_HOME_UM
#define DTHC_Z_HOME_UM 102000 /* where the home switch (Z_LIMIT_MAX) trips: 2 mm above max */
#endif
#ifndef DTHC_Z_MAX_SPEED_UM_S
#define DTHC_Z_MAX_SPEED_UM_S 60000
#endif
#ifndef DTHC_Z_ACCEL_UM_S2
#define DTHC_Z_ACCEL_UM_S2 650000
#endif
#ifndef DTHC_UART_BAUD
#define DTHC_UART_BAUD 1000000UL
#endif

#endif /* DTHC_PINS_H */
