/*
 * hal.h - the hardware layer the portable board logic (firmware/board/) runs on.
 *
 * A port to another MCU (AVR today: firmware/avr/hal_avr.c; a native fake for the unit
 * tests: firmware/native/hal_fake.c; an RP2040 later) implements exactly these functions
 * and calls the board's three entry points (firmware/board/board.h):
 *   board_init()  once at start, before interrupts run the tick;
 *   board_tick()  from the sample timer interrupt, once per sample period, with the
 *                 scheduled time of that tick (never re-entered; other interrupts may
 *                 preempt it);
 *   board_poll()  from the main loop, as often as it can.
 *
 * Contexts: the tick runs in interrupt context; everything else the board does runs in
 * the main loop, which masks the tick (hal_tick_lock) whenever it touches state the tick
 * uses. The UART, step and ADC interrupts live below this interface only.
 */
#ifndef DTHC_HAL_H
#define DTHC_HAL_H

#include <stdbool.h>
#include <stdint.h>

/* --- time ------------------------------------------------------------------------------ */

/* The free-running microsecond clock, live: low 32 bits, and all 64. */
uint32_t hal_time_us(void);
uint64_t hal_time_us64(void);

/* --- the sample tick ------------------------------------------------------------------- */

/* Period of board_tick from the next tick on (the board calls it with the tick locked).
 * The ticks stay on an exact grid: tick n+1 is scheduled period_us after tick n. */
void hal_tick_set_period_us(uint16_t period_us);
/* Mask / unmask the tick, not the other interrupts: the main loop's critical section.
 * A tick that fell due while masked runs at unlock (late, with its scheduled time). */
void hal_tick_lock(void);
void hal_tick_unlock(void);

/* --- UART (ring buffers filled and drained by interrupts) ------------------------------- */

/* The next received byte, or -1 when none is waiting. */
int16_t hal_uart_getc(void);
/* When the last 0x00 that hal_uart_getc returned arrived (taken in the receive interrupt).
 * A frame is valid from its delimiter's arrival, so the host lease runs from there, not
 * from when the main loop got round to decoding it (up to a millisecond later). */
uint32_t hal_uart_delimiter_us(void);
/* Frames the receiver lost whole before the board saw a byte of them (a full receive
 * buffer), so that the board can count them with its framing errors: every bad frame is
 * counted once. 0 for a port that never loses one. */
uint16_t hal_uart_rx_frames_lost(void);
/* Free bytes in the transmit ring. */
uint16_t hal_uart_tx_free(void);
/* Queue n bytes for transmission, all or nothing; false (nothing queued) when they do not
 * fit. Callable from the tick and from the main loop with the tick locked. */
bool hal_uart_write(const uint8_t *data, uint16_t n);

/* --- outputs and inputs ----------------------------------------------------------------- */

void hal_set_torch(bool on);
void hal_set_ohmic_enable(bool on);
/* Self-checks the hardware layer failed since the previous call (HAL_HEALTH_* bits, cleared
 * by the call, read once per tick): the board latches INTERNAL, detail the lowest one's
 * DTHC_INTERNAL_* code (bit n is code n + 1). */
#define HAL_HEALTH_TICK_OVERRUN 0x01u  /* the tick fell behind by HAL_TICK_OVERRUN_PERIODS */
#define HAL_HEALTH_ADC_INCOMPLETE 0x02u /* no conversion completed in a sample period */
#define HAL_HEALTH_LOOP_STALL 0x04u     /* the watchdog went unkicked past half its timeout */
uint8_t hal_health(void);
/* The input snapshot now, in protocol bit order (PROTOCOL.md section 7), active = 1. */
uint16_t hal_inputs(void);
/* Arc voltage in centivolts by the front end's nominal scaling (the board calibrates it),
 * averaged over the conversions since the previous call. */
uint16_t hal_arc_raw(void);
/* The XY path speed of the table in 0.1 mm/s (SAMPLES.xy_speed_dmm_s), read once per
 * batch; called only when the build has capability XY_SPEED (a port without a speed input
 * returns DTHC_XY_SPEED_UNKNOWN, 0xFFFF). */
uint16_t hal_xy_speed_dmm_s(void);
/* The cutter's current set point in 0.1 A (SET_CURRENT), called only by a build with
 * BOARD_CURRENT_OUT=1 and capability CURRENT_OUT (no AVR build has an output for it). */
void hal_set_current_da(uint16_t current_da);

/* --- Z step generator ------------------------------------------------------------------- */

/* Step at |rate| steps/s, up when rate > 0, never below lo or above hi (positions in steps
 * from the boot position). rate 0 stops stepping at once. */
void hal_z_drive(int32_t rate_steps_s, int32_t lo_steps, int32_t hi_steps);
/* Steps emitted so far, signed, relative to the boot position. */
int32_t hal_z_steps(void);

/* --- misc ------------------------------------------------------------------------------- */

/* 32 bits that differ from one start to the next (noise, uninitialised RAM, counters). */
uint32_t hal_entropy32(void);

#endif /* DTHC_HAL_H */
