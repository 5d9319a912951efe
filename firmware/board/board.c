/*
 * board.c - the sample tick (inputs, EVENTs, lease, faults, samples) and shared helpers.
 * Everything here that the tick calls runs in interrupt context on a real MCU: no float,
 * no waiting; a report that does not fit the transmit ring is dropped (and counted by the
 * host through its counter or stream_seq).
 */
#include "board_internal.h"

#include <string.h>

board_t B;
uint8_t board_small_tx[BOARD_SMALL_TX];
/* Two SAMPLES buffers: the tick fills one while the main loop encodes and queues the
 * other (board_flush_samples: kept out of the tick). */
static uint8_t samples_tx[2][BOARD_SAMPLES_TX];
static uint8_t samples_fill;                /* the buffer the tick fills */
static volatile uint8_t samples_ready_len;  /* payload bytes waiting in the other; 0: free */
static uint8_t samples_wire_len;            /* the waiting batch, encoded: its length */
typedef char samples_wire_fits[BOARD_SAMPLES_PAYLOAD + 6 <= 255 ? 1 : -1];
#define SAMPLES_AT (samples_tx[samples_fill] + DTHC_TX_PAYLOAD_OFFSET)

/* --- sending from the tick (or from the main loop with the tick locked) ---------------- */

void board_send_small(uint8_t type, uint8_t seq, uint8_t len)
{
    size_t n = dthc_encode_frame(type, seq, BOARD_SMALL_PAYLOAD_AT, len, board_small_tx,
                                 sizeof board_small_tx);
    (void)hal_uart_write(board_small_tx, (uint16_t)n);
}

/* --- sending from the main loop (tick unlocked) ---------------------------------------- */

/* Queue n encoded bytes whole, with the tick locked; false when the ring has no room for
 * them now (nothing queued: the caller tries again at a later poll, nothing waits). */
bool board_queue(const uint8_t *wire, size_t n)
{
    bool ok;
    hal_tick_lock();
    ok = hal_uart_write(wire, (uint16_t)n);
    hal_tick_unlock();
    return ok;
}

/* --- outputs ---------------------------------------------------------------------------- */

void board_set_torch(bool on)
{
    B.torch = on;
    hal_set_torch(on);
    B.arc_ok_seen = false; /* ARC_LOST needs arc OK seen since this switch-on */
    B.arc_off_timing = false;
}

void board_set_ohmic(bool on)
{
    B.ohmic = on;
    hal_set_ohmic_enable(on);
}

uint8_t board_status_bits(void)
{
    uint8_t s = 0;
    if (B.torch) {
        s |= DTHC_STATUS_TORCH_ON;
    }
    if (B.ohmic) {
        s |= DTHC_STATUS_OHMIC_SENSE;
    }
    if (B.faults) {
        s |= DTHC_STATUS_FAULT_LATCHED;
    }
    if (board_z_busy()) {
        s |= DTHC_STATUS_Z_BUSY;
    }
    if (B.sample_overflow) {
        s |= DTHC_STATUS_SAMPLE_OVERFLOW;
    }
    if (B.session) {
        s |= DTHC_STATUS_SESSION;
    }
#if BOARD_HOMING
    if (B.homed) {
        s |= DTHC_STATUS_HOMED;
    }
#endif
    return s;
}

uint8_t board_lowest_fault(void)
{
    uint8_t code = 0;
    while (code < 15 && !(B.faults & (1u << code))) {
        code++;
    }
    return code;
}

/* --- faults ----------------------------------------------------------------------------- */

static void send_fault_report(uint32_t counter, uint8_t code, uint8_t detail)
{
    uint8_t *p = BOARD_SMALL_PAYLOAD_AT;
    dthc_fault_put_counter(p, counter);
    dthc_fault_put_t_us(p, B.now_us);
    dthc_fault_put_code(p, code);
    dthc_fault_put_detail(p, detail);
    dthc_fault_put_faults(p, B.faults);
    dthc_fault_put_z_um(p, board_z_um());
    board_send_small(DTHC_MSG_FAULT, 0, DTHC_FAULT_SIZE);
}

