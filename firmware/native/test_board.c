/*
 * test_board.c - native unit tests of the board logic (firmware/board/) over the fake HAL.
 *
 *   test_board            run every test
 *   test_board NAME...    run the named tests
 *   test_board --list     print the test names
 * Prints "ok NAME" or "FAIL NAME: why" per test; exits 1 if any failed.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../firmware_protocol/c/dthc_protocol.h"
#include "../board/board.h"
#include "../hal/hal.h"
#include "hal_fake.h"

/* --- plumbing -------------------------------------------------------------------------- */

static const board_config_t CONFIG = {
    "DTHC-TEST-0001",
    DTHC_CAP_OHMIC | DTHC_CAP_FLOAT | DTHC_CAP_BREAKAWAY | DTHC_CAP_ESTOP | DTHC_CAP_FILTERS
        | DTHC_CAP_Z_LIMITS | DTHC_CAP_HOMING,
    0, 100000, 60000, 60000, 650000, 200, DTHC_RESET_POWER_ON, 102000,
};

typedef struct {
    uint8_t type;
    uint8_t seq;
    uint8_t len;
    uint8_t p[DTHC_MAX_PAYLOAD];
} frame_t;

#define MAX_FRAMES 4096
static frame_t out[MAX_FRAMES];
static unsigned n_out;
static unsigned parsed_to;
static dthc_rx_t host_rx;
static char why[256];
static uint8_t next_seq = 1;

#define CHECK(cond, ...)                                                                     \
    do {                                                                                     \
        if (!(cond)) {                                                                       \
            snprintf(why, sizeof why, __VA_ARGS__);                                          \
            return 1;                                                                        \
        }                                                                                    \
    } while (0)

/* Parse what the board sent since the last call into out[]. */
static void parse(void)
{
    while (parsed_to < F.tx_len) {
        dthc_frame_t f;
        if (dthc_rx_feed(&host_rx, F.tx[parsed_to++], &f) == 1 && n_out < MAX_FRAMES) {
            frame_t *o = &out[n_out++];
            o->type = f.type;
            o->seq = f.seq;
            o->len = f.len;
            memcpy(o->p, f.payload, f.len);
        }
    }
}

static void setup(void)
{
    fake_reset();
    board_init(&CONFIG, 0xC0FFEE01u);
    dthc_rx_init(&host_rx);
    n_out = parsed_to = 0;
    next_seq = 1;
}

/* Send one frame to the board and let the main loop handle it. */
static void send_raw(uint8_t type, uint8_t seq, const uint8_t *payload, uint8_t len)
{
    uint8_t wire[DTHC_MAX_WIRE_FRAME];
    size_t n = dthc_encode_frame(type, seq, payload, len, wire, sizeof wire);
    fake_rx(wire, (unsigned)n);
    while (board_poll()) {
    }
    parse();
}

static uint8_t send(uint8_t type, const uint8_t *payload, uint8_t len)
{
    uint8_t seq = next_seq;
    next_seq = (uint8_t)(next_seq == 255 ? 1 : next_seq + 1);
    send_raw(type, seq, payload, len);
    return seq;
}

/* Run ms, the main loop polled after every tick (it queues the SAMPLES batches). */
static void run_ms(uint32_t ms)
{
    while (ms--) {
        fake_run_us(1000u);
        while (board_poll()) {
        }
    }
    parse();
}

/* The last frame of a type (with seq, unless seq < 0) sent since index `since`. */
static const frame_t *last(uint8_t type, int seq, unsigned since)
{
    const frame_t *found = NULL;
    unsigned i;
    for (i = since; i < n_out; i++) {
        if (out[i].type == type && (seq < 0 || out[i].seq == seq)) {
            found = &out[i];
        }
    }
    return found;
}

/* The result of the last MOTION_DONE (PROBE_RESULT) with seq (any, if seq < 0) sent since
 * index `since`, or -1 if there is none. */
static int motion_result(int seq, unsigned since)
{
    const frame_t *f = last(DTHC_MSG_MOTION_DONE, seq, since);
    return f ? dthc_motion_done_get_result(f->p) : -1;
}

static int probe_result(int seq, unsigned since)
{
    const frame_t *f = last(DTHC_MSG_PROBE_RESULT, seq, since);
    return f ? dthc_probe_result_get_result(f->p) : -1;
}

static unsigned count(uint8_t type, int seq, unsigned since)
{
    unsigned i, n = 0;
    for (i = since; i < n_out; i++) {
        n += out[i].type == type && (seq < 0 || out[i].seq == seq);
    }
    return n;
}

static int is_ack(uint8_t seq, unsigned since)
{
    return last(DTHC_MSG_ACK, seq, since) != NULL && !last(DTHC_MSG_NAK, seq, since);
}

static int nak_code(uint8_t seq, unsigned since, uint8_t *detail)
{
    const frame_t *f = last(DTHC_MSG_NAK, seq, since);
    if (!f) {
        return -1;
    }
    if (detail) {
        *detail = dthc_nak_get_detail(f->p);
    }
    return dthc_nak_get_code(f->p);
}

static void hello(void)
{
    uint8_t p[DTHC_HELLO_SIZE];
    dthc_hello_put_proto_major(p, DTHC_PROTOCOL_MAJOR);
    dthc_hello_put_proto_minor(p, DTHC_PROTOCOL_MINOR);
    dthc_hello_put_host_nonce(p, 0x04030201u);
    send(DTHC_MSG_HELLO, p, DTHC_HELLO_SIZE);
}

static uint8_t cmd_u8(uint8_t type, uint8_t v)
{
    return send(type, &v, 1);
}

static uint8_t cmd_u16(uint8_t type, uint16_t v)
{
    uint8_t p[2];
    dthc_put_u16(p, v);
    return send(type, p, 2);
}

static uint8_t z_move(int32_t target_um, uint32_t feed_um_s)
{
    uint8_t p[DTHC_Z_MOVE_SIZE];
    dthc_z_move_put_target_um(p, target_um);
    dthc_z_move_put_feed_um_s(p, feed_um_s);
    return send(DTHC_MSG_Z_MOVE, p, DTHC_Z_MOVE_SIZE);
}

/* Z_PROBE and Z_PROBE_AWAY share their payload: feed, travel, sensor set. */
static uint8_t probe_msg(uint8_t type, uint32_t feed, uint32_t travel, uint16_t sensors)
{
    uint8_t p[DTHC_Z_PROBE_SIZE];
    dthc_z_probe_put_feed_um_s(p, feed);
    dthc_z_probe_put_max_travel_um(p, travel);
    dthc_z_probe_put_sensors(p, sensors);
    return send(type, p, DTHC_Z_PROBE_SIZE);
}

static uint8_t z_probe(uint32_t feed, uint32_t travel, uint16_t sensors)
{
    return probe_msg(DTHC_MSG_Z_PROBE, feed, travel, sensors);
}

static uint8_t z_probe_away(uint32_t feed, uint32_t travel, uint16_t sensors)
{
    return probe_msg(DTHC_MSG_Z_PROBE_AWAY, feed, travel, sensors);
}

static void z_velocity(uint16_t stream_seq, int32_t v, uint16_t expiry_ms)
{
    uint8_t p[DTHC_Z_VELOCITY_SIZE];
    dthc_z_velocity_put_stream_seq(p, stream_seq);
    dthc_z_velocity_put_velocity_um_s(p, v);
    dthc_z_velocity_put_expiry_ms(p, expiry_ms);
    send_raw(DTHC_MSG_Z_VELOCITY, 0, p, DTHC_Z_VELOCITY_SIZE);
}

static uint8_t configure(uint16_t rate, uint8_t batch, uint8_t kind, uint16_t param,
                         uint16_t arc_lost, int32_t offset, float scale)
{
    uint8_t p[DTHC_CONFIGURE_SIZE];
    dthc_configure_put_sample_rate_hz(p, rate);
    dthc_configure_put_batch_size(p, batch);
    dthc_configure_put_filter_kind(p, kind);
    dthc_configure_put_filter_param(p, param);
    dthc_configure_put_arc_lost_ms(p, arc_lost);
    dthc_configure_put_cal_offset(p, offset);
    dthc_configure_put_cal_scale(p, scale);
    return send(DTHC_MSG_CONFIGURE, p, DTHC_CONFIGURE_SIZE);
}

/* A fresh STATUS. */
static const frame_t *status(void)
{
    uint8_t seq = cmd_u8(DTHC_MSG_QUERY, DTHC_QUERY_STATUS);
    return last(DTHC_MSG_STATUS, seq, 0);
}

static int32_t z_um(void)
{
    return dthc_status_get_z_um(status()->p);
}

static uint16_t faults(void)
{
    return dthc_status_get_faults(status()->p);
}

static uint8_t status_bits(void)
{
    return dthc_status_get_status(status()->p);
}

#define IN(bit) (1u << DTHC_INPUT_##bit)
#define FAULT(bit) (1u << DTHC_FAULT_##bit)

/* --- tests ------------------------------------------------------------------------------- */

/* Host silent: torch off, Z decelerating and LEASE_EXPIRED latched in the first tick past
 * the lease. */
static int test_lease_expiry_within_one_tick(void)
{
    unsigned mark;
    const frame_t *f;
    uint32_t t_last;
    hello();
    cmd_u8(DTHC_MSG_TORCH, 1);
    z_move(80000, 20000);
    t_last = (uint32_t)F.now_us; /* the last host frame */
    run_ms(50);
    CHECK(F.torch && F.rate > 0, "torch on and Z moving before the silence");
    mark = n_out;
    run_ms(200);
    CHECK(F.torch, "torch must still be on at exactly the lease");
    run_ms(1);
    f = last(DTHC_MSG_FAULT, -1, mark);
    CHECK(!F.torch, "torch still on one tick past the lease");
    CHECK(f && dthc_fault_get_code(f->p) == DTHC_FAULT_LEASE_EXPIRED, "no FAULT LEASE_EXPIRED");
    CHECK(dthc_fault_get_t_us(f->p) - t_last <= 251000u, "fault at %u us",
          (unsigned)(dthc_fault_get_t_us(f->p) - t_last));
    CHECK(motion_result(-1, mark) == DTHC_MOTION_FAULT,
          "the move must end with MOTION_DONE FAULT");
    run_ms(100);
    CHECK(F.rate == 0, "Z still stepping 100 ms after expiry (rate %d)", (int)F.rate);
    return 0;
}

