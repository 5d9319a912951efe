/*
 * arc_vtof_calc.h - the voltage-to-frequency front end's arithmetic, free of any AVR
 * header so the native tests (firmware/native/test_arc_vtof.c) run the very code the
 * firmware runs (arc_vtof.c).
 *
 * A THCAD-type card turns its input (the arc voltage divided by DTHC_ARC_DIVIDER) into a
 * frequency: DTHC_VTOF_ZERO_HZ at 0 V, DTHC_VTOF_FULL_HZ at DTHC_VTOF_FULL_MV. Timer5 counts
 * its rising edges; each sample tick takes the counts since the previous tick.
 *
 * Integers only, and no division in the tick: vtof_set_period() (main loop, the tick
 * locked) precomputes, for the sample period P, the zero-volt counts per period, the
 * centivolts per count as a multiplier, and 1/P. The tick (vtof_convert) then:
 *   counts  = (uint16_t)(tcnt - tcnt_prev)        one 16-bit wrap between ticks is harmless
 *   e       = dt - P                               how late (or early) this tick read
 *   norm    = counts - f_prev * e                  the counts over exactly P: the tick's own
 *                                                  jitter (a masked tick runs late) moved
 *                                                  no counts into or out of this sample
 *                                                  (f_prev: the previous tick's frequency;
 *                                                  over 4 periods late, counts * P / dt)
 *   cv      = (norm - zero) * K >> 16              clamped to [0, full scale]
 * Counts are kept with 4 fractional bits (q4), the multiplier K with 12 (q12). The AVR has
 * no barrel shifter: the long shifts are by 16 (a register move), not by 14 (a loop).
 */
#ifndef DTHC_ARC_VTOF_CALC_H
#define DTHC_ARC_VTOF_CALC_H

#include <stdint.h>

#ifndef DTHC_VTOF_ZERO_HZ
#define DTHC_VTOF_ZERO_HZ 121000UL /* the card's frequency at 0 V input (its label says) */
#endif
#ifndef DTHC_VTOF_FULL_HZ
#define DTHC_VTOF_FULL_HZ 925000UL /* ... at its full-scale input */
#endif
#ifndef DTHC_VTOF_FULL_MV
#define DTHC_VTOF_FULL_MV 10000UL /* the card's full-scale input (THCAD-10: 10 V) */
#endif
#ifndef DTHC_ARC_DIVIDER
#define DTHC_ARC_DIVIDER 50 /* arc volts per card-input volt (the cutter's 1:50 CNC port) */
#endif

#define VTOF_SPAN_HZ ((uint32_t)(DTHC_VTOF_FULL_HZ - DTHC_VTOF_ZERO_HZ))
/* Arc centivolts at the card's full scale (50000 = 500 V by default). */
#define VTOF_FULL_CV ((uint32_t)((uint32_t)DTHC_VTOF_FULL_MV * DTHC_ARC_DIVIDER / 10UL))
/* Centivolts per count at P = 1 us, q12: K(P) = VTOF_K_1US / P (computed at compile time). */
#define VTOF_K_1US ((uint32_t)((uint64_t)VTOF_FULL_CV * 4096ULL * 1000000ULL / VTOF_SPAN_HZ))
/* Counts per microsecond, q4 and scaled by 2^12: counts_q4(P) = P * VTOF_x_Q12 >> 12. */
#define VTOF_ZERO_Q12 ((uint32_t)(((uint64_t)DTHC_VTOF_ZERO_HZ * 65536ULL + 500000ULL) / 1000000ULL))
#define VTOF_SPAN_Q12 ((uint32_t)(((uint64_t)VTOF_SPAN_HZ * 65536ULL + 500000ULL) / 1000000ULL))
#define VTOF_MAX_PERIOD_US 10000UL /* the protocol's slowest rate, 100 Hz */

/* What the arithmetic assumes, checked at build time. */
typedef char vtof_span_positive[(DTHC_VTOF_FULL_HZ > DTHC_VTOF_ZERO_HZ) ? 1 : -1];
/* The AVR counts an external clock up to f_cpu / 2.5 (6.4 MHz at 16 MHz). */
typedef char vtof_freq_countable[(DTHC_VTOF_FULL_HZ <= 6000000UL) ? 1 : -1];
/* Full scale fits the 16-bit reading, and (norm - zero) * K below 2^32: full scale * 2^16. */
typedef char vtof_full_scale_fits[(VTOF_FULL_CV < 65536UL) ? 1 : -1];
/* K at 1 us fits 32 bits; P * the q12 rates fit 32 bits. */
typedef char vtof_k_fits[((uint64_t)VTOF_FULL_CV * 4096ULL * 1000000ULL / VTOF_SPAN_HZ
                          < 4294967296ULL) ? 1 : -1];
typedef char vtof_rate_fits[(VTOF_MAX_PERIOD_US * (VTOF_ZERO_Q12 + VTOF_SPAN_Q12)
                             < 2147483648ULL) ? 1 : -1];
/* A whole slowest period's counts, four times over, fit the 16-bit counter (a late tick). */
typedef char vtof_counter_fits[((uint64_t)DTHC_VTOF_FULL_HZ * VTOF_MAX_PERIOD_US * 4ULL
                                / 1000000ULL < 65536ULL) ? 1 : -1];