static void send_fault(uint8_t code, uint8_t detail)
{
    B.last_fault_report_us = B.now_us;
    send_fault_report(B.fault_counter[code], code, detail);
}

/* Latch a fault (tick context): torch and ohmic sensing off, motion ended and Z
 * decelerated to a stop, FAULT sent with the next event counter. */
void board_latch(uint8_t code, uint8_t detail)
{
    if (B.faults & (1u << code)) {
        return;
    }
    B.faults = (uint16_t)(B.faults | (1u << code));
    if (B.torch) {
        board_set_torch(false);
    }
    if (B.ohmic) {
        board_set_ohmic(false);
    }
    board_z_end(DTHC_MOTION_FAULT, DTHC_PROBE_ABORTED);
    board_z_stop();
    B.event_counter++;
    B.fault_counter[code] = B.event_counter;
    B.fault_detail[code] = detail;
    send_fault(code, detail);
}

/* --- inputs and safety -------------------------------------------------------------------- */

static void read_inputs(void)
{
    uint16_t now = hal_inputs();
    uint16_t changed;
    uint8_t bit;
    if (!B.ohmic) {
        now = (uint16_t)(now & ~(1u << DTHC_INPUT_OHMIC)); /* contact only while sensing */
    }
    changed = (uint16_t)(now ^ B.inputs);
    B.inputs = now;
    for (bit = 0; changed; bit++, changed >>= 1) {
        uint8_t *p;
        if (!(changed & 1u)) {
            continue;
        }
        /* One EVENT per edge, raw: the host debounces. */
        p = BOARD_SMALL_PAYLOAD_AT;
        B.event_counter++;
        dthc_event_put_counter(p, B.event_counter);
        dthc_event_put_t_us(p, B.now_us);
        dthc_event_put_input(p, bit);
        dthc_event_put_level(p, (uint8_t)((now >> bit) & 1u));
        dthc_event_put_inputs(p, now);
        dthc_event_put_z_um(p, board_z_um());
        board_send_small(DTHC_MSG_EVENT, 0, DTHC_EVENT_SIZE);
    }
}

/* At rest (PROTOCOL.md section 4): nothing lit, nothing moving. Torch and ohmic sensing
 * off, and Z neither running a move, a probe or a velocity nor decelerating from one
 * (board_z_busy: the status byte's Z_BUSY). */
static bool board_at_rest(void)
{
#if BOARD_LEASE_IDLE_LAPSE
    return !B.torch && !B.ohmic && !board_z_busy();
#else
    return false; /* protocol 1.0: a lapse latches whatever the board is doing */
#endif
}

/* The lease ran out (tick context). In use: latched, outputs off, Z stopped, re-armed only
 * by FAULT_RESET. At rest: one FAULT LEASE_EXPIRED detail IDLE with the next event counter
 * and the fault set as it is, nothing latched; the next valid frame renews the lease
 * (renew_lease sets it running again, so a later lapse is reported again). Nothing can leave
 * the rest state while the host stays silent: only host frames switch the torch or ohmic
 * sensing on or start Z, and every valid frame renews the lease before it is executed. */
static void check_lease(void)
{
    /* Both ends of the lease on one clock, hal_time_us: the frame's arrival is stamped on
     * it, so "now" is read from it too, not from the tick's schedule. The two are kept by
     * different counters of one timer on the AVR (overflows, compare schedule) and agree on
     * a real MCU; simavr 1.6 can drop a Timer1 overflow when OCR1A is written in the cycle
     * it falls due, which left them 32.768 ms apart and the lease that much short. */
    if (!B.session || B.lease != LEASE_RUNNING
        || (int32_t)(hal_time_us() - B.last_rx_us) <= (int32_t)B.lease_ms * 1000) {
        return;
    }
    if (board_at_rest()) {
        B.lease = LEASE_LAPSED_IDLE;
        B.event_counter++;
        send_fault_report(B.event_counter, DTHC_FAULT_LEASE_EXPIRED, DTHC_LEASE_DETAIL_IDLE);
        return;
    }
    B.lease = LEASE_EXPIRED;
    board_latch(DTHC_FAULT_LEASE_EXPIRED, DTHC_LEASE_DETAIL_LATCHED);
}

