/* hal_fake.h - a fake hardware layer for the native unit tests of the board logic. */
#ifndef DTHC_HAL_FAKE_H
#define DTHC_HAL_FAKE_H

#include <stdbool.h>
#include <stdint.h>

typedef struct {
    uint64_t now_us;       /* the clock hal_time_us reads (less clock_lag_us) and ticks run on */
    uint32_t clock_lag_us; /* hal_time_us behind the tick schedule (a lost timer overflow) */
    uint32_t next_tick_us; /* the scheduled time of the next tick */
    uint16_t period_us;
    int tick_locked;
    uint16_t inputs;        /* what hal_inputs returns (protocol order, active = 1) */
    uint8_t health;         /* what hal_health returns (HAL_HEALTH_* bits), then cleared */
    uint16_t arc_raw;       /* what hal_arc_raw returns */
    uint16_t xy_speed_dmm_s; /* what hal_xy_speed_dmm_s returns */
    uint16_t current_da;    /* the last hal_set_current_da */
    bool torch;
    bool ohmic;
    int32_t steps;          /* the step generator's position */
    int32_t rate;           /* its commanded rate, steps/s */
    int32_t lo, hi;
    int64_t phase_us;       /* fractional steps, in step-microseconds */
    uint8_t rx[4096];
    uint32_t rx_at_us[4096]; /* when each queued byte arrived */
    unsigned rx_len, rx_pos;
    uint32_t delimiter_us;   /* arrival of the last 0x00 hal_uart_getc returned */
    uint16_t rx_frames_lost; /* what hal_uart_rx_frames_lost returns */
    uint8_t tx[65536];
    unsigned tx_len;
    unsigned tx_cap;        /* ring space the fake pretends to have */
} fake_hal_t;

extern fake_hal_t F;

void fake_reset(void);
/* Queue host bytes for hal_uart_getc. */
void fake_rx(const uint8_t *data, unsigned n);
/* Advance the clock by us: step the generator and run every tick that falls due. */
void fake_run_us(uint32_t us);

#endif /* DTHC_HAL_FAKE_H */