typedef struct {
    uint16_t period_us;  /* P */
    int32_t zero_q4;     /* counts per P at 0 V, q4 */
    int32_t span_q4;     /* counts per P from 0 V to full scale, q4 */
    uint32_t k_q12;      /* centivolts per count, q12 */
    uint32_t inv_p_q26;  /* 2^26 / P */
    int32_t prev_q4;     /* the previous tick's counts over P, q4 (the frequency now) */
    uint16_t tcnt_prev;  /* the counter at the previous tick */
    uint32_t t_prev_us;  /* and the time it was read */
} vtof_state_t;

/* x / 2^16 and x / 2^10 rounded towards 0, by shifts of constants (avr-gcc -Os calls a
 * 32-bit division for a signed "/ 1024"; a right shift of a negative value is
 * implementation-defined). */
static inline int32_t vtof_shr16(int32_t x)
{
    return x < 0 ? -(int32_t)((uint32_t)-x >> 16) : (int32_t)((uint32_t)x >> 16);
}

static inline int32_t vtof_shr10(int32_t x)
{
    return x < 0 ? -(int32_t)((uint32_t)-x >> 10) : (int32_t)((uint32_t)x >> 10);
}

/* For sample period period_us (the main loop, the tick locked: divisions allowed). The
 * frequency estimate carries over to the new period. */
static inline void vtof_set_period(vtof_state_t *s, uint16_t period_us)
{
    uint32_t p = period_us ? period_us : 1u;
    if (p > VTOF_MAX_PERIOD_US) {
        p = VTOF_MAX_PERIOD_US;
    }
    if (s->period_us) {
        s->prev_q4 = (int32_t)(((uint32_t)(s->prev_q4 > 0 ? s->prev_q4 : 0) * p
                                + s->period_us / 2u) / s->period_us);
    }
    s->period_us = (uint16_t)p;
    s->zero_q4 = (int32_t)((p * VTOF_ZERO_Q12 + 2048u) >> 12);
    s->span_q4 = (int32_t)((p * VTOF_SPAN_Q12 + 2048u) >> 12);
    s->k_q12 = (VTOF_K_1US + p / 2u) / p;
    s->inv_p_q26 = ((1UL << 26) + p / 2u) / p;
    if (s->prev_q4 <= 0) {
        s->prev_q4 = s->zero_q4; /* no reading yet: assume 0 V */
    }
}

/* The counter and the time at start (the counts from here on belong to the first tick). */
static inline void vtof_start(vtof_state_t *s, uint16_t tcnt, uint32_t t_us)
{
    s->tcnt_prev = tcnt;
    s->t_prev_us = t_us;
}

/* The tick: the counter and the time read together now -> arc centivolts. */
static inline uint16_t vtof_convert(vtof_state_t *s, uint16_t tcnt, uint32_t t_us)
{
    uint16_t counts = (uint16_t)(tcnt - s->tcnt_prev);
    int32_t p = (int32_t)s->period_us;
    int32_t e = (int32_t)(t_us - s->t_prev_us) - p;
    int32_t frac_q10;
    int32_t norm_q4;
    int32_t v_q4;
    s->tcnt_prev = tcnt;
    s->t_prev_us = t_us;
    if (e > 4 * p) {
        /* More than 4 periods late (rare: the first tick after CONFIGURE shortened the
         * period, or a long stall): the counts over dt scaled to P exactly; the only
         * divisions in the tick, in this path alone. Beyond 65535 counts (70 ms at 925 kHz)
         * the counter has wrapped more than once and the reading is low for one sample. */
        uint32_t dt = (uint32_t)(e + p);
        uint32_t q = (uint32_t)counts * (uint32_t)p;
        if (dt >= (1UL << 24)) {
            norm_q4 = s->prev_q4; /* over 16 s: nothing better to say */
        } else {
            norm_q4 = (int32_t)((q / dt) * 16u + ((q % dt) * 16u) / dt);
        }
    } else {
        if (e < -p) {
            e = -p;
        }
        /* e / P, q10: |e * 2^26 / P| <= 2^28. */
        frac_q10 = vtof_shr16(e * (int32_t)s->inv_p_q26);
        /* prev_q4 <= 2 full scales (2^19 at the slowest rate) times |frac| <= 2^12. */
        norm_q4 = (int32_t)counts * 16 - vtof_shr10(s->prev_q4 * frac_q10);
    }
    if (norm_q4 < 0) {
        s->prev_q4 = 0;
    } else if (norm_q4 > 2 * (s->zero_q4 + s->span_q4)) {
        s->prev_q4 = 2 * (s->zero_q4 + s->span_q4);
    } else {
        s->prev_q4 = norm_q4;
    }
    v_q4 = norm_q4 - s->zero_q4;
    if (v_q4 <= 0) {
        return 0;
    }
    if (v_q4 >= s->span_q4) {
        return (uint16_t)VTOF_FULL_CV;
    }
    return (uint16_t)(((uint32_t)v_q4 * s->k_q12 + 32768u) >> 16);
}

#endif /* DTHC_ARC_VTOF_CALC_H */