/* The hardware layer's self-checks: the lowest failed one latches INTERNAL with its code. */
static void check_health(void)
{
    uint8_t health = hal_health();
    uint8_t code = DTHC_INTERNAL_TICK_OVERRUN;
    if (!health) {
        return;
    }
    while (!(health & 1u)) {
        health >>= 1;
        code++;
    }
    board_latch(DTHC_FAULT_INTERNAL, code);
}

static void check_safety(void)
{
    uint16_t in = B.inputs;
    check_lease();
    check_health();
    if (in & (1u << DTHC_INPUT_BREAKAWAY)) {
        board_latch(DTHC_FAULT_BREAKAWAY, 0);
    }
    if (in & (1u << DTHC_INPUT_ESTOP)) {
        board_latch(DTHC_FAULT_ESTOP, 0);
    }
    /* A limit switch stops motion towards it at once (the step generator's bounds) and
     * latches Z_LIMIT when Z was driven into it; homing seeks the top one on purpose. */
    if ((in & (1u << DTHC_INPUT_Z_LIMIT_MIN)) && B.z_v_um_s < 0) {
        board_latch(DTHC_FAULT_Z_LIMIT, 0);
    }
    if ((in & (1u << DTHC_INPUT_Z_LIMIT_MAX)) && B.z_v_um_s > 0 && B.z_mode != Z_HOME) {
        board_latch(DTHC_FAULT_Z_LIMIT, 1);
    }
    if (B.torch && B.arc_lost_ms) {
        if (in & (1u << DTHC_INPUT_ARC_OK)) {
            B.arc_ok_seen = true;
            B.arc_off_timing = false;
        } else if (B.arc_ok_seen) {
            if (!B.arc_off_timing) {
                B.arc_off_timing = true;
                B.arc_off_since_us = B.now_us;
            } else if ((uint32_t)(B.now_us - B.arc_off_since_us)
                       >= (uint32_t)B.arc_lost_ms * 1000u) {
                board_latch(DTHC_FAULT_ARC_LOST, 0);
            }
        }
    }
}

static void report_faults(void)
{
    uint8_t code;
    for (code = 0; code < BOARD_FAULT_CODES; code++) {
        if (B.faults & (1u << code)) {
            send_fault(code, B.fault_detail[code]); /* the counter that latched it */
        }
    }
}

/* --- sampling ------------------------------------------------------------------------------ */

/* Calibrated centivolts, clamped to what SAMPLES carry (0..655.35 V): 32-bit only. */
static int32_t calibrate(uint16_t raw)
{
    int32_t diff;
    uint32_t p;
    /* Beyond 2^17 counts every result saturates for any scale worth having, and the
     * product with a 14-bit mantissa stays inside 31 bits. */
    if (B.cal_offset < -(1L << 17)) {
        diff = 1L << 17;
    } else {
        diff = (int32_t)raw - B.cal_offset;
        if (diff > (1L << 17)) {
            diff = 1L << 17;
        }
    }
    if (diff <= 0) {
        return 0; /* negative volts: SAMPLES carry 0 */
    }
    p = (uint32_t)diff * B.scale_m;
    if (B.scale_sh > 31) {
        p = 0;
    } else if (B.scale_sh) {
        p = (p + (1UL << (B.scale_sh - 1))) >> B.scale_sh;
    }
    return p > 0xFFFFu ? 0xFFFF : (int32_t)p;
}