/* A frame the main loop decodes late (it was busy) renews the lease from the frame's
 * arrival, so the torch still drops one lease after the host's last frame arrived. */
static int test_lease_runs_from_the_frames_arrival(void)
{
    uint8_t wire[DTHC_MAX_WIRE_FRAME];
    unsigned mark;
    size_t n;
    uint32_t t_arrival;
    const frame_t *f;
    hello();
    cmd_u8(DTHC_MSG_TORCH, 1);
    run_ms(100);
    n = dthc_encode_frame(DTHC_MSG_HEARTBEAT, next_seq++, NULL, 0, wire, sizeof wire);
    fake_rx(wire, (unsigned)n);
    t_arrival = (uint32_t)F.now_us;
    fake_run_us(3000u); /* the main loop busy: the frame waits 3 ms in the receive ring */
    while (board_poll()) {
    }
    parse();
    CHECK(F.torch, "the torch went off before the heartbeat was decoded");
    mark = n_out;
    run_ms(246); /* 249 ms after the arrival */
    CHECK(F.torch, "torch off before the lease from the heartbeat's arrival");
    run_ms(2);
    f = last(DTHC_MSG_FAULT, -1, mark);
    CHECK(!F.torch, "torch on %u us after the heartbeat arrived",
          (unsigned)((uint32_t)F.now_us - t_arrival));
    CHECK(f && dthc_fault_get_t_us(f->p) - t_arrival <= 251000u, "fault %u us after arrival",
          f ? (unsigned)(dthc_fault_get_t_us(f->p) - t_arrival) : 0u);
    return 0;
}

/* The lease is one clock's duration: with the µs clock 32.768 ms behind the tick's schedule
 * (a Timer1 overflow lost, as simavr can), the torch still drops one lease after the last
 * frame's arrival, not 32.768 ms early (the e2e kill test caught 218 ms of a 250 ms lease). */
static int test_lease_holds_with_the_clock_behind_the_tick(void)
{
    hello();
    cmd_u8(DTHC_MSG_TORCH, 1);
    run_ms(100);
    F.clock_lag_us = 32768u;
    send(DTHC_MSG_HEARTBEAT, NULL, 0);
    run_ms(249);
    CHECK(F.torch, "torch off before the lease with the clock behind the tick");
    run_ms(2);
    CHECK(!F.torch && (faults() & FAULT(LEASE_EXPIRED)), "lease did not expire");
    return 0;
}

/* A self-check the hardware layer failed (the fake's health bits: a tick overrun, an ADC
 * conversion missing, the watchdog nearly starved): the next tick latches INTERNAL with
 * that check's code, the torch goes out and Z stops; the lowest code wins when several
 * fail together; FAULT_RESET clears it (the check is past). */
static int test_a_failed_self_check_latches_internal_with_its_code(void)
{
    static const struct {
        uint8_t health;
        uint8_t code;
    } cases[] = {
        {HAL_HEALTH_TICK_OVERRUN, DTHC_INTERNAL_TICK_OVERRUN},
        {HAL_HEALTH_ADC_INCOMPLETE, DTHC_INTERNAL_ADC_INCOMPLETE},
        {HAL_HEALTH_LOOP_STALL, DTHC_INTERNAL_WATCHDOG_NEAR_MISS},
        {HAL_HEALTH_LOOP_STALL | HAL_HEALTH_ADC_INCOMPLETE, DTHC_INTERNAL_ADC_INCOMPLETE},
    };
    unsigned i;
    for (i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        unsigned mark;
        const frame_t *f;
        uint8_t seq;
        setup(); /* each case on a fresh board */
        hello();
        cmd_u8(DTHC_MSG_TORCH, 1);
        z_move(80000, 20000);
        run_ms(20);
        CHECK(F.torch && F.rate > 0, "case %u: torch on and Z moving first", i);
        mark = n_out;
        F.health = cases[i].health;
        run_ms(1);
        f = last(DTHC_MSG_FAULT, -1, mark);
        CHECK(!F.torch, "case %u: torch still on after a failed self-check", i);
        CHECK(faults() & FAULT(INTERNAL), "case %u: INTERNAL not latched", i);
        CHECK(f && dthc_fault_get_code(f->p) == DTHC_FAULT_INTERNAL
                  && dthc_fault_get_detail(f->p) == cases[i].code,
              "case %u: FAULT INTERNAL detail %u expected", i, (unsigned)cases[i].code);
        run_ms(100);
        CHECK(F.rate == 0, "case %u: Z still stepping after INTERNAL", i);
        seq = cmd_u16(DTHC_MSG_FAULT_RESET, FAULT(INTERNAL));
        CHECK(is_ack(seq, mark), "case %u: FAULT_RESET of INTERNAL refused", i);
        CHECK(!(faults() & FAULT(INTERNAL)), "case %u: INTERNAL still latched", i);
    }
    return 0;
}

/* Frames after expiry renew nothing; only FAULT_RESET re-arms. */
static int test_frames_after_expiry_do_not_revive(void)
{
    uint8_t seq;
    unsigned mark;
    hello();
    cmd_u8(DTHC_MSG_OHMIC_SENSE, 1);
    run_ms(300);
    CHECK(faults() & FAULT(LEASE_EXPIRED), "lease not expired");
    CHECK(!F.ohmic, "ohmic sensing still on after expiry");
    send(DTHC_MSG_HEARTBEAT, NULL, 0);
    run_ms(10);
    CHECK(faults() & FAULT(LEASE_EXPIRED), "a heartbeat cleared the lease fault");
    mark = n_out;
    seq = cmd_u8(DTHC_MSG_TORCH, 1);
    CHECK(nak_code(seq, mark, NULL) == DTHC_NAK_FAULT_LATCHED, "TORCH on accepted while latched");
    CHECK(!F.torch, "torch on while latched");
    seq = cmd_u16(DTHC_MSG_FAULT_RESET, FAULT(LEASE_EXPIRED));
    CHECK(is_ack(seq, mark), "FAULT_RESET not acknowledged");
    CHECK(!(faults() & FAULT(LEASE_EXPIRED)), "FAULT_RESET did not clear the lease fault");
    seq = cmd_u8(DTHC_MSG_TORCH, 1);
    CHECK(is_ack(seq, mark) && F.torch, "torch refused after FAULT_RESET");
    run_ms(200);
    CHECK(F.torch, "re-armed lease expired early");
    run_ms(100);
    CHECK(!F.torch && (faults() & FAULT(LEASE_EXPIRED)), "re-armed lease did not expire again");
    return 0;
}

/* The FAULT frames of a code since `since`, counted; *first set to the first one. */
static unsigned faults_of(uint8_t code, unsigned since, const frame_t **first)
{
    unsigned i, n = 0;
    *first = NULL;
    for (i = since; i < n_out; i++) {
        if (out[i].type == DTHC_MSG_FAULT && dthc_fault_get_code(out[i].p) == code) {
            if (!n) {
                *first = &out[i];
            }
            n++;
        }
    }
    return n;
}

/* The lease runs out with the board at rest (nothing lit, Z still): one FAULT
 * LEASE_EXPIRED detail IDLE in the first tick past the lease, with the next event counter
 * and no fault bit; not repeated while the host stays silent; nothing latched, so the
 * host's next frame renews the lease and a TORCH on is accepted without FAULT_RESET. */
static int test_idle_lease_lapse_reported_once_not_latched(void)
{
    unsigned mark;
    const frame_t *f;
    uint32_t t_last, counter;
    uint8_t seq;
    hello();
    counter = dthc_status_get_event_counter(status()->p); /* the event counter before the lapse */
    t_last = (uint32_t)F.now_us;
    mark = n_out;
    run_ms(250);
    CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f) == 0, "lapse reported before the lease");
    run_ms(1);
    CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f) == 1, "no idle lapse reported");
    CHECK(dthc_fault_get_detail(f->p) == DTHC_LEASE_DETAIL_IDLE,
          "detail %u, want IDLE", dthc_fault_get_detail(f->p));
    CHECK(dthc_fault_get_faults(f->p) == 0, "fault set 0x%04x in the lapse report",
          dthc_fault_get_faults(f->p));
    CHECK(dthc_fault_get_counter(f->p) == counter + 1, "counter %u, want %u",
          (unsigned)dthc_fault_get_counter(f->p), (unsigned)(counter + 1));
    CHECK(dthc_fault_get_t_us(f->p) - t_last <= 251000u, "reported at %u us",
          (unsigned)(dthc_fault_get_t_us(f->p) - t_last));
    run_ms(800); /* silent on: no re-report every 250 ms */
    CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f) == 1, "the idle lapse was repeated");
    CHECK(!F.torch && !F.ohmic && F.rate == 0, "outputs on or Z moving after the lapse");
    CHECK(faults() == 0, "a fault latched by an idle lapse");
    CHECK(!(status_bits() & DTHC_STATUS_FAULT_LATCHED), "FAULT_LATCHED after an idle lapse");
    mark = n_out;
    seq = cmd_u8(DTHC_MSG_TORCH, 1);
    CHECK(is_ack(seq, mark) && F.torch, "TORCH on after an idle lapse refused");
    run_ms(200);
    CHECK(F.torch, "the renewed lease ran out early");
    return 0;
}

/* Once per lapse: the host comes back, falls silent again, and the new lapse is reported
 * again with a new counter. A HELLO of a new session also ends a lapse. */
