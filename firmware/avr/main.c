/*
 * main.c - the AVR reference board: start, then the main loop (frames in, replies out),
 * the watchdog kicked from it, idle sleep when there is nothing to do. Everything the
 * safety of the table depends on runs in the sample tick (hal_avr.c -> board_tick).
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "../../firmware_protocol/c/dthc_protocol.h"
#include "../board/board.h"
#include "../hal/hal.h"
#include "hal_avr.h"
#include "pins.h"

#ifndef DTHC_SERIAL
#if defined(__AVR_ATmega328P__)
#define DTHC_SERIAL "DTHC-NANO-0001"
#else
#define DTHC_SERIAL "DTHC-MEGA-0001"
#endif
#endif

#define CAPS_COMMON                                                                          \
    (DTHC_CAP_OHMIC | DTHC_CAP_FLOAT | DTHC_CAP_BREAKAWAY | DTHC_CAP_ESTOP | DTHC_CAP_FILTERS)
#if DTHC_HAS_THC_UPDOWN
#define CAPS_THC DTHC_CAP_THC_UPDOWN
#else
#define CAPS_THC 0
#endif
#if DTHC_HAS_Z_LIMIT_INPUTS && BOARD_HOMING
#define CAPS_LIMITS (DTHC_CAP_Z_LIMITS | DTHC_CAP_HOMING) /* the home switch is Z_LIMIT_MAX */
#elif DTHC_HAS_Z_LIMIT_INPUTS
#define CAPS_LIMITS DTHC_CAP_Z_LIMITS
#else
#define CAPS_LIMITS 0
#endif

/* MCUSR, read and cleared before anything else (a watchdog reset leaves the watchdog on). */
static uint8_t mcusr_at_start __attribute__((section(".noinit")));
static uint32_t start_magic __attribute__((section(".noinit")));
#define START_MAGIC 0xD7C0B007UL

void early_reset_cause(void) __attribute__((naked, used, section(".init3")));
void early_reset_cause(void)
{
    mcusr_at_start = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

static uint8_t reset_reason(void)
{
    uint8_t r = mcusr_at_start;
    uint8_t warm = start_magic == START_MAGIC; /* RAM survived: not a power cycle */
    start_magic = START_MAGIC;
    if (r & _BV(PORF)) {
        return DTHC_RESET_POWER_ON;
    }
    if (r & _BV(WDRF)) {
        return DTHC_RESET_WATCHDOG;
    }
    if (r & _BV(BORF)) {
        return DTHC_RESET_BROWNOUT;
    }
    if (r & _BV(EXTRF)) {
        return DTHC_RESET_EXTERNAL;
    }
    /* No flag: a jump to the reset vector (software) if RAM survived, else a first start
     * without flags (an emulator). */
    return warm ? DTHC_RESET_SOFTWARE : DTHC_RESET_POWER_ON;
}

static board_config_t config = {
    DTHC_SERIAL,
    CAPS_COMMON | CAPS_THC | CAPS_LIMITS,
    DTHC_Z_MIN_UM,
    DTHC_Z_MAX_UM,
    DTHC_Z_BOOT_UM,
    DTHC_Z_MAX_SPEED_UM_S,
    DTHC_Z_ACCEL_UM_S2,
    DTHC_Z_STEPS_PER_MM,
    0,
#if BOARD_HOMING
    DTHC_Z_HOME_UM,
#endif
};

int main(void)
{
    hal_init(); /* outputs off first */
    config.reset_reason = reset_reason();
    board_init(&config, hal_entropy32());
    wdt_enable(WDTO_120MS);
    hal_start();
    sei();
    for (;;) {
        hal_watchdog_kick();
        if (board_poll()) {
            continue;
        }
        /* Nothing received: sleep until an interrupt (the tick wakes us every period).
         * Never poll the UART status register: simavr sleeps on an idle one. */
        cli();
        if (!hal_uart_rx_pending()) {
            set_sleep_mode(SLEEP_MODE_IDLE);
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