static int32_t filter(int32_t cv)
{
    switch (B.filter_kind) {
    case DTHC_FILTER_MOVING_AVERAGE: {
        uint8_t window = (uint8_t)B.filter_param;
        if (B.hist_len == window) {
            B.hist_sum -= B.hist[B.hist_pos];
        } else {
            B.hist_len++;
        }
        B.hist[B.hist_pos] = cv;
        B.hist_sum += cv;
        B.hist_pos = (uint8_t)((B.hist_pos + 1u) % window);
        return B.hist_sum / (int32_t)B.hist_len;
    }
    case DTHC_FILTER_MEDIAN3: {
        int32_t a, b, c;
        B.hist[B.hist_pos] = cv;
        B.hist_pos = (uint8_t)((B.hist_pos + 1u) % 3u);
        if (B.hist_len < 3) {
            B.hist_len++;
        }
        if (B.hist_len == 1) {
            return cv;
        }
        if (B.hist_len == 2) { /* the median of two values is their mean */
            return (B.hist[0] + B.hist[1]) / 2;
        }
        a = B.hist[0];
        b = B.hist[1];
        c = B.hist[2];
        if ((a <= b && b <= c) || (c <= b && b <= a)) {
            return b;
        }
        if ((b <= a && a <= c) || (c <= a && a <= b)) {
            return a;
        }
        return c;
    }
    case DTHC_FILTER_LOW_PASS: {
        /* y += alpha * (x - y), y in 1/256 cV: |x - y| < 2^24 split so that every
         * product fits 32 bits unsigned. */
        int32_t d = cv * 256 - B.lp_q8;
        uint32_t mag = (uint32_t)(d < 0 ? -d : d);
        uint32_t step;
        if (!B.hist_len) {
            B.hist_len = 1;
            B.lp_q8 = cv * 256;
            return cv;
        }
        step = (((mag >> 8) * B.lp_alpha_q16) >> 8) + (((mag & 0xFFu) * B.lp_alpha_q16) >> 16);
        B.lp_q8 += d < 0 ? -(int32_t)step : (int32_t)step;
        return (B.lp_q8 + 128) >> 8;
    }
    default:
        return cv;
    }
}

static void send_batch(void)
{
    uint8_t *p = SAMPLES_AT;
    uint8_t len = (uint8_t)(DTHC_SAMPLES_HEADER_SIZE + 2u * B.n_batch);
    dthc_samples_put_stream_seq(p, B.sample_seq);
    dthc_samples_put_t0_us(p, B.batch_t0_us);
    dthc_samples_put_period_us(p, B.period_us);
    dthc_samples_put_z_um(p, board_z_um());
    dthc_samples_put_inputs(p, B.inputs);
    dthc_samples_put_zvel_seq(p, B.zvel_seq);
    dthc_samples_put_xy_speed_dmm_s(p, (B.cfg->capabilities & DTHC_CAP_XY_SPEED)
                                           ? hal_xy_speed_dmm_s()
                                           : DTHC_XY_SPEED_UNKNOWN);
    dthc_samples_put_status(p, board_status_bits());
    if (!samples_ready_len) {
        samples_ready_len = len;
        samples_fill ^= 1u;
        B.sample_overflow = false;
    } else {
        /* The previous batch is still waiting: this one is lost. The host sees the
         * stream_seq gap, and the next batch says SAMPLE_OVERFLOW. */
        B.sample_overflow = true;
    }
    B.sample_seq++;
    B.n_batch = 0;
}

/* A short frame is arriving (a QUERY is 7 bytes, 70 us on the wire at 1 Mbaud): a batch
 * queued now would go out ahead of its reply (35 bytes, 0.35 ms of wire). The batch waits
 * until the frame is complete, for at most BATCH_HOLD_US (a frame that never ends does not
 * stop the samples). */
#define BATCH_HOLD_FRAME_BYTES 32
#define BATCH_HOLD_US 300u
static bool batch_holding;
static uint16_t batch_hold_since_us; /* low 16 bits of the clock: RAM is short on the Nano */

static bool batch_waits_for_frame(void)
{
    uint16_t now;
    if (board_rx.enc_len == 0 || board_rx.enc_len > BATCH_HOLD_FRAME_BYTES) {
        batch_holding = false;
        return false;
    }
    now = (uint16_t)hal_time_us();
    if (!batch_holding) {
        batch_holding = true;
        batch_hold_since_us = now;
    }
    return (uint16_t)(now - batch_hold_since_us) < BATCH_HOLD_US;
}