static int test_idle_lease_lapse_reported_again_after_renewal(void)
{
    unsigned mark;
    const frame_t *f1, *f2;
    hello();
    mark = n_out;
    run_ms(300);
    CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f1) == 1, "first lapse not reported");
    CHECK(is_ack(send(DTHC_MSG_HEARTBEAT, NULL, 0), mark), "heartbeat after the lapse");
    mark = n_out;
    run_ms(249);
    CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f2) == 0, "lease not renewed by a frame");
    run_ms(2);
    CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f2) == 1, "second lapse not reported");
    CHECK(dthc_fault_get_detail(f2->p) == DTHC_LEASE_DETAIL_IDLE
              && dthc_fault_get_counter(f2->p) > dthc_fault_get_counter(f1->p),
          "second lapse: detail %u counter %u", dthc_fault_get_detail(f2->p),
          (unsigned)dthc_fault_get_counter(f2->p));
    hello();
    mark = n_out;
    run_ms(251);
    CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f2) == 1, "lapse after HELLO not reported");
    CHECK(faults() == 0, "a fault latched by an idle lapse");
    return 0;
}

/* Not at rest: Z moving (a move, a probe, a velocity in force, or still decelerating from
 * a stop) with the torch and ohmic sensing off still latches LEASE_EXPIRED (detail
 * LATCHED), ends the motion and stops Z; likewise ohmic sensing on with Z still. */
static int test_lease_latches_when_not_at_rest(void)
{
    int c;
    for (c = 0; c < 6; c++) {
        unsigned mark;
        const frame_t *f;
        uint16_t lease = 100;
        setup();
        hello();
        cmd_u16(DTHC_MSG_SET_LEASE, 100);
        if (c == 0) {
            z_move(80000, 5000);
        } else if (c == 1) {
            z_probe(5000, 30000, IN(FLOAT));
        } else if (c == 2) {
            z_velocity(1, 5000, 200);
        } else if (c == 3) {
            cmd_u8(DTHC_MSG_OHMIC_SENSE, 1);
        } else if (c == 5) {
            F.inputs = IN(FLOAT); /* on the float switch: a probe away lifts off it */
            run_ms(1);
            z_probe_away(500, 30000, IN(FLOAT));
        } else {
            z_move(80000, 60000);
            run_ms(60);
            lease = 30;
            cmd_u16(DTHC_MSG_SET_LEASE, lease);
            send(DTHC_MSG_Z_STOP, NULL, 0); /* from 39 mm/s at 650 mm/s^2: 60 ms */
        }
        mark = n_out;
        run_ms(lease + 1u);
        CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f) == 1, "case %d: no FAULT", c);
        CHECK(dthc_fault_get_detail(f->p) == DTHC_LEASE_DETAIL_LATCHED,
              "case %d: detail %u", c, dthc_fault_get_detail(f->p));
        CHECK(dthc_fault_get_faults(f->p) & FAULT(LEASE_EXPIRED), "case %d: not latched", c);
        CHECK(!F.ohmic, "case %d: ohmic sensing on after expiry", c);
        if (c == 0) {
            CHECK(motion_result(-1, mark) == DTHC_MOTION_FAULT,
                  "the move must end with MOTION_DONE FAULT");
        }
        if (c == 1 || c == 5) {
            CHECK(probe_result(-1, mark) == DTHC_PROBE_ABORTED,
                  "the probe must end with PROBE_RESULT ABORTED");
        }
        run_ms(300);
        CHECK(F.rate == 0, "case %d: Z still stepping after expiry", c);
        CHECK(faults_of(DTHC_FAULT_LEASE_EXPIRED, mark, &f) >= 2, "case %d: not re-reported", c);
        CHECK(faults() & FAULT(LEASE_EXPIRED), "case %d: a frame revived the lease", c);
    }
    return 0;
}

/* While latched, FAULT is re-sent every 250 ms with the counter that latched it. */
static int test_fault_rereported_every_250ms(void)
{
    unsigned mark, i, n = 0;
    uint32_t counter = 0, t_prev = 0;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    F.inputs = IN(ESTOP);
    run_ms(2);
    mark = n_out;
    run_ms(1000);
    for (i = mark; i < n_out; i++) {
        if (out[i].type == DTHC_MSG_FAULT) {
            uint32_t t = dthc_fault_get_t_us(out[i].p);
            if (n) {
                CHECK(t - t_prev == 250000u, "re-report after %u us", (unsigned)(t - t_prev));
                CHECK(dthc_fault_get_counter(out[i].p) == counter, "re-report changed the counter");
            }
            counter = dthc_fault_get_counter(out[i].p);
            t_prev = t;
            n++;
        }
    }
    CHECK(n >= 3, "%u re-reports in 1 s", n);
    return 0;
}

/* A retransmitted seq is answered from memory, not executed again; NAKs too. */
static int test_duplicate_replayed_not_reexecuted(void)
{
    uint8_t p = 1, lease[2];
    uint8_t seq;
    unsigned mark;
    const frame_t *s;
    hello();
    seq = cmd_u8(DTHC_MSG_OHMIC_SENSE, 1);
    cmd_u8(DTHC_MSG_OHMIC_SENSE, 0);
    mark = n_out;
    send_raw(DTHC_MSG_OHMIC_SENSE, seq, &p, 1);
    CHECK(is_ack(seq, mark), "duplicate not acknowledged again");
    CHECK(!F.ohmic, "duplicate executed again");
    dthc_put_u16(lease, 5);
    seq = send(DTHC_MSG_SET_LEASE, lease, 2);
    send_raw(DTHC_MSG_SET_LEASE, seq, lease, 2);
    CHECK(count(DTHC_MSG_NAK, seq, mark) == 2, "refused command's NAK not repeated");
    s = status();
    CHECK(dthc_status_get_rx_duplicates(s->p) == 2,
          "rx_duplicates %u", dthc_status_get_rx_duplicates(s->p));
    /* HELLO clears the memory: the same seq executes again. */
    hello();
    mark = n_out;
    send_raw(DTHC_MSG_OHMIC_SENSE, 1, &p, 1);
    CHECK(F.ohmic, "after HELLO an old seq must execute");
    return 0;
}

/* Unknown type and bad length: NAK with the rejected frame's own seq. */
static int test_nak_with_rejected_frames_seq(void)
{
    uint8_t two[2] = {0, 0};
    unsigned mark;
    hello();
    mark = n_out;
    send_raw(0x7E, 77, NULL, 0);
    CHECK(nak_code(77, mark, NULL) == DTHC_NAK_UNKNOWN_TYPE, "unknown type: no NAK with seq 77");
    send_raw(DTHC_MSG_TORCH, 78, two, 2);
    CHECK(nak_code(78, mark, NULL) == DTHC_NAK_BAD_LENGTH, "bad length: no NAK with seq 78");
    send_raw(0x7E, 0, NULL, 0);
    CHECK(count(DTHC_MSG_NAK, 0, mark) == 0, "seq 0 must not be answered");
    return 0;
}

/* Before HELLO: commands refused with NO_SESSION; queries answered. */
static int test_no_session_refusals(void)
{
    uint8_t seq;
    unsigned mark = n_out;
    seq = cmd_u8(DTHC_MSG_TORCH, 1);
    CHECK(nak_code(seq, mark, NULL) == DTHC_NAK_NO_SESSION, "TORCH before HELLO not refused");
    CHECK(!F.torch, "torch on without a session");
    seq = cmd_u8(DTHC_MSG_QUERY, DTHC_QUERY_HELLO_INFO);
    CHECK(last(DTHC_MSG_HELLO_INFO, seq, mark), "QUERY(HELLO_INFO) before HELLO unanswered");
    CHECK(!(status_bits() & DTHC_STATUS_SESSION), "session bit before HELLO");
    return 0;
}

/* HELLO_INFO says what the build has. */
static int test_hello_info_fields(void)
{
    const frame_t *h;
    char serial[DTHC_SERIAL_LEN + 1];
    uint8_t seq;
    hello();
    seq = cmd_u8(DTHC_MSG_QUERY, DTHC_QUERY_HELLO_INFO);
    h = last(DTHC_MSG_HELLO_INFO, seq, 0);
    CHECK(h && h->len == 45, "no HELLO_INFO");
    CHECK(dthc_hello_info_get_fw_major(h->p) == 0 && dthc_hello_info_get_fw_minor(h->p) == 1
              && dthc_hello_info_get_fw_patch(h->p) == 0,
          "fw version");
    dthc_hello_info_get_serial(h->p, serial);
    CHECK(strcmp(serial, "DTHC-TEST-0001") == 0, "serial %s", serial);
    CHECK(dthc_hello_info_get_capabilities(h->p) == CONFIG.capabilities, "capabilities");
    CHECK(!(dthc_hello_info_get_capabilities(h->p) & (DTHC_CAP_XY_SPEED | DTHC_CAP_CURRENT_OUT)),
          "caps");
    CHECK(dthc_hello_info_get_lease_ms(h->p) == 250, "lease");
    return 0;
}

/* The probe stops in the tick that reads the contact, reports contact and rest positions. */
static int test_probe_stops_on_contact_in_tick(void)
{
    uint8_t seq;
    unsigned mark;
    const frame_t *r;
    int32_t contact;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    seq = z_probe(5000, 20000, IN(OHMIC) | IN(FLOAT));
    CHECK(is_ack(seq, 0), "probe not acknowledged");
    run_ms(500);
    CHECK(F.rate < 0, "probe not moving down");
    mark = n_out;
    F.inputs = IN(FLOAT);
    fake_run_us(F.next_tick_us - (uint32_t)F.now_us); /* exactly one tick */
    while (board_poll()) {
    }
    parse();
    CHECK(F.rate > -5000 * 200 / 1000, "no deceleration in the contact tick (rate %d)",
          (int)F.rate);
    run_ms(50);
    r = last(DTHC_MSG_PROBE_RESULT, seq, mark);
    CHECK(r, "no PROBE_RESULT");
    contact = dthc_probe_result_get_contact_z_um(r->p);
    CHECK(dthc_probe_result_get_result(r->p) == DTHC_PROBE_CONTACT,
          "result %u", dthc_probe_result_get_result(r->p));
    CHECK(dthc_probe_result_get_sensor(r->p) == IN(FLOAT), "sensor");
    CHECK(contact <= 60000 - 2400 && contact >= 60000 - 2600, "contact at %d", (int)contact);
    CHECK(dthc_probe_result_get_stop_z_um(r->p) <= contact
              && dthc_probe_result_get_stop_z_um(r->p) >= contact - 50,
          "stop %d vs contact %d", (int)dthc_probe_result_get_stop_z_um(r->p), (int)contact);
    CHECK(F.rate == 0, "still moving after the result");
    return 0;
}

