/*
 * test_arc_vtof.c - native tests of the voltage-to-frequency front end's arithmetic
 * (firmware/avr/arc_vtof_calc.h, the code arc_vtof.c runs in the tick), with the default
 * card: 121 kHz at 0 V, 925 kHz at 10 V, 1:50 divider (500 V of arc at full scale).
 *
 *   test_arc_vtof            run every test
 *   test_arc_vtof NAME...    run the named tests
 *   test_arc_vtof --list     print the test names
 * Prints "ok NAME" or "FAIL NAME: why" per test; exits 1 if any failed.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../avr/arc_vtof_calc.h"

static char why[256];

#define CHECK(cond, ...)                                                                     \
    do {                                                                                     \
        if (!(cond)) {                                                                       \
            snprintf(why, sizeof why, __VA_ARGS__);                                          \
            return 0;                                                                        \
        }                                                                                    \
    } while (0)

/* A card at hz feeding the counter: the counter and the clock at each tick. */
typedef struct {
    double edges;  /* exact edges since the start (fractional) */
    uint16_t base; /* the counter's value at the start */
    uint32_t t_us;
} card_t;

static uint16_t card_advance(card_t *c, double hz, uint32_t us)
{
    c->edges += hz * (double)us / 1e6;
    c->t_us += us;
    return (uint16_t)(c->base + (uint32_t)floor(c->edges));
}

/* The card runs us at hz, then the tick reads the counter and the clock. */
static uint16_t tick(vtof_state_t *s, card_t *c, double hz, uint32_t us)
{
    uint16_t tcnt = card_advance(c, hz, us);
    return vtof_convert(s, tcnt, c->t_us);
}

static double hz_for_arc_v(double arc_v)
{
    return (double)DTHC_VTOF_ZERO_HZ
           + (double)VTOF_SPAN_HZ * (arc_v / DTHC_ARC_DIVIDER) / (DTHC_VTOF_FULL_MV / 1000.0);
}

static void setup(vtof_state_t *s, card_t *c, uint16_t period_us, uint16_t base)
{
    memset(s, 0, sizeof *s);
    memset(c, 0, sizeof *c);
    c->base = base;
    c->t_us = 1000000u;
    vtof_set_period(s, period_us);
    vtof_start(s, base, c->t_us);
}

/* Exact counts per 1 ms tick: 0 V, 250 V (mid scale) and 500 V (full scale). */
static int scale_points_are_exact(void)
{
    static const struct {
        uint16_t counts;
        uint16_t cv;
    } points[] = {{121, 0}, {523, 25000}, {925, 50000}, {322, 12500}};
    for (unsigned i = 0; i < sizeof points / sizeof points[0]; i++) {
        vtof_state_t s;
        card_t c;
        setup(&s, &c, 1000, 0);
        uint16_t cv = vtof_convert(&s, points[i].counts, c.t_us + 1000u);
        CHECK(cv == points[i].cv, "%u counts/ms -> %u cV, expected %u", points[i].counts, cv,
              points[i].cv);
    }
    return 1;
}

/* One count is 500 V / 804 = 0.622 V at 1 kHz. */
static int one_count_is_the_stated_resolution(void)
{
    vtof_state_t s;
    card_t c;
    setup(&s, &c, 1000, 0);
    uint16_t a = vtof_convert(&s, 400, 1001000u);
    uint16_t b = vtof_convert(&s, 801, 1002000u);
    CHECK(b - a == 62 || b - a == 63, "one count = %d cV, expected 62.2", b - a);
    return 1;
}

/* Below 0 V (a dead card: no edges) reads 0; above full scale clamps at 500 V. */
static int out_of_range_clamps(void)
{
    vtof_state_t s;
    card_t c;
    setup(&s, &c, 1000, 0);
    CHECK(vtof_convert(&s, 0, 1001000u) == 0, "no edges -> 0 V");
    CHECK(vtof_convert(&s, 100, 1002000u) == 0, "below zero-volt frequency -> 0 V");
    CHECK(vtof_convert(&s, 1100, 1003000u) == 50000, "above full scale -> 500 V");
    return 1;
}

/* The counter wraps between two ticks: the counts are still right. */
static int a_16_bit_wrap_between_ticks_is_harmless(void)
{
    vtof_state_t s;
    card_t c;
    int wrapped = 0;
    setup(&s, &c, 1000, 65000);
    for (int i = 0; i < 3; i++) {
        uint16_t before = s.tcnt_prev;
        uint16_t cv = tick(&s, &c, 523000.0, 1000);
        wrapped |= s.tcnt_prev < before;
        CHECK(cv == 25000, "tick %d (counter %u -> %u): %u cV, expected 25000", i, before,
              s.tcnt_prev, cv);
    }
    CHECK(wrapped, "the counter did not wrap");
    return 1;
}

/* A steady arc at a voltage between counts: each sample within a count, the mean exact. */
static int a_steady_fractional_frequency_averages_exactly(void)
{
    vtof_state_t s;
    card_t c;
    setup(&s, &c, 1000, 12345);
    double v = 116.0, sum = 0;
    int n = 2000;
    for (int i = 0; i < n; i++) {
        uint16_t cv = tick(&s, &c, hz_for_arc_v(v), 1000);
        if (i >= 2) {
            CHECK(fabs(cv / 100.0 - v) <= 0.63, "sample %d: %.2f V, expected %.2f within a count",
                  i, cv / 100.0, v);
        }
        sum += cv / 100.0;
    }
    CHECK(fabs(sum / n - v) < 0.05, "mean %.3f V, expected %.2f", sum / n, v);
    return 1;
}