/* Transmit room kept for a batch while replies are queued: the largest reply (HELLO_INFO,
 * 45 bytes of payload) and one batch of the configured size, each with its frame overhead
 * (type, seq, CRC, COBS, delimiter), at most BOARD_TX_RESERVE_MAX (below the smallest ring:
 * a ring that drains empty always lets the next frame in). */
#define FRAME_OVERHEAD 7u
#define REPLY_WIRE_MAX (45u + FRAME_OVERHEAD)
#ifndef BOARD_TX_RESERVE_MAX
#define BOARD_TX_RESERVE_MAX 100u
#endif
uint16_t board_tx_reserve(void)
{
    uint16_t batch = (uint16_t)(DTHC_SAMPLES_HEADER_SIZE + 2u * B.batch_size + FRAME_OVERHEAD);
    uint16_t reserve = (uint16_t)(REPLY_WIRE_MAX + batch);
    return reserve < BOARD_TX_RESERVE_MAX ? reserve : BOARD_TX_RESERVE_MAX;
}

bool board_samples_waiting(void)
{
    return samples_ready_len != 0;
}

/* Main loop, after the received bytes: encode a completed batch, and queue it at the next
 * call (a frame that arrived during the encode is read, and answered, first), unless a
 * short frame is arriving. */
bool board_flush_samples(void)
{
    uint8_t len = samples_ready_len;
    uint8_t *buf;
    if (!len || batch_waits_for_frame()) {
        return false;
    }
    /* The tick does not swap while len != 0: the other buffer stays ours until then. */
    buf = samples_tx[samples_fill ^ 1u];
    if (!samples_wire_len) {
        samples_wire_len = (uint8_t)dthc_encode_in_place(DTHC_MSG_SAMPLES, 0, buf, len);
        return true;
    }
    if (!board_queue(buf, samples_wire_len)) {
        /* Replies fill the transmit ring (a burst of queries): the batch waits for room
         * and goes at a later poll. Only a batch still waiting when the next one is
         * complete is lost (send_batch says SAMPLE_OVERFLOW then). */
        return false;
    }
    samples_wire_len = 0;
    samples_ready_len = 0;
    return true;
}

static void sample(void)
{
    int32_t cv = filter(calibrate(hal_arc_raw()));
    if (!B.n_batch) {
        B.batch_t0_us = B.now_us;
    }
    dthc_samples_put_samples_cv(SAMPLES_AT, B.n_batch, (uint16_t)cv);
    B.n_batch++;
    if (B.n_batch >= B.batch_size) {
        send_batch();
    }
}

/* --- CONFIGURE (main loop, tick locked: the float arithmetic stays out of the tick) ------ */

static bool set_scale(float scale)
{
    float x = scale * 100.0f; /* volts per count -> centivolts per count */
    int sh = 0;
    if (!(scale > 0.0f) || scale > 3.0e38f) {
        return false; /* not positive, NaN or infinite */
    }
    while (x < 8192.0f && sh < 40) { /* a 14-bit mantissa: [2^13, 2^14) */
        x *= 2.0f;
        sh++;
    }
    while (x >= 16384.0f && sh > 0) {
        x *= 0.5f;
        sh--;
    }
    if (x >= 16383.5f) {
        x = 16383.0f; /* >= 2^14 cV per count: every non-zero reading saturates */
    }
    B.scale_m = (uint32_t)(x + 0.5f);
    B.scale_sh = (uint8_t)sh;
    return true;
}