/* No contact within max travel: NO_CONTACT, resting at the travel's end. */
static int test_probe_no_contact_and_limit(void)
{
    uint8_t seq;
    const frame_t *r;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    seq = z_probe(20000, 3000, IN(OHMIC));
    run_ms(600);
    r = last(DTHC_MSG_PROBE_RESULT, seq, 0);
    CHECK(r && dthc_probe_result_get_result(r->p) == DTHC_PROBE_NO_CONTACT, "no NO_CONTACT");
    CHECK(dthc_probe_result_get_stop_z_um(r->p) == 57000,
          "rest at %d", (int)dthc_probe_result_get_stop_z_um(r->p));
    seq = z_probe(60000, 90000, IN(OHMIC));
    run_ms(2000);
    r = last(DTHC_MSG_PROBE_RESULT, seq, 0);
    CHECK(r && dthc_probe_result_get_result(r->p) == DTHC_PROBE_LIMIT, "no LIMIT result");
    CHECK(dthc_probe_result_get_stop_z_um(r->p) == 0,
          "rest at %d", (int)dthc_probe_result_get_stop_z_um(r->p));
    return 0;
}

/* Z_PROBE_AWAY (1.2): up until every sensor of the set is released, stopped in the tick
 * that reads the last release, which it latches; RELEASED with that position and the rest
 * position above it by the overrun; the sensor that let go last. */
static int test_probe_away_stops_on_release_in_tick(void)
{
    uint8_t seq;
    unsigned mark;
    const frame_t *r;
    int32_t released, stop;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    cmd_u8(DTHC_MSG_OHMIC_SENSE, 1);
    F.inputs = IN(OHMIC) | IN(FLOAT);
    run_ms(1);
    seq = z_probe_away(5000, 20000, IN(OHMIC) | IN(FLOAT));
    CHECK(is_ack(seq, 0), "probe away not acknowledged");
    run_ms(300);
    CHECK(F.rate > 0, "probe away not moving up (rate %d)", (int)F.rate);
    F.inputs = IN(OHMIC); /* one of two released: not yet */
    run_ms(200);
    CHECK(F.rate > 0, "stopped with a sensor still active");
    CHECK(!last(DTHC_MSG_PROBE_RESULT, seq, 0), "PROBE_RESULT with a sensor still active");
    mark = n_out;
    F.inputs = 0;
    fake_run_us(F.next_tick_us - (uint32_t)F.now_us); /* exactly one tick */
    while (board_poll()) {
    }
    parse();
    CHECK(F.rate < 5000 * 200 / 1000, "no deceleration in the release tick (rate %d)",
          (int)F.rate);
    run_ms(50);
    r = last(DTHC_MSG_PROBE_RESULT, seq, mark);
    CHECK(r, "no PROBE_RESULT");
    released = dthc_probe_result_get_contact_z_um(r->p);
    stop = dthc_probe_result_get_stop_z_um(r->p);
    CHECK(dthc_probe_result_get_result(r->p) == DTHC_PROBE_RELEASED,
          "result %u", dthc_probe_result_get_result(r->p));
    CHECK(dthc_probe_result_get_sensor(r->p) == IN(OHMIC),
          "sensor 0x%04x", dthc_probe_result_get_sensor(r->p));
    CHECK(released >= 60000 + 2400 && released <= 60000 + 2600, "released at %d",
          (int)released);
    CHECK(stop >= released && stop <= released + 50, "stop %d vs release %d", (int)stop,
          (int)released);
    CHECK(F.rate == 0, "still moving after the result");
    CHECK(!(status_bits() & DTHC_STATUS_Z_BUSY), "Z busy after the result");
    return 0;
}

/* Z_PROBE_AWAY: NO_RELEASE at the travel's end, LIMIT at Z max, RELEASED at once when
 * nothing is active, ABORTED by Z_STOP; Z_PROBE's refusals (feed, travel, sensors, a
 * latched fault). */
static int test_probe_away_no_release_limit_and_refusals(void)
{
    uint8_t seq, detail = 0xEE;
    const frame_t *r;
    int32_t z;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    F.inputs = IN(FLOAT);
    run_ms(1);
    seq = z_probe_away(20000, 3000, IN(FLOAT));
    run_ms(600);
    r = last(DTHC_MSG_PROBE_RESULT, seq, 0);
    CHECK(r && dthc_probe_result_get_result(r->p) == DTHC_PROBE_NO_RELEASE,
          "no NO_RELEASE (%d)", r ? dthc_probe_result_get_result(r->p) : -1);
    CHECK(dthc_probe_result_get_sensor(r->p) == IN(FLOAT),
          "sensor 0x%04x", dthc_probe_result_get_sensor(r->p));
    CHECK(dthc_probe_result_get_stop_z_um(r->p) == 63000,
          "rest at %d", (int)dthc_probe_result_get_stop_z_um(r->p));
    CHECK(dthc_probe_result_get_contact_z_um(r->p) == 63000,
          "contact at %d", (int)dthc_probe_result_get_contact_z_um(r->p));
    seq = z_probe_away(60000, 90000, IN(FLOAT));
    run_ms(2000);
    r = last(DTHC_MSG_PROBE_RESULT, seq, 0);
    CHECK(r && dthc_probe_result_get_result(r->p) == DTHC_PROBE_LIMIT, "no LIMIT result");
    CHECK(dthc_probe_result_get_stop_z_um(r->p) == 100000,
          "rest at %d", (int)dthc_probe_result_get_stop_z_um(r->p));
    CHECK(!faults(), "a probe away at the soft limit latched 0x%04x", faults());
    z_move(80000, 60000);
    run_ms(1000);
    F.inputs = 0;
    run_ms(1);
    z = z_um();
    seq = z_probe_away(5000, 3000, IN(FLOAT) | IN(OHMIC));
    run_ms(5);
    r = last(DTHC_MSG_PROBE_RESULT, seq, 0);
    CHECK(r && dthc_probe_result_get_result(r->p) == DTHC_PROBE_RELEASED, "not RELEASED at once");
    CHECK(dthc_probe_result_get_sensor(r->p) == 0,
          "sensor 0x%04x", dthc_probe_result_get_sensor(r->p));
    CHECK(dthc_probe_result_get_contact_z_um(r->p) == z
              && dthc_probe_result_get_stop_z_um(r->p) == z,
          "moved");
    F.inputs = IN(FLOAT);
    run_ms(1);
    seq = z_probe_away(5000, 3000, IN(FLOAT));
    run_ms(100);
    send(DTHC_MSG_Z_STOP, NULL, 0);
    run_ms(50);
    r = last(DTHC_MSG_PROBE_RESULT, seq, 0);
    CHECK(r && dthc_probe_result_get_result(r->p) == DTHC_PROBE_ABORTED,
          "Z_STOP did not abort the probe away");
    CHECK(nak_code(z_probe_away(0, 3000, IN(FLOAT)), 0, &detail) == DTHC_NAK_OUT_OF_RANGE
              && detail == 0, "feed 0 accepted");
    CHECK(nak_code(z_probe_away(5000, 0, IN(FLOAT)), 0, &detail) == DTHC_NAK_OUT_OF_RANGE
              && detail == 1, "travel 0 accepted");
    CHECK(nak_code(z_probe_away(5000, 3000, IN(ARC_OK)), 0, &detail) == DTHC_NAK_OUT_OF_RANGE
              && detail == 2, "no contact sensor accepted");
    F.inputs = IN(FLOAT) | IN(ESTOP);
    run_ms(1);
    CHECK(nak_code(z_probe_away(5000, 3000, IN(FLOAT)), 0, &detail) == DTHC_NAK_FAULT_LATCHED
              && detail == DTHC_FAULT_ESTOP, "accepted with a fault latched");
    return 0;
}

/* A stream frame not newer than the last applied is ignored; expiry stops Z. */
static int test_z_velocity_stale_ignored_and_expiry(void)
{
    int32_t z0, z1, z2;
    hello();
    z0 = z_um();
    z_velocity(10, 3000, 40);
    run_ms(20);
    z_velocity(11, 3000, 40);
    run_ms(30);
    CHECK(F.rate > 0, "velocity not applied");
    CHECK(dthc_status_get_zvel_seq(status()->p) == 11, "zvel_seq not echoed");
    run_ms(40); /* 40 ms after seq 11: expired, decelerating */
    run_ms(20);
    CHECK(F.rate == 0 && !(status_bits() & DTHC_STATUS_Z_BUSY), "Z not stopped after expiry");
    z1 = z_um();
    CHECK(z1 > z0, "Z did not move up");
    z_velocity(10, 3000, 40); /* older */
    z_velocity(11, 3000, 40); /* same */
    run_ms(30);
    z2 = z_um();
    CHECK(z2 == z1 && F.rate == 0, "a stale Z_VELOCITY was applied");
    CHECK(dthc_status_get_zvel_seq(status()->p) == 11, "stale frame changed zvel_seq");
    z_velocity((uint16_t)(11 + 40000), 3000, 40); /* "newer" by > 32767: older */
    run_ms(10);
    CHECK(F.rate == 0, "a wrapped-older frame was applied");
    z_velocity(12, -3000, 40);
    run_ms(10);
    CHECK(F.rate < 0, "a newer frame was not applied");
    return 0;
}