/* A tick run 300 us late (the main loop held it masked) and the next one on time: the counts
 * the late tick gathered over 1.3 ms are scaled back to one period, not read as 30 % more
 * volts, and the next tick (0.7 ms of counts) is not read low. */
static int a_late_tick_does_not_move_volts_between_samples(void)
{
    vtof_state_t s;
    card_t c;
    setup(&s, &c, 1000, 0);
    double hz = hz_for_arc_v(250.0);
    for (int i = 0; i < 5; i++) {
        (void)tick(&s, &c, hz, 1000);
    }
    uint16_t late = tick(&s, &c, hz, 1300);
    uint16_t next = tick(&s, &c, hz, 700);
    uint16_t very_late = tick(&s, &c, hz, 3900);
    uint16_t after = tick(&s, &c, hz, 100);
    CHECK(abs((int)late - 25000) <= 70, "late tick: %u cV, expected 25000", late);
    CHECK(abs((int)next - 25000) <= 70, "the tick after: %u cV, expected 25000", next);
    /* The correction extrapolates the previous sample's frequency, itself within a count:
     * 2.9 periods of it can be 3 counts off. */
    CHECK(abs((int)very_late - 25000) <= 190, "3 periods late: %u cV", very_late);
    CHECK(abs((int)after - 25000) <= 200, "100 us after it: %u cV", after);
    uint16_t stalled = tick(&s, &c, hz, 20000); /* 19 periods late: counts * P / dt */
    CHECK(abs((int)stalled - 25000) <= 10, "20 periods late: %u cV", stalled);
    return 1;
}

/* A voltage step: the sample that straddles it reads between, the next one the new value. */
static int a_step_shows_within_two_samples(void)
{
    vtof_state_t s;
    card_t c;
    setup(&s, &c, 1000, 0);
    for (int i = 0; i < 5; i++) {
        (void)tick(&s, &c, hz_for_arc_v(116.0), 1000);
    }
    (void)tick(&s, &c, hz_for_arc_v(123.5), 1000);
    uint16_t cv = tick(&s, &c, hz_for_arc_v(123.5), 1000);
    CHECK(fabs(cv / 100.0 - 123.5) <= 0.63, "%.2f V after the step, expected 123.5", cv / 100.0);
    return 1;
}

/* Other sample rates (CONFIGURE): 100 Hz gives 10x the counts per sample; the rate change
 * itself (a tick still on the old period) reads right. */
static int other_sample_periods_scale(void)
{
    vtof_state_t s;
    card_t c;
    setup(&s, &c, 10000, 500);
    uint16_t cv = tick(&s, &c, 523000.0, 10000);
    CHECK(abs((int)cv - 25000) <= 1, "100 Hz: %u cV, expected 25000", cv);
    cv = tick(&s, &c, hz_for_arc_v(116.0), 10000);
    CHECK(abs((int)cv - 11600) <= 7, "100 Hz, 116 V: %u cV (a count is 6.2 cV)", cv);
    vtof_set_period(&s, 1000); /* the tick already scheduled keeps the old 10 ms */
    cv = tick(&s, &c, hz_for_arc_v(116.0), 10000);
    CHECK(abs((int)cv - 11600) <= 70, "the tick after the change: %u cV", cv);
    cv = tick(&s, &c, hz_for_arc_v(116.0), 1000);
    CHECK(abs((int)cv - 11600) <= 70, "1 kHz again: %u cV", cv);
    return 1;
}

typedef struct {
    const char *name;
    int (*fn)(void);
} test_t;

#define T(name) {#name, name}
static const test_t TESTS[] = {
    T(scale_points_are_exact),
    T(one_count_is_the_stated_resolution),
    T(out_of_range_clamps),
    T(a_16_bit_wrap_between_ticks_is_harmless),
    T(a_steady_fractional_frequency_averages_exactly),
    T(a_late_tick_does_not_move_volts_between_samples),
    T(a_step_shows_within_two_samples),
    T(other_sample_periods_scale),
};
#define N_TESTS (sizeof TESTS / sizeof TESTS[0])

static int run(unsigned i)
{
    why[0] = 0;
    if (TESTS[i].fn()) {
        printf("ok %s\n", TESTS[i].name);
        return 0;
    }
    printf("FAIL %s: %s\n", TESTS[i].name, why);
    return 1;
}

int main(int argc, char **argv)
{
    int failed = 0;
    unsigned i;
    if (argc > 1 && strcmp(argv[1], "--list") == 0) {
        for (i = 0; i < N_TESTS; i++) {
            printf("%s\n", TESTS[i].name);
        }
        return 0;
    }
    if (argc == 1) {
        for (i = 0; i < N_TESTS; i++) {
            failed |= run(i);
        }
        return failed;
    }
    for (int a = 1; a < argc; a++) {
        for (i = 0; i < N_TESTS && strcmp(TESTS[i].name, argv[a]) != 0; i++) {
        }
        if (i == N_TESTS) {
            printf("FAIL %s: no such test\n", argv[a]);
            failed = 1;
            continue;
        }
        failed |= run(i);
    }
    return failed;
}