bool board_configure(const uint8_t *p, uint8_t *bad_field)
{
    uint16_t rate = dthc_configure_get_sample_rate_hz(p);
    uint8_t batch = dthc_configure_get_batch_size(p);
    uint8_t kind = dthc_configure_get_filter_kind(p);
    uint16_t param = dthc_configure_get_filter_param(p);
    uint16_t arc_lost = dthc_configure_get_arc_lost_ms(p);
    int32_t offset = dthc_configure_get_cal_offset(p);
    float scale = dthc_configure_get_cal_scale(p);
    uint32_t saved_m = B.scale_m;
    uint8_t saved_sh = B.scale_sh;
    *bad_field = 0xFF;
    if (rate < DTHC_SAMPLE_RATE_MIN_HZ || rate > BOARD_MAX_RATE_HZ) {
        *bad_field = 0;
    } else if (batch < 1 || batch > BOARD_MAX_BATCH) {
        *bad_field = 1;
    } else if (kind > DTHC_FILTER_MEDIAN3) {
        *bad_field = 2;
    } else if ((kind == DTHC_FILTER_MOVING_AVERAGE && (param < 1 || param > BOARD_MA_MAX))
               || (kind == DTHC_FILTER_LOW_PASS && (param < 1 || param > DTHC_LOW_PASS_MAX_HZ))) {
        *bad_field = 3;
    } else if (arc_lost > DTHC_ARC_LOST_MAX_MS) {
        *bad_field = 4;
    } else if (!set_scale(scale)) {
        *bad_field = 6;
    }
    if (*bad_field != 0xFF) {
        B.scale_m = saved_m; /* nothing applied */
        B.scale_sh = saved_sh;
        return false;
    }
    B.rate_hz = rate;
    B.period_us = (uint16_t)(1000000UL / rate);
    B.batch_size = batch;
    B.filter_kind = kind;
    B.filter_param = param;
    B.arc_lost_ms = arc_lost;
    B.cal_offset = offset;
    if (kind == DTHC_FILTER_LOW_PASS) {
        /* First order: alpha = dt / (RC + dt), RC = 1 / (2 pi fc). */
        float dt = (float)B.period_us * 1e-6f;
        float rc = 1.0f / (6.2831853f * (float)param);
        B.lp_alpha_q16 = (uint16_t)(dt / (rc + dt) * 65535.0f + 0.5f);
    }
    B.hist_len = 0;
    B.hist_pos = 0;
    B.hist_sum = 0;
    B.n_batch = 0; /* a partial batch is dropped, as the mock board does */
    hal_tick_set_period_us(B.period_us);
    board_z_update_dv();
    return true;
}

/* --- entry points ----------------------------------------------------------------------- */

void board_init(const board_config_t *cfg, uint32_t entropy)
{
    memset(&B, 0, sizeof B);
    B.cfg = cfg;
    B.boot_id = entropy;
    B.lease_ms = DTHC_DEFAULT_LEASE_MS;
    B.rate_hz = DTHC_DEFAULT_SAMPLE_RATE_HZ;
    B.period_us = (uint16_t)(1000000UL / DTHC_DEFAULT_SAMPLE_RATE_HZ);
    B.batch_size = DTHC_DEFAULT_BATCH_SIZE;
    B.filter_kind = DTHC_FILTER_NONE;
    (void)set_scale(0.01f); /* raw is nominal centivolts: the host's default 0.01 V/count */
    dthc_rx_init(&board_rx);
    hal_set_torch(false);
    hal_set_ohmic_enable(false);
    hal_tick_set_period_us(B.period_us);
    board_z_init();
}

#ifdef BOARD_TIMING
uint16_t board_tick_max_us;
uint32_t board_tick_sum_us; /* over the last 1024 ticks: their mean, for STATUS */
uint16_t board_tick_n;
uint16_t board_tick_mean_us;
#endif

void board_tick(uint32_t t_us)
{
#ifdef BOARD_TIMING
    uint32_t start = hal_time_us();
#endif
    B.now_us = t_us;
    read_inputs();
    check_safety();
    board_z_tick();
    sample();
    if (B.faults && (uint32_t)(B.now_us - B.last_fault_report_us) >= BOARD_FAULT_REPEAT_US) {
        report_faults();
    }
#ifdef BOARD_TIMING
    start = hal_time_us() - start;
    if (start > board_tick_max_us) {
        board_tick_max_us = (uint16_t)start;
    }
    board_tick_sum_us += start;
    if (++board_tick_n == 1024) {
        board_tick_mean_us = (uint16_t)(board_tick_sum_us / 1024u);
        board_tick_sum_us = 0;
        board_tick_n = 0;
    }
#endif
}