/* A velocity stream into a soft limit stops at it and latches Z_LIMIT. */
static int test_soft_limit_latches_z_limit(void)
{
    uint16_t s;
    unsigned i;
    const frame_t *f;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    for (i = 0; i < 120; i++) {
        z_velocity((uint16_t)(100 + i), 60000, 50);
        run_ms(10);
    }
    f = last(DTHC_MSG_FAULT, -1, 0);
    CHECK(f && dthc_fault_get_code(f->p) == DTHC_FAULT_Z_LIMIT && dthc_fault_get_detail(f->p) == 1,
          "no Z_LIMIT max fault");
    CHECK(z_um() == 100000, "Z at %d, not at the limit", (int)z_um());
    s = faults();
    CHECK(s & FAULT(Z_LIMIT), "Z_LIMIT not latched");
    return 0;
}

/* Move targets outside the soft limits are refused; while latched only upward moves. */
static int test_move_limits_and_upward_only(void)
{
    uint8_t seq, d;
    unsigned mark = 0;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    seq = z_move(100001, 10000);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 0, "target above max");
    seq = z_move(-1, 10000);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 0, "target below min");
    seq = z_move(50000, 0);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 1, "feed 0");
    F.inputs = IN(BREAKAWAY);
    run_ms(2);
    F.inputs = 0;
    seq = z_move(50000, 10000);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_FAULT_LATCHED && d == DTHC_FAULT_BREAKAWAY,
          "downward move while latched");
    seq = z_move(70000, 30000);
    CHECK(is_ack(seq, mark), "upward move refused while latched");
    run_ms(1000);
    CHECK(motion_result(seq, 0) == DTHC_MOTION_REACHED, "upward move not reached");
    return 0;
}

/* A move follows a trapezoid: accel limit respected, reaches the target exactly. */
static int test_move_trapezoid(void)
{
    uint8_t seq;
    int32_t prev = 0, max_rate = 0;
    unsigned i;
    const frame_t *done;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    seq = z_move(20000, 60000);
    for (i = 0; i < 1500; i++) {
        int32_t r = F.rate;
        int32_t dr = r - prev;
        CHECK(dr <= 131 && dr >= -131,
              "rate step %d steps/s in one tick (tick %u, rate %d, z %d)",
              (int)dr, i, (int)r, (int)F.steps);
        if (-r > max_rate) {
            max_rate = -r;
        }
        prev = r;
        run_ms(1);
    }
    done = last(DTHC_MSG_MOTION_DONE, seq, 0);
    CHECK(done && dthc_motion_done_get_result(done->p) == DTHC_MOTION_REACHED,
          "no MOTION_DONE REACHED");
    CHECK(dthc_motion_done_get_z_um(done->p) == 20000,
          "done at %d", (int)dthc_motion_done_get_z_um(done->p));
    CHECK(max_rate == 12000, "top speed %d steps/s", (int)max_rate);
    CHECK(z_um() == 20000, "rest at %d", (int)z_um());
    return 0;
}

/* Z_STOP and superseding report STOPPED and SUPERSEDED; QUERY(MOTION_DONE) re-sends. */
static int test_stop_supersede_query(void)
{
    uint8_t a, b, stop, q;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    a = z_move(90000, 20000);
    run_ms(100);
    b = z_move(10000, 20000);
    CHECK(motion_result(a, 0) == DTHC_MOTION_SUPERSEDED, "no SUPERSEDED");
    run_ms(100);
    stop = send(DTHC_MSG_Z_STOP, NULL, 0);
    CHECK(is_ack(stop, 0), "Z_STOP not acknowledged");
    CHECK(motion_result(b, 0) == DTHC_MOTION_STOPPED, "no STOPPED");
    run_ms(100);
    CHECK(F.rate == 0, "not stopped");
    q = cmd_u8(DTHC_MSG_QUERY, DTHC_QUERY_MOTION_DONE);
    CHECK(motion_result(q, 0) == DTHC_MOTION_STOPPED,
          "QUERY(MOTION_DONE) did not re-send with its seq");
    return 0;
}

/* E-stop and breakaway latch, torch off; reset refused while active, then cleared. */
static int test_estop_breakaway_latch(void)
{
    uint8_t seq, d;
    unsigned mark;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    cmd_u8(DTHC_MSG_TORCH, 1);
    F.inputs = IN(ESTOP);
    run_ms(1);
    CHECK(!F.torch, "torch on after E-stop");
    CHECK(faults() & FAULT(ESTOP), "ESTOP not latched");
    mark = n_out;
    seq = cmd_u16(DTHC_MSG_FAULT_RESET, FAULT(ESTOP));
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_FAULT_ACTIVE && d == DTHC_FAULT_ESTOP,
          "reset while E-stop active not refused");
    F.inputs = IN(BREAKAWAY);
    run_ms(1);
    CHECK(faults() == (FAULT(ESTOP) | FAULT(BREAKAWAY)), "breakaway not latched");
    seq = cmd_u16(DTHC_MSG_FAULT_RESET, 0xFFFF);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_FAULT_ACTIVE && d == DTHC_FAULT_BREAKAWAY,
          "reset while breakaway active");
    CHECK(faults() == (FAULT(ESTOP) | FAULT(BREAKAWAY)), "a refused reset cleared something");
    F.inputs = 0;
    run_ms(1);
    seq = cmd_u16(DTHC_MSG_FAULT_RESET, 0xFFFF);
    CHECK(is_ack(seq, mark) && faults() == 0, "reset after release failed");
    return 0;
}

/* Every edge an EVENT; EVENT and FAULT share the counter. */
static int test_events_and_shared_counter(void)
{
    unsigned mark, i;
    uint32_t expect = 0;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    mark = n_out;
    F.inputs = IN(ARC_OK) | IN(FLOAT);
    run_ms(1);
    F.inputs = IN(FLOAT);
    run_ms(1);
    F.inputs = IN(FLOAT) | IN(BREAKAWAY);
    run_ms(1);
    for (i = mark; i < n_out; i++) {
        if (out[i].type == DTHC_MSG_EVENT || out[i].type == DTHC_MSG_FAULT) {
            uint32_t c = out[i].type == DTHC_MSG_EVENT ? dthc_event_get_counter(out[i].p)
                                                        : dthc_fault_get_counter(out[i].p);
            CHECK(c == ++expect, "counter %u, expected %u", (unsigned)c, (unsigned)expect);
        }
    }
    CHECK(expect == 5, "%u events+faults, expected 4 edges and 1 fault", (unsigned)expect);
    CHECK(count(DTHC_MSG_EVENT, -1, mark) == 4, "edges");
    return 0;
}

/* Ohmic contact is reported only while ohmic sensing is on. */
static int test_ohmic_only_while_sensing(void)
{
    hello();
    F.inputs = IN(OHMIC);
    run_ms(2);
    CHECK(!(dthc_status_get_inputs(status()->p) & IN(OHMIC)),
          "ohmic contact seen with sensing off");
    cmd_u8(DTHC_MSG_OHMIC_SENSE, 1);
    run_ms(2);
    CHECK(dthc_status_get_inputs(status()->p) & IN(OHMIC),
          "ohmic contact not seen with sensing on");
    return 0;
}

/* CONFIGURE out of range: NAK with the field's index, nothing applied. */
static int test_configure_out_of_range(void)
{
    uint8_t seq, d;
    unsigned mark = 0;
    const frame_t *h;
    hello();
    seq = configure(50, 5, 0, 0, 0, 0, 0.01f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 0, "rate 50: field %u", d);
    seq = configure(1000, 0, 0, 0, 0, 0, 0.01f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 1, "batch 0");
    seq = configure(1000, 5, 4, 0, 0, 0, 0.01f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 2, "filter kind 4");
    seq = configure(1000, 5, 1, 33, 0, 0, 0.01f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 3, "moving average 33");
    seq = configure(1000, 5, 2, 501, 0, 0, 0.01f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 3, "low-pass 501 Hz");
    seq = configure(1000, 5, 0, 0, 1001, 0, 0.01f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 4, "arc_lost 1001");
    seq = configure(500, 10, 0, 0, 0, 0, 0.0f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 6, "scale 0");
    seq = configure(500, 10, 0, 0, 0, 0, -1.0f);
    CHECK(nak_code(seq, mark, &d) == DTHC_NAK_OUT_OF_RANGE && d == 6, "scale -1");
    seq = cmd_u8(DTHC_MSG_QUERY, DTHC_QUERY_HELLO_INFO);
    h = last(DTHC_MSG_HELLO_INFO, seq, 0);
    CHECK(dthc_hello_info_get_sample_rate_hz(h->p) == 1000
              && dthc_hello_info_get_batch_size(h->p) == 5,
          "a refused CONFIGURE applied");
    CHECK(F.period_us == 1000, "tick period changed");
    seq = configure(500, 10, 0, 0, 0, 0, 0.01f);
    CHECK(is_ack(seq, mark) && F.period_us == 2000, "valid CONFIGURE not applied");
    return 0;
}

/* Calibration and filters on what SAMPLES carry. */
static uint16_t last_sample(void)
{
    const frame_t *s = last(DTHC_MSG_SAMPLES, -1, 0);
    return s ? dthc_samples_get_samples_cv(s->p, (uint8_t)((s->len - DTHC_SAMPLES_SIZE) / 2 - 1))
             : 0xFFFF;
}

