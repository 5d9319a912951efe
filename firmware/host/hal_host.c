/*
 * hal_host.c - firmware/hal/hal.h over state a host process fills in, so the very board
 * logic of firmware/board/ runs as a shared library (build/host/libdthc_board.so) inside
 * the mock device (mock_device/cboard.py), over its Python plant (STYLE 23: one board
 * logic, built for the MCU and as a library for the mock).
 *
 * No callbacks: once per sample period the host calls host_advance() (the step generator
 * runs for one period), steps its plant, writes the plant's inputs, arc voltage and XY
 * speed into host_hal_t, calls host_tick() (board_tick, then the main loop) and reads back the outputs (torch, ohmic enable, current,
 * the Z step count) and what the board sent (tx). Host bytes go in through host_rx(), which
 * runs the main loop at once (a reply does not wait for the next tick). The clock is board
 * time: it advances by one period per host_tick, as the sample timer would.
 *
 * The board logic keeps its state in globals (as on the MCU): one board per loaded copy of
 * the library (the host loads a private copy per board).
 */
#include <string.h>

#include "../board/board.h"
#include "../board/board_internal.h"
#include "../hal/hal.h"

#define HOST_RX_CAP 8192
#define HOST_TX_CAP 16384

typedef struct {
    /* the host writes these before each host_tick */
    uint16_t inputs;         /* protocol bit order, active = 1 */
    uint16_t arc_raw;        /* centivolts */
    uint16_t xy_speed_dmm_s; /* 0.1 mm/s */
    /* the board's outputs, read by the host */
    uint8_t torch;
    uint8_t ohmic;
    uint16_t current_da;
    int32_t steps;   /* the step generator's position, steps from the boot position */
    int32_t rate;    /* its commanded rate, steps/s, positive up */
    int32_t lo, hi;  /* its bounds */
    /* the clock: board time, one period per host_tick */
    uint64_t now_us;
    uint16_t period_us;
    /* what the board sent since the host last emptied it (tx_len = 0) */
    uint32_t tx_len;
    uint8_t tx[HOST_TX_CAP];
} host_hal_t;

/* A snapshot of the board's state for the host (its STATUS and what a test asserts). */
typedef struct {
    uint32_t boot_id;
    uint32_t last_rx_us;
    uint32_t event_counter;
    uint32_t crc_errors;
    uint32_t framing_errors;
    uint16_t faults;
    uint16_t inputs;
    uint16_t lease_ms;
    uint16_t zvel_seq;
    uint16_t rx_duplicates;
    uint16_t sample_seq;
    uint16_t period_us;
    uint8_t batch_size;
    uint8_t session;
    uint8_t lease; /* 0 running, 1 lapsed at rest, 2 expired (latched) */
    uint8_t zvel_applied;
    uint8_t status; /* the STATUS status byte */
    uint8_t torch;
    uint8_t ohmic;
} host_state_t;

static host_hal_t H;
static board_config_t config;
static char serial[17];
static uint8_t rx[HOST_RX_CAP];
static uint32_t rx_len, rx_pos;
static int64_t phase_us;
static int tick_locked;
static uint32_t delimiter_us;
static uint32_t entropy;

/* --- the host's entry points -------------------------------------------------------------- */

host_hal_t *host_hal(void)
{
    return &H;
}

/* Power-on: every byte of state cleared, then board_init with this configuration. */
void host_init(const char *serial_number, uint32_t capabilities, int32_t z_min_um,
               int32_t z_max_um, int32_t z_boot_um, int32_t z_max_speed_um_s,
               int32_t z_accel_um_s2, uint16_t z_steps_per_mm, uint8_t reset_reason,
               int32_t z_home_um, uint32_t entropy32)
{
    memset(&H, 0, sizeof H);
    rx_len = rx_pos = 0;
    phase_us = 0;
    tick_locked = 0;
    delimiter_us = 0;
    strncpy(serial, serial_number, sizeof serial - 1);
    serial[sizeof serial - 1] = 0;
    config.serial = serial;
    config.capabilities = capabilities;
    config.z_min_um = z_min_um;
    config.z_max_um = z_max_um;
    config.z_boot_um = z_boot_um;
    config.z_max_speed_um_s = z_max_speed_um_s;
    config.z_accel_um_s2 = z_accel_um_s2;
    config.z_steps_per_mm = z_steps_per_mm;
    config.reset_reason = reset_reason;
#if BOARD_HOMING
    config.z_home_um = z_home_um;
#else
    (void)z_home_um;
#endif
    entropy = entropy32;
    board_init(&config, entropy32);
}

static void run_main_loop(void)
{
    while (board_poll()) {
    }
}

/* Host bytes arriving now (between two ticks): queued, then the main loop handles them.
 * Returns how many were taken (all, unless the receive buffer is full). */
