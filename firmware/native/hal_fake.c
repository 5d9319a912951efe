/* hal_fake.c - firmware/hal/hal.h for the native tests: a clock the test advances, a step
 * generator that moves at its commanded rate within its bounds, UART buffers. */
#include "hal_fake.h"

#include <string.h>

#include "../board/board.h"
#include "../hal/hal.h"

fake_hal_t F;

void fake_reset(void)
{
    memset(&F, 0, sizeof F);
    F.period_us = 1000;
    F.next_tick_us = 1000;
    F.tx_cap = sizeof F.tx;
}

void fake_rx(const uint8_t *data, unsigned n)
{
    if (F.rx_pos == F.rx_len) {
        F.rx_pos = F.rx_len = 0;
    }
    memcpy(F.rx + F.rx_len, data, n);
    for (unsigned i = 0; i < n; i++) {
        F.rx_at_us[F.rx_len + i] = (uint32_t)F.now_us - F.clock_lag_us; /* hal_time_us */
    }
    F.rx_len += n;
}

static void step_for(uint32_t us)
{
    int32_t r = F.rate;
    F.phase_us += (int64_t)(r < 0 ? -r : r) * us;
    while (F.phase_us >= 1000000) {
        F.phase_us -= 1000000;
        if (r > 0 && F.steps < F.hi) {
            F.steps++;
        } else if (r < 0 && F.steps > F.lo) {
            F.steps--;
        }
    }
}

void fake_run_us(uint32_t us)
{
    uint64_t end = F.now_us + us;
    while (F.now_us + (uint32_t)(F.next_tick_us - (uint32_t)F.now_us) <= end) {
        uint32_t to_tick = F.next_tick_us - (uint32_t)F.now_us;
        step_for(to_tick);
        F.now_us += to_tick;
        if (!F.tick_locked) {
            uint32_t t = F.next_tick_us;
            F.next_tick_us += F.period_us;
            board_tick(t);
        }
    }
    step_for((uint32_t)(end - F.now_us));
    F.now_us = end;
}

uint8_t hal_health(void)
{
    uint8_t health = F.health;
    F.health = 0;
    return health;
}

uint32_t hal_time_us(void)
{
    return (uint32_t)F.now_us - F.clock_lag_us;
}

uint64_t hal_time_us64(void)
{
    return F.now_us - F.clock_lag_us;
}

void hal_tick_set_period_us(uint16_t period_us)
{
    F.period_us = period_us;
}

void hal_tick_lock(void)
{
    F.tick_locked++;
}

void hal_tick_unlock(void)
{
    F.tick_locked--;
}

int16_t hal_uart_getc(void)
{
    if (F.rx_pos >= F.rx_len) {
        return -1;
    }
    if (F.rx[F.rx_pos] == 0) {
        F.delimiter_us = F.rx_at_us[F.rx_pos];
    }
    return F.rx[F.rx_pos++];
}

uint32_t hal_uart_delimiter_us(void)
{
    return F.delimiter_us;
}

uint16_t hal_uart_rx_frames_lost(void)
{
    return F.rx_frames_lost;
}

uint16_t hal_uart_tx_free(void)
{
    unsigned free_bytes = F.tx_cap > F.tx_len ? F.tx_cap - F.tx_len : 0;
    return (uint16_t)(free_bytes > 0xFFFF ? 0xFFFF : free_bytes);
}

bool hal_uart_write(const uint8_t *data, uint16_t n)
{
    if (n > hal_uart_tx_free()) {
        return false;
    }
    memcpy(F.tx + F.tx_len, data, n);
    F.tx_len += n;
    return true;
}

void hal_set_torch(bool on)
{
    F.torch = on;
}

void hal_set_ohmic_enable(bool on)
{
    F.ohmic = on;
}

uint16_t hal_inputs(void)
{
    return F.inputs;
}

uint16_t hal_arc_raw(void)
{
    return F.arc_raw;
}

uint16_t hal_xy_speed_dmm_s(void)
{
    return F.xy_speed_dmm_s;
}

void hal_set_current_da(uint16_t current_da)
{
    F.current_da = current_da;
}

void hal_z_drive(int32_t rate_steps_s, int32_t lo_steps, int32_t hi_steps)
{
    F.rate = rate_steps_s;
    F.lo = lo_steps;
    F.hi = hi_steps;
}

int32_t hal_z_steps(void)
{
    return F.steps;
}

uint32_t hal_entropy32(void)
{
    return 0x12345678u;
}