static int test_calibration_and_filters(void)
{
    const frame_t *s;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    /* volts = (raw - 1000) * 0.02: raw 13500 -> 250.00 V */
    configure(1000, 1, DTHC_FILTER_NONE, 0, 0, 1000, 0.02f);
    F.arc_raw = 13500;
    run_ms(1);
    CHECK(last_sample() == 25000, "calibrated %u, expected 25000", last_sample());
    s = last(DTHC_MSG_SAMPLES, -1, 0);
    CHECK(s->len == DTHC_SAMPLES_SIZE + 2 && dthc_samples_get_period_us(s->p) == 1000
              && dthc_samples_get_xy_speed_dmm_s(s->p) == DTHC_XY_SPEED_UNKNOWN,
          "SAMPLES header");
    /* moving average over 4 */
    configure(1000, 1, DTHC_FILTER_MOVING_AVERAGE, 4, 0, 0, 0.01f);
    F.arc_raw = 10000;
    run_ms(4);
    F.arc_raw = 12000;
    run_ms(2);
    CHECK(last_sample() == 11000, "moving average %u, expected 11000", last_sample());
    run_ms(2);
    CHECK(last_sample() == 12000, "moving average settled at %u", last_sample());
    /* median of three rejects a one-sample spike */
    configure(1000, 1, DTHC_FILTER_MEDIAN3, 0, 0, 0, 0.01f);
    F.arc_raw = 12000;
    run_ms(3);
    F.arc_raw = 40000;
    run_ms(1);
    CHECK(last_sample() == 12000, "median3 passed a spike: %u", last_sample());
    F.arc_raw = 12000;
    run_ms(1);
    CHECK(last_sample() == 12000, "median3 %u", last_sample());
    /* low-pass at 10 Hz, 1 kHz: a step reaches 1 - 1/e after about RC = 15.9 ms */
    configure(1000, 1, DTHC_FILTER_LOW_PASS, 10, 0, 0, 0.01f);
    F.arc_raw = 0;
    run_ms(1);
    F.arc_raw = 10000;
    run_ms(16);
    CHECK(last_sample() > 6000 && last_sample() < 6600, "low-pass after RC: %u", last_sample());
    run_ms(200);
    CHECK(last_sample() > 9990, "low-pass settled at %u", last_sample());
    /* clamped to 0..655.35 V */
    configure(1000, 1, DTHC_FILTER_NONE, 0, 0, 20000, 0.01f);
    F.arc_raw = 100;
    run_ms(1);
    CHECK(last_sample() == 0, "negative volts not clamped to 0: %u", last_sample());
    return 0;
}

/* A batch completed while a short frame is arriving waits for it (its reply goes out
 * first), but for at most 0.3 ms: a frame that never ends does not stop the samples. */
static int test_batch_waits_for_a_short_frame(void)
{
    uint8_t what = DTHC_QUERY_STATUS;
    uint8_t wire[DTHC_MAX_WIRE_FRAME];
    size_t n = dthc_encode_frame(DTHC_MSG_QUERY, 9, &what, 1, wire, sizeof wire);
    unsigned mark, i, status_at = 0, samples_at = 0;
    run_ms(4); /* 4 of the batch's 5 samples */
    mark = n_out;
    fake_rx(wire, 3); /* the QUERY's first bytes */
    while (board_poll()) {
    }
    fake_run_us(1000); /* the 5th sample: the batch is complete */
    while (board_poll()) {
    }
    parse();
    CHECK(count(DTHC_MSG_SAMPLES, -1, mark) == 0, "a batch went out during the frame");
    fake_rx(wire + 3, (unsigned)n - 3u);
    while (board_poll()) {
    }
    parse();
    for (i = mark; i < n_out; i++) {
        if (out[i].type == DTHC_MSG_STATUS && !status_at) {
            status_at = i + 1;
        }
        if (out[i].type == DTHC_MSG_SAMPLES && !samples_at) {
            samples_at = i + 1;
        }
    }
    CHECK(status_at && samples_at && status_at < samples_at,
          "STATUS at %u, SAMPLES at %u: the reply first", status_at, samples_at);

    run_ms(4);
    mark = n_out;
    fake_rx(wire, 3); /* a frame that never ends */
    while (board_poll()) {
    }
    fake_run_us(1000);
    while (board_poll()) {
    }
    parse();
    CHECK(count(DTHC_MSG_SAMPLES, -1, mark) == 0, "the batch did not wait at all");
    fake_run_us(400);
    while (board_poll()) {
    }
    parse();
    CHECK(count(DTHC_MSG_SAMPLES, -1, mark) == 1, "the batch waited more than 0.3 ms");
    return 0;
}

/* Batches: N samples, t0 steps by N x period, stream_seq counts. */
static int test_batches(void)
{
    unsigned mark, i, n = 0;
    uint32_t t_prev = 0;
    uint16_t seq_prev = 0;
    hello();
    mark = n_out;
    run_ms(100);
    for (i = mark; i < n_out; i++) {
        if (out[i].type == DTHC_MSG_SAMPLES) {
            uint32_t t0 = dthc_samples_get_t0_us(out[i].p);
            uint16_t sseq = dthc_samples_get_stream_seq(out[i].p);
            CHECK(out[i].len == DTHC_SAMPLES_SIZE + 2 * 5, "batch of %u bytes", out[i].len);
            if (n) {
                CHECK(t0 - t_prev == 5000, "t0 step %u", (unsigned)(t0 - t_prev));
                CHECK((uint16_t)(sseq - seq_prev) == 1, "stream_seq gap");
            }
            t_prev = t0;
            seq_prev = sseq;
            n++;
        }
    }
    CHECK(n == 20, "%u batches in 100 ms", n);
    return 0;
}

/* A completed batch that finds the transmit ring full (replies to a burst of queries)
 * waits for room and goes later: no stream_seq gap, no SAMPLE_OVERFLOW. */
/* The SAMPLES batches sent since `mark` follow each other with no stream_seq gap and no
 * SAMPLE_OVERFLOW; their count in *n. */
static int batches_unbroken(unsigned mark, unsigned *n)
{
    unsigned i;
    uint16_t seq_prev = 0;
    *n = 0;
    for (i = mark; i < n_out; i++) {
        if (out[i].type != DTHC_MSG_SAMPLES) {
            continue;
        }
        CHECK(!(dthc_samples_get_status(out[i].p) & DTHC_STATUS_SAMPLE_OVERFLOW),
              "SAMPLE_OVERFLOW in batch %u", *n);
        CHECK(!*n || (uint16_t)(dthc_samples_get_stream_seq(out[i].p) - seq_prev) == 1,
              "stream_seq gap");
        seq_prev = dthc_samples_get_stream_seq(out[i].p);
        (*n)++;
    }
    return 0;
}

static int test_batch_waits_for_room_in_the_transmit_ring(void)
{
    unsigned mark, n;
    hello();
    run_ms(10);
    mark = n_out;
    F.tx_cap = F.tx_len; /* no room for 7 ms: a batch completes meanwhile, not two */
    run_ms(7);
    F.tx_cap = sizeof F.tx;
    run_ms(20);
    if (batches_unbroken(mark, &n)) {
        return 1;
    }
    CHECK(n >= 4, "%u batches in 27 ms", n);
    return 0;
}

/* A bunched burst of STATUS queries (a host that lagged sends 30 at once) into a 256-byte
 * transmit ring that drains at 1 Mbaud: every query is answered, and no batch is lost
 * (no stream_seq gap, no SAMPLE_OVERFLOW): the replies leave the next batch its room. */
static int test_a_burst_of_queries_leaves_room_for_the_batches(void)
{
    uint8_t wire[16], what = DTHC_QUERY_STATUS;
    unsigned mark, i, k, n = 0, replies = 0;
    uint32_t drained = 0;
    hello();
    run_ms(10);
    drained = F.tx_len; /* the ring is empty: what was sent so far is on the wire */
    mark = n_out;
    for (k = 0; k < 30; k++) {
        size_t len = dthc_encode_frame(DTHC_MSG_QUERY, (uint8_t)(100 + k), &what, 1, wire,
                                       sizeof wire);
        fake_rx(wire, (unsigned)len);
    }
    for (k = 0; k < 400; k++) { /* 40 ms in steps of 100 us: 10 bytes leave the ring */
        drained = drained + 10u < F.tx_len ? drained + 10u : F.tx_len;
        F.tx_cap = drained + 256u;
        fake_run_us(100);
        while (board_poll()) {
        }
    }
    F.tx_cap = sizeof F.tx;
    parse();
    for (i = mark; i < n_out; i++) {
        replies += out[i].type == DTHC_MSG_STATUS;
    }
    if (batches_unbroken(mark, &n)) {
        return 1;
    }
    CHECK(replies == 30, "%u of 30 queries answered", replies);
    CHECK(n >= 7, "%u batches in 40 ms", n);
    return 0;
}

/* SET_CURRENT is refused (no CURRENT_OUT); SET_LEASE range. */
static int test_unsupported_and_lease_range(void)
{
    uint8_t seq, d;
    hello();
    seq = cmd_u16(DTHC_MSG_SET_CURRENT, 450);
    CHECK(nak_code(seq, 0, &d) == DTHC_NAK_UNSUPPORTED && d == 5, "SET_CURRENT");
    seq = cmd_u16(DTHC_MSG_SET_LEASE, 19);
    CHECK(nak_code(seq, 0, &d) == DTHC_NAK_OUT_OF_RANGE, "lease 19");
    seq = cmd_u16(DTHC_MSG_SET_LEASE, 2001);
    CHECK(nak_code(seq, 0, &d) == DTHC_NAK_OUT_OF_RANGE, "lease 2001");
    return 0;
}

/* A board with an XY speed input and a current output (the mock device's build): SAMPLES
 * carry the speed read at the batch, SET_CURRENT is applied and reported by STATUS. The
 * same logic without the capabilities: 0xFFFF and NAK UNSUPPORTED (the AVR builds). */
static const board_config_t CONFIG_XY = {
    "DTHC-TEST-0002",
    DTHC_CAP_XY_SPEED | DTHC_CAP_CURRENT_OUT | DTHC_CAP_OHMIC | DTHC_CAP_FLOAT,
    0, 100000, 60000, 60000, 650000, 200, DTHC_RESET_POWER_ON, 102000,
};

