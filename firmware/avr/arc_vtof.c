/*
 * arc_vtof.c - the arc voltage front end of the DTHC_ARC_VTOF build (Mega 2560 only): an
 * isolated voltage-to-frequency card (THCAD type) drives T5 (PL2, D47); Timer5 counts its
 * rising edges, free-running, with no interrupt. Each sample tick reads the counter and
 * the microsecond clock together and turns the counts since the previous tick into arc
 * centivolts by the card's nominal scaling (arc_vtof_calc.h: integers, no division in the
 * tick; the host calibrates, as for the ADC).
 *
 * Resolution: the counts per sample, (full - zero) Hz / sample rate: 804 at 1 kHz with the
 * default card (121-925 kHz, 10 V, 1:50 divider), 0.62 V of arc per count (the daemon's
 * median and low-pass filters smooth the steps). The build refuses a BOARD_MAX_RATE_HZ at
 * which a sample would hold fewer than DTHC_VTOF_MIN_SPAN_COUNTS counts from 0 V to full
 * scale (500 by default, 1 V per count at 500 V): the Makefile caps this build at 1 kHz;
 * the ADC builds' 2 kHz would give 402 counts, 1.24 V per count.
 * A card that is missing or dead gives no edges: the board reports 0 V.
 */
#include <avr/io.h>
#include <util/atomic.h>

#include "../board/board.h"
#include "../hal/hal.h"
#include "arc_vtof.h"
#include "arc_vtof_calc.h"
#include "pins.h"

#if !defined(__AVR_ATmega2560__)
#error "arc_vtof.c: the V-to-F input is on the Mega 2560's T5 (the Nano's T1, PD5, is OHMIC)"
#endif

#ifndef PIN_ARC_VTOF_PORT
#error "pins.h: no PIN_ARC_VTOF for this MCU"
#endif
#ifndef DTHC_VTOF_MIN_SPAN_COUNTS
#define DTHC_VTOF_MIN_SPAN_COUNTS 500UL
#endif
typedef char vtof_enough_counts_per_sample[
    (VTOF_SPAN_HZ / BOARD_MAX_RATE_HZ >= DTHC_VTOF_MIN_SPAN_COUNTS) ? 1 : -1];

#define VTOF_CAT_(a, b) a##b
#define VTOF_CAT(a, b) VTOF_CAT_(a, b)

static vtof_state_t vtof;

void arc_vtof_init(void)
{
    /* The card's output: an input with the pull-up on (no card: no edges, 0 V). */
    VTOF_CAT(DDR, PIN_ARC_VTOF_PORT) &= (uint8_t)~_BV(PIN_ARC_VTOF_BIT);
    VTOF_CAT(PORT, PIN_ARC_VTOF_PORT) |= _BV(PIN_ARC_VTOF_BIT);
    TIMSK5 = 0;
    TCCR5A = 0;
    TCNT5 = 0;
    TCCR5B = _BV(CS52) | _BV(CS51) | _BV(CS50); /* normal mode, clock on T5's rising edge */
}

void arc_vtof_start(void)
{
    uint16_t c;
    uint32_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        c = TCNT5;
        t = hal_time_us();
    }
    vtof_start(&vtof, c, t);
}

/* Called with the tick locked (or before it runs): the divisions here keep the other
 * interrupts running. */
void arc_vtof_set_period_us(uint16_t period_us)
{
    vtof_set_period(&vtof, period_us);
}

/* The counts since the previous call, as arc centivolts over one sample period. */
uint16_t hal_arc_raw(void)
{
    uint16_t c;
    uint32_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        c = TCNT5;
        t = hal_time_us();
    }
    return vtof_convert(&vtof, c, t);
}