uint32_t host_rx(const uint8_t *data, uint32_t n)
{
    if (rx_pos == rx_len) {
        rx_pos = rx_len = 0;
    }
    if (n > HOST_RX_CAP - rx_len) {
        n = HOST_RX_CAP - rx_len;
    }
    memcpy(rx + rx_len, data, n);
    rx_len += n;
    run_main_loop();
    return n;
}

/* One sample period passes: the step generator steps at its rate within its bounds and the
 * clock reaches the next tick's time. The host then updates its plant (Z from H.steps) and
 * the inputs, and calls host_tick. */
void host_advance(void)
{
    uint32_t period = H.period_us;
    int32_t r = H.rate;
    phase_us += (int64_t)(r < 0 ? -r : r) * period;
    while (phase_us >= 1000000) {
        phase_us -= 1000000;
        if (r > 0 && H.steps < H.hi) {
            H.steps++;
        } else if (r < 0 && H.steps > H.lo) {
            H.steps--;
        }
    }
    H.now_us += period;
}

/* The sample tick at the clock's time, then the main loop (it queues a completed batch). */
void host_tick(void)
{
    board_tick((uint32_t)H.now_us);
    run_main_loop();
}

void host_state(host_state_t *s)
{
    s->boot_id = B.boot_id;
    s->last_rx_us = B.last_rx_us;
    s->event_counter = B.event_counter;
    s->crc_errors = board_rx.crc_errors;
    s->framing_errors = board_rx.framing_errors;
    s->faults = B.faults;
    s->inputs = B.inputs;
    s->lease_ms = B.lease_ms;
    s->zvel_seq = B.zvel_seq;
    s->rx_duplicates = B.rx_duplicates;
    s->sample_seq = B.sample_seq;
    s->period_us = B.period_us;
    s->batch_size = B.batch_size;
    s->session = B.session;
    s->lease = B.lease;
    s->zvel_applied = B.zvel_applied;
    s->status = board_status_bits();
    s->torch = B.torch;
    s->ohmic = B.ohmic;
}

/* --- hal.h ---------------------------------------------------------------------------------- */

uint32_t hal_time_us(void)
{
    return (uint32_t)H.now_us;
}

uint64_t hal_time_us64(void)
{
    return H.now_us;
}

void hal_tick_set_period_us(uint16_t period_us)
{
    H.period_us = period_us;
}

/* The host runs the tick and the main loop in one thread, never one inside the other: the
 * lock has nothing to mask. */
void hal_tick_lock(void)
{
    tick_locked++;
}

void hal_tick_unlock(void)
{
    tick_locked--;
}

int16_t hal_uart_getc(void)
{
    if (rx_pos >= rx_len) {
        return -1;
    }
    if (rx[rx_pos] == 0) {
        delimiter_us = (uint32_t)H.now_us; /* bytes arrive between ticks: at the last one */
    }
    return rx[rx_pos++];
}

uint32_t hal_uart_delimiter_us(void)
{
    return delimiter_us;
}

uint16_t hal_uart_rx_frames_lost(void)
{
    return 0; /* the mock hands every byte over */
}

/* The host empties tx after every call: it never fills, as a ring drained at line rate
 * between two ticks would not at the mock's rates. */
uint16_t hal_uart_tx_free(void)
{
    uint32_t free_bytes = HOST_TX_CAP - H.tx_len;
    return (uint16_t)(free_bytes > 0xFFFFu ? 0xFFFFu : free_bytes);
}

bool hal_uart_write(const uint8_t *data, uint16_t n)
{
    if (n > HOST_TX_CAP - H.tx_len) {
        return false;
    }
    memcpy(H.tx + H.tx_len, data, n);
    H.tx_len += n;
    return true;
}

void hal_set_torch(bool on)
{
    H.torch = on;
}

void hal_set_ohmic_enable(bool on)
{
    H.ohmic = on;
}

/* The mock's plant runs the board logic in lockstep: no tick can fall behind, no
 * conversion go missing, no watchdog starve. */
uint8_t hal_health(void)
{
    return 0;
}

uint16_t hal_inputs(void)
{
    return H.inputs;
}

uint16_t hal_arc_raw(void)
{
    return H.arc_raw;
}

uint16_t hal_xy_speed_dmm_s(void)
{
    return H.xy_speed_dmm_s;
}

void hal_set_current_da(uint16_t current_da)
{
    H.current_da = current_da;
}

void hal_z_drive(int32_t rate_steps_s, int32_t lo_steps, int32_t hi_steps)
{
    H.rate = rate_steps_s;
    H.lo = lo_steps;
    H.hi = hi_steps;
}

int32_t hal_z_steps(void)
{
    return H.steps;
}

uint32_t hal_entropy32(void)
{
    return entropy;
}