static int test_xy_speed_and_current_out(void)
{
    unsigned mark;
    const frame_t *f;
    uint8_t seq;
    F.xy_speed_dmm_s = 417; /* 41.7 mm/s: ignored without the capability */
    hello();
    mark = n_out;
    run_ms(10);
    f = last(DTHC_MSG_SAMPLES, -1, mark);
    CHECK(f && dthc_samples_get_xy_speed_dmm_s(f->p) == DTHC_XY_SPEED_UNKNOWN,
          "no XY_SPEED: 0xFFFF");
    board_init(&CONFIG_XY, 0xC0FFEE02u);
    hello();
    mark = n_out;
    run_ms(10);
    f = last(DTHC_MSG_SAMPLES, -1, mark);
    CHECK(f && dthc_samples_get_xy_speed_dmm_s(f->p) == 417, "XY speed carried");
    F.xy_speed_dmm_s = 0;
    mark = n_out;
    run_ms(5);
    f = last(DTHC_MSG_SAMPLES, -1, mark);
    CHECK(f && dthc_samples_get_xy_speed_dmm_s(f->p) == 0, "standing still: 0");
#if BOARD_CURRENT_OUT
    seq = cmd_u16(DTHC_MSG_SET_CURRENT, 450);
    CHECK(is_ack(seq, 0) && F.current_da == 450, "SET_CURRENT applied");
    mark = n_out;
    seq = cmd_u8(DTHC_MSG_QUERY, DTHC_QUERY_STATUS);
    f = last(DTHC_MSG_STATUS, seq, mark);
    CHECK(f && dthc_status_get_current_da(f->p) == 450, "STATUS current_da");
#else
    seq = cmd_u16(DTHC_MSG_SET_CURRENT, 450);
    CHECK(nak_code(seq, 0, NULL) == DTHC_NAK_UNSUPPORTED, "no BOARD_CURRENT_OUT build");
#endif
    return 0;
}

/* Board-side ARC_LOST: torch on, arc OK seen, then gone for arc_lost_ms. */
static int test_arc_lost(void)
{
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    configure(1000, 5, 0, 0, 50, 0, 0.01f);
    cmd_u8(DTHC_MSG_TORCH, 1);
    run_ms(100);
    CHECK(F.torch && !faults(), "no arc OK yet must not latch");
    F.inputs = IN(ARC_OK);
    run_ms(10);
    F.inputs = 0;
    run_ms(49);
    CHECK(F.torch, "ARC_LOST before arc_lost_ms");
    run_ms(2);
    CHECK(!F.torch && (faults() & FAULT(ARC_LOST)), "ARC_LOST not latched");
    return 0;
}

/* A limit switch blocks motion towards it at once and latches Z_LIMIT when driven into;
 * moving away (up from the min switch) stays allowed, and FAULT_RESET clears it. */
static int test_limit_switch_stops_and_latches(void)
{
    uint8_t seq;
    const frame_t *f;
    int32_t steps;
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    z_move(20000, 20000);
    run_ms(300);
    CHECK(F.rate < 0, "not moving down");
    F.inputs = IN(Z_LIMIT_MIN);
    run_ms(1);
    steps = F.steps;
    f = last(DTHC_MSG_FAULT, -1, 0);
    CHECK(f && dthc_fault_get_code(f->p) == DTHC_FAULT_Z_LIMIT && dthc_fault_get_detail(f->p) == 0,
          "no Z_LIMIT min fault");
    CHECK(F.lo == steps, "the step generator may still step down (lo %d, at %d)", (int)F.lo,
          (int)steps);
    run_ms(50);
    CHECK(F.steps == steps, "Z moved %d steps past the switch", (int)(steps - F.steps));
    seq = z_move(dthc_status_get_z_um(status()->p) + 5000, 20000);
    CHECK(is_ack(seq, 0), "moving up off the switch refused");
    F.inputs = 0;
    run_ms(600);
    seq = cmd_u16(DTHC_MSG_FAULT_RESET, FAULT(Z_LIMIT));
    CHECK(is_ack(seq, 0) && !faults(), "Z_LIMIT not cleared");
    /* The max switch (the home switch) latches too, outside Z_HOME. */
    n_out = parsed_to = 0;
    z_move(90000, 20000);
    run_ms(300);
    CHECK(F.rate > 0, "not moving up");
    F.inputs = IN(Z_LIMIT_MAX);
    run_ms(1);
    steps = F.steps;
    f = last(DTHC_MSG_FAULT, -1, 0);
    CHECK(f && dthc_fault_get_code(f->p) == DTHC_FAULT_Z_LIMIT && dthc_fault_get_detail(f->p) == 1,
          "no Z_LIMIT max fault");
    CHECK(F.hi == steps, "the step generator may still step up (hi %d, at %d)", (int)F.hi,
          (int)steps);
    return 0;
}

/* Frames the receiver lost whole (a full receive buffer: hal_uart_rx_frames_lost) are
 * framing errors in STATUS, beside the codec's own: every bad frame counted once. */
static int test_frames_lost_in_the_receiver_count_as_framing_errors(void)
{
    static const uint8_t bad[] = {0x06, 0x11, 0x22, 0x33, 0x44, 0x55, 0x00}; /* CRC wrong */
    fake_rx(bad, sizeof bad);
    while (board_poll()) {
    }
    F.rx_frames_lost = 3;
    CHECK(dthc_status_get_rx_crc_errors(status()->p) == 1, "the bad CRC not counted");
    CHECK(dthc_status_get_rx_framing_errors(status()->p) == 3,
          "framing errors %u, expected the 3 frames lost in the receiver",
          (unsigned)dthc_status_get_rx_framing_errors(status()->p));
    return 0;
}

/* A STATUS query whose reply meets a full transmit ring (the ring filled while the query
 * arrived): the main loop neither waits for room nor drops the reply; the reply goes out at
 * the first poll with room, before the next frame is read. */
static int test_a_reply_waits_for_room_without_waiting_in_the_loop(void)
{
    uint8_t wire[16], what = DTHC_QUERY_STATUS;
    size_t len;
    unsigned mark;
    hello();
    run_ms(10);
    mark = n_out;
    len = dthc_encode_frame(DTHC_MSG_QUERY, 77, &what, 1, wire, sizeof wire);
    fake_rx(wire, 3); /* its first bytes, read while there is room */
    while (board_poll()) {
    }
    F.tx_cap = F.tx_len; /* then the ring is full */
    fake_rx(wire + 3, (unsigned)len - 3u);
    len = dthc_encode_frame(DTHC_MSG_QUERY, 78, &what, 1, wire, sizeof wire);
    fake_rx(wire, (unsigned)len);
    while (board_poll()) {
    }
    parse();
    CHECK(!last(DTHC_MSG_STATUS, 77, mark), "answered without room");
    CHECK(F.rx_pos < F.rx_len, "the next query read while the first reply waits");
    F.tx_cap = sizeof F.tx;
    while (board_poll()) {
    }
    parse();
    CHECK(last(DTHC_MSG_STATUS, 77, mark) && last(DTHC_MSG_STATUS, 78, mark),
          "a reply lost: 77 %d, 78 %d", last(DTHC_MSG_STATUS, 77, mark) != NULL,
          last(DTHC_MSG_STATUS, 78, mark) != NULL);
    return 0;
}

typedef int (*test_fn)(void);

/* --- Z_HOME (protocol 1.3) ------------------------------------------------------------ */

static uint8_t z_home(uint32_t seek, uint32_t locate, uint32_t backoff, uint32_t travel,
                      uint16_t timeout_ms)
{
    uint8_t p[DTHC_Z_HOME_SIZE];
    dthc_z_home_put_seek_um_s(p, seek);
    dthc_z_home_put_locate_um_s(p, locate);
    dthc_z_home_put_backoff_um(p, backoff);
    dthc_z_home_put_max_travel_um(p, travel);
    dthc_z_home_put_timeout_ms(p, timeout_ms);
    return send(DTHC_MSG_Z_HOME, p, DTHC_Z_HOME_SIZE);
}

/* A home switch where the step count reaches switch_steps (-1: none), read every 50 us;
 * run until HOME_RESULT seq arrives or ms pass, a heartbeat every 100 ms. Returns the
 * HOME_RESULT, or NULL. *peak: the highest step count seen. */
static const frame_t *home_until(uint8_t seq, uint32_t ms, int32_t switch_steps, int32_t *peak)
{
    uint32_t t;
    int k;
    for (t = 0; t < ms; t++) {
        for (k = 0; k < 20; k++) {
            F.inputs = (uint16_t)((switch_steps >= 0 && F.steps >= switch_steps)
                                      ? (F.inputs | IN(Z_LIMIT_MAX))
                                      : (F.inputs & ~IN(Z_LIMIT_MAX)));
            fake_run_us(50u);
            if (peak && F.steps > *peak) {
                *peak = F.steps;
            }
        }
        while (board_poll()) {
        }
        if (t % 100 == 99) {
            send(DTHC_MSG_HEARTBEAT, NULL, 0);
        }
        parse();
        if (last(DTHC_MSG_HOME_RESULT, seq, 0)) {
            return last(DTHC_MSG_HOME_RESULT, seq, 0);
        }
    }
    return NULL;
}

static void quiet_batches(void)
{
    hello();
    cmd_u16(DTHC_MSG_SET_LEASE, 2000);
    configure(1000, 100, DTHC_FILTER_NONE, 0, 0, 0, 0.01f); /* fewer frames to parse */
}

/* Seek, back off, re-seek slowly: the trip becomes the home position (102 mm), Z parks
 * 2 mm below it, HOMED is set, the switch latches nothing; a second homing finds the same
 * position within a step (shift_um: the repeatability), and the soft limits hold from it. */
static int test_home_finds_the_switch_and_sets_z(void)
{
    const int32_t sw = 4000; /* the board's count at the trip: 80 mm on its boot Z */
    const frame_t *f;
    int32_t peak = 0, shift;
    uint8_t seq;
    quiet_batches();
    CHECK(!(status_bits() & DTHC_STATUS_HOMED), "HOMED set at power-on");
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    CHECK(is_ack(seq, 0), "Z_HOME refused");
    f = home_until(seq, 15000, sw, &peak);
    CHECK(f, "no HOME_RESULT");
    CHECK(dthc_home_result_get_result(f->p) == DTHC_HOME_HOMED, "result %u",
          (unsigned)dthc_home_result_get_result(f->p));
    shift = dthc_home_result_get_shift_um(f->p);
    CHECK(shift >= 22000 - 10 && shift <= 22000 + 10, "shift %ld, not 22 mm", (long)shift);
    CHECK(dthc_home_result_get_z_um(f->p) == 100000, "parked at %ld",
          (long)dthc_home_result_get_z_um(f->p));
    CHECK(z_um() == 100000 && (status_bits() & DTHC_STATUS_HOMED), "not homed at 100 mm");
    CHECK(!faults(), "the home switch latched a fault (%#x)", (unsigned)faults());
    CHECK(peak - sw < 40, "ran %d steps past the switch", (int)(peak - sw));
    /* Home again: the same switch, the same count (a board that lost no step). */
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    f = home_until(seq, 15000, sw, NULL);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_HOMED, "second homing failed");
    shift = dthc_home_result_get_shift_um(f->p);
    CHECK(shift >= -10 && shift <= 10, "second homing moved Z by %ld um", (long)shift);
    /* The soft limits now hold from the home position: Z max is 100 mm, the switch 102. */
    seq = z_move(100001, 20000);
    CHECK(nak_code(seq, 0, NULL) == DTHC_NAK_OUT_OF_RANGE, "a move above Z max accepted");
    return 0;
}

/* Started on the switch: off it first, then the cycle. */
static int test_home_starting_on_the_switch_backs_off_first(void)
{
    const frame_t *f;
    uint8_t seq;
    quiet_batches();
    F.steps = 4100; /* the carriage sits on the switch (a hand put it there) */
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    f = home_until(seq, 15000, 4000, NULL);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_HOMED, "not homed from the switch");
    /* the switch at count 4000 is 102 mm now: parked 2 mm (400 steps) below it */
    CHECK(z_um() == 100000 && F.steps >= 3600 - 2 && F.steps <= 3600 + 2,
          "parked at %ld (steps %d)", (long)z_um(), (int)F.steps);
    return 0;
}

/* No switch within max travel: NOT_FOUND, unhomed, stopped near start + travel; a cycle
 * that outlasts its timeout: TIMEOUT; Z_STOP, a new move or the lease: ABORTED. */
static int test_home_ends_not_found_timeout_and_aborted(void)
{
    const frame_t *f;
    uint8_t seq;
    int32_t z;
    quiet_batches();
    seq = z_home(20000, 2000, 2000, 10000, 15000);
    f = home_until(seq, 5000, -1, NULL);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_NOT_FOUND, "not NOT_FOUND");
    z = z_um();
    CHECK(z >= 69900 && z <= 70000, "stopped at %ld, not within 10 mm of 60", (long)z);
    CHECK(!(status_bits() & DTHC_STATUS_HOMED), "HOMED after NOT_FOUND");
    seq = z_home(1000, 1000, 2000, 150000, 300); /* 1 mm/s: never there in 0.3 s */
    f = home_until(seq, 2000, -1, NULL);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_TIMEOUT, "not TIMEOUT");
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    home_until(seq, 200, -1, NULL);
    send(DTHC_MSG_Z_STOP, NULL, 0);
    run_ms(1);
    f = last(DTHC_MSG_HOME_RESULT, seq, 0);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_ABORTED, "Z_STOP: not ABORTED");
    run_ms(200);
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    home_until(seq, 200, -1, NULL);
    z_move(50000, 20000);
    run_ms(1);
    f = last(DTHC_MSG_HOME_RESULT, seq, 0);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_ABORTED, "Z_MOVE: not ABORTED");
    run_ms(3000);
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    run_ms(2100); /* the host falls silent: the lease ends homing */
    f = last(DTHC_MSG_HOME_RESULT, seq, 0);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_ABORTED, "lease: not ABORTED");
    CHECK(faults() & FAULT(LEASE_EXPIRED), "no LEASE_EXPIRED");
    /* the last HOME_RESULT again, on asking */
    seq = cmd_u8(DTHC_MSG_QUERY, DTHC_QUERY_HOME_RESULT);
    f = last(DTHC_MSG_HOME_RESULT, seq, 0);
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_ABORTED, "QUERY HOME_RESULT");
    return 0;
}

/* A home switch that never opens (stuck, or wired closed): the back-off down ends
 * NO_RELEASE at Z min, not max_travel_um down (200 mm here: 140 mm into the plate). */
static int test_home_with_a_switch_that_never_opens_stops_at_z_min(void)
{
    const frame_t *f = NULL;
    uint8_t seq;
    uint32_t t;
    int32_t z;
    quiet_batches();
    F.inputs |= IN(Z_LIMIT_MAX);
    seq = z_home(20000, 2000, 2000, 200000, 15000);
    for (t = 0; t < 12000 && !f; t++) {
        run_ms(1);
        if (t % 100 == 99) {
            send(DTHC_MSG_HEARTBEAT, NULL, 0);
        }
        f = last(DTHC_MSG_HOME_RESULT, seq, 0);
    }
    CHECK(f && dthc_home_result_get_result(f->p) == DTHC_HOME_NO_RELEASE, "not NO_RELEASE");
    z = z_um();
    CHECK(z >= 0 && z <= 100, "homing left Z at %ld, not at Z min 0", (long)z);
    CHECK(!(status_bits() & DTHC_STATUS_HOMED), "HOMED after NO_RELEASE");
    return 0;
}

/* The refusals of PROTOCOL.md 6.1, each naming its field; nothing moves. */
static int test_home_refusals(void)
{
    uint8_t seq, detail = 0xFF;
    quiet_batches();
    seq = z_home(0, 2000, 2000, 150000, 15000);
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_OUT_OF_RANGE && detail == 0, "zero seek");
    seq = z_home(20000, 0, 2000, 150000, 15000);
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_OUT_OF_RANGE && detail == 1, "zero locate");
    seq = z_home(20000, 2000, 0, 150000, 15000);
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_OUT_OF_RANGE && detail == 2, "zero backoff");
    seq = z_home(20000, 2000, 103000, 150000, 15000); /* parks below Z min */
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_OUT_OF_RANGE && detail == 2, "backoff too far");
    seq = z_home(20000, 2000, 2000, 0, 15000);
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_OUT_OF_RANGE && detail == 3, "zero travel");
    seq = z_home(20000, 2000, 2000, 150000, 0);
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_OUT_OF_RANGE && detail == 4, "zero timeout");
    run_ms(20);
    CHECK(F.steps == 0 && F.rate == 0, "a refused Z_HOME moved Z");
    F.inputs = IN(ESTOP);
    run_ms(2);
    F.inputs = 0;
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_FAULT_LATCHED, "homing with a fault latched");
    /* a board without the HOMING capability (no home switch) */
    fake_reset();
    board_init(&CONFIG_XY, 1u);
    dthc_rx_init(&host_rx);
    n_out = parsed_to = 0;
    hello();
    seq = z_home(20000, 2000, 2000, 150000, 15000);
    CHECK(nak_code(seq, 0, &detail) == DTHC_NAK_UNSUPPORTED && detail == 9, "no HOMING: %d",
          nak_code(seq, 0, NULL));
    return 0;
}

static const struct {
    const char *name;
    test_fn fn;
} TESTS[] = {
#define T(n) {#n, test_##n}
    T(lease_expiry_within_one_tick),
    T(lease_runs_from_the_frames_arrival),
    T(lease_holds_with_the_clock_behind_the_tick),
    T(a_failed_self_check_latches_internal_with_its_code),
    T(frames_after_expiry_do_not_revive),
    T(idle_lease_lapse_reported_once_not_latched),
    T(idle_lease_lapse_reported_again_after_renewal),
    T(lease_latches_when_not_at_rest),
    T(fault_rereported_every_250ms),
    T(duplicate_replayed_not_reexecuted),
    T(nak_with_rejected_frames_seq),
    T(no_session_refusals),
    T(hello_info_fields),
    T(probe_stops_on_contact_in_tick),
    T(probe_no_contact_and_limit),
    T(probe_away_stops_on_release_in_tick),
    T(probe_away_no_release_limit_and_refusals),
    T(z_velocity_stale_ignored_and_expiry),
    T(soft_limit_latches_z_limit),
    T(move_limits_and_upward_only),
    T(move_trapezoid),
    T(stop_supersede_query),
    T(estop_breakaway_latch),
    T(events_and_shared_counter),
    T(ohmic_only_while_sensing),
    T(configure_out_of_range),
    T(calibration_and_filters),
    T(batches),
    T(batch_waits_for_room_in_the_transmit_ring),
    T(a_burst_of_queries_leaves_room_for_the_batches),
    T(batch_waits_for_a_short_frame),
    T(unsupported_and_lease_range),
    T(arc_lost),
    T(xy_speed_and_current_out),
    T(limit_switch_stops_and_latches),
    T(frames_lost_in_the_receiver_count_as_framing_errors),
    T(a_reply_waits_for_room_without_waiting_in_the_loop),
    T(home_finds_the_switch_and_sets_z),
    T(home_starting_on_the_switch_backs_off_first),
    T(home_ends_not_found_timeout_and_aborted),
    T(home_refusals),
    T(home_with_a_switch_that_never_opens_stops_at_z_min),
#undef T
};
#define N_TESTS (sizeof TESTS / sizeof TESTS[0])

static int run(unsigned i)
{
    int failed;
    setup();
    why[0] = 0;
    failed = TESTS[i].fn();
    if (failed) {
        printf("FAIL %s: %s\n", TESTS[i].name, why);
    } else {
        printf("ok %s\n", TESTS[i].name);
    }
    return failed;
}

int main(int argc, char **argv)
{
    int failed = 0, a;
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
    for (a = 1; a < argc; a++) {
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
