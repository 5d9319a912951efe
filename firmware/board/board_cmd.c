/*
 * board_cmd.c - the main loop's side: received frames, the session, the duplicate memory,
 * every host command and its reply.
 *
 * A command runs with the tick locked (it changes what the tick reads), and its ACK or
 * NAK is queued before the lock is released, so a report the command causes (a
 * MOTION_DONE, a PROBE_RESULT) always follows the command's reply on the wire. Query
 * replies are snapshotted under the lock and encoded after it: encoding never holds up
 * the tick.
 */
#include "board_internal.h"

#include <string.h>

dthc_rx_t board_rx;
static uint8_t query_tx[BOARD_QUERY_TX];
#define QUERY_AT (query_tx + DTHC_TX_PAYLOAD_OFFSET)

#define POLL_BYTES_MAX 64 /* per board_poll call, so the main loop kicks the watchdog */

/* Boot id: the start's entropy, stirred once with the arrival time of the first host
 * frame (host timing differs from start to start even where the MCU is deterministic). */
static void finalise_boot_id(void)
{
    uint32_t h;
    if (B.boot_id_final) {
        return;
    }
    h = B.boot_id ^ (hal_time_us() * 0x9E3779B1UL);
    h ^= h >> 16;
    h *= 0x85EBCA6BUL;
    h ^= h >> 13;
    h *= 0xC2B2AE35UL;
    h ^= h >> 16;
    if (h == 0 || h == 0xFFFFFFFFUL) {
        h = 0x5EED0001UL; /* the two values a host takes for a constant */
    }
    B.boot_id = h;
    B.boot_id_final = true;
}

/* --- replies ----------------------------------------------------------------------------- */

/* ACK (code 0) or NAK, queued now (tick locked). */
static void send_outcome(uint8_t seq, uint8_t code, uint8_t detail)
{
    uint8_t *p = BOARD_SMALL_PAYLOAD_AT;
    if (!code) {
        dthc_ack_put_boot_id(p, B.boot_id);
        board_send_small(DTHC_MSG_ACK, seq, DTHC_ACK_SIZE);
        return;
    }
    dthc_nak_put_boot_id(p, B.boot_id);
    dthc_nak_put_code(p, code);
    dthc_nak_put_detail(p, detail);
    board_send_small(DTHC_MSG_NAK, seq, DTHC_NAK_SIZE);
}

/* The reply of an executed command, remembered for its duplicates. */
static void reply(uint8_t seq, uint8_t code, uint8_t detail)
{
    outcome_t *o;
    send_outcome(seq, code, detail);
    if (!seq) {
        return; /* seq 0 is never a sequenced command's: nothing to recognise later */
    }
    o = &B.outcomes[B.outcome_next];
    o->seq = seq;
    o->code = code;
    o->detail = detail;
    B.outcome_next = (uint8_t)((B.outcome_next + 1u) % BOARD_OUTCOMES);
}

static const outcome_t *remembered(uint8_t seq)
{
    uint8_t i;
    for (i = 0; i < BOARD_OUTCOMES; i++) {
        if (seq && B.outcomes[i].seq == seq) {
            return &B.outcomes[i];
        }
    }
    return NULL;
}

static uint8_t hello_info(void)
{
    uint8_t *p = QUERY_AT;
    const board_config_t *c = B.cfg;
    dthc_hello_info_put_proto_major(p, DTHC_PROTOCOL_MAJOR);
    dthc_hello_info_put_proto_minor(p, DTHC_PROTOCOL_MINOR);
    dthc_hello_info_put_fw_major(p, BOARD_FW_MAJOR);
    dthc_hello_info_put_fw_minor(p, BOARD_FW_MINOR);
    dthc_hello_info_put_fw_patch(p, BOARD_FW_PATCH);
    dthc_hello_info_put_reset_reason(p, c->reset_reason);
    dthc_hello_info_put_boot_id(p, B.boot_id);
    dthc_hello_info_put_serial(p, c->serial);
    dthc_hello_info_put_sample_rate_hz(p, B.rate_hz);
    dthc_hello_info_put_batch_size(p, B.batch_size);
    dthc_hello_info_put_capabilities(p, c->capabilities);
    dthc_hello_info_put_z_min_um(p, c->z_min_um);
    dthc_hello_info_put_z_max_um(p, c->z_max_um);
    dthc_hello_info_put_max_frame(p, DTHC_MAX_FRAME);
    dthc_hello_info_put_lease_ms(p, B.lease_ms);
    return DTHC_HELLO_INFO_SIZE;
}

#ifdef BOARD_TIMING
/* A measuring build (make BOARD_TIMING=1): STATUS.current_da carries the longest tick in
 * us, STATUS.rx_duplicates how long the previous STATUS took from its QUERY's last byte
 * decoded to its reply queued, in us, and
 * STATUS.rx_crc_errors the stack bytes never used so far (the port's hal_stack_unused),
 * STATUS.rx_framing_errors the mean tick of the last 1024, in us. */
extern uint16_t board_tick_max_us;
extern uint16_t board_tick_mean_us;
uint16_t hal_stack_unused(void);
static uint16_t status_encode_us;
static uint32_t frame_done_us;
static uint16_t stack_unused;
static bool stack_scan_due;
#endif

static uint16_t sat16(uint32_t v)
{
    return v > 0xFFFFu ? 0xFFFFu : (uint16_t)v;
}

static uint8_t status(void)
{
    uint8_t *p = QUERY_AT;
    dthc_status_put_boot_id(p, B.boot_id);
    dthc_status_put_t_us(p, hal_time_us());
    dthc_status_put_faults(p, B.faults);
    dthc_status_put_inputs(p, B.inputs);
    dthc_status_put_status(p, board_status_bits());
    dthc_status_put_lease_ms(p, B.lease_ms);
    dthc_status_put_event_counter(p, B.event_counter);
    dthc_status_put_sample_seq(p, B.sample_seq);
    dthc_status_put_zvel_seq(p, B.zvel_seq);
    dthc_status_put_z_um(p, board_z_um());
#if BOARD_CURRENT_OUT
    dthc_status_put_current_da(p, B.current_da);
#else
    dthc_status_put_current_da(p, 0); /* no CURRENT_OUT */
#endif
    dthc_status_put_rx_crc_errors(p, sat16(board_rx.crc_errors));
    /* with the frames the receiver lost whole (a full receive buffer): each counted once */
    dthc_status_put_rx_framing_errors(
        p, sat16(board_rx.framing_errors + (uint32_t)hal_uart_rx_frames_lost()));
    dthc_status_put_rx_duplicates(p, B.rx_duplicates);
#ifdef BOARD_TIMING
    dthc_status_put_current_da(p, board_tick_max_us);
    dthc_status_put_rx_duplicates(p, status_encode_us);
    dthc_status_put_rx_crc_errors(p, stack_unused);
    dthc_status_put_rx_framing_errors(p, board_tick_mean_us);
#endif
    return DTHC_STATUS_SIZE;
}

/* A query reply that found no room in the transmit ring: its encoded bytes wait in query_tx
 * and go at the next poll that finds room; no frame is read meanwhile (its bytes wait in
 * the receive ring). Nothing waits for room: neither the main loop nor the tick. */
static uint8_t reply_waiting_len;

static bool queue_waiting_reply(void)
{
    bool ok;
    hal_tick_lock();
    ok = hal_uart_write(query_tx, reply_waiting_len);
    hal_tick_unlock();
    if (ok) {
        reply_waiting_len = 0;
    }
    return ok;
}

/* Encode a query reply (snapshotted under the lock) with the tick running, and queue it,
 * or leave it waiting for room (queue_waiting_reply). */
static void send_query_reply(uint8_t type, uint8_t seq, uint8_t len)
{
    uint8_t n;
    hal_tick_unlock();
    n = (uint8_t)dthc_encode_in_place(type, seq, query_tx, len);
    hal_tick_lock();
    if (!hal_uart_write(query_tx, n)) {
        reply_waiting_len = n;
    }
#ifdef BOARD_TIMING
    if (type == DTHC_MSG_STATUS) {
        status_encode_us = (uint16_t)(hal_time_us() - frame_done_us);
        stack_scan_due = true; /* a slow scan: later, with the tick running */
    }
#endif
}

/* --- commands (tick locked) --------------------------------------------------------------- */

static void cmd_hello(uint8_t seq, const uint8_t *p)
{
    send_query_reply(DTHC_MSG_HELLO_INFO, seq, hello_info());
    if (dthc_hello_get_proto_major(p) != DTHC_PROTOCOL_MAJOR) {
        B.session = false; /* the host can read what the board speaks, and stops there */
        return;
    }
    B.session = true;
    memset(B.outcomes, 0, sizeof B.outcomes);
    B.outcome_next = 0;
    B.zvel_applied = false; /* the velocity stream restarts with each session */
    B.last_rx_us = hal_time_us();
    if (B.lease == LEASE_LAPSED_IDLE) {
        B.lease = LEASE_RUNNING; /* a lapse of an earlier session ends with it */
    }
}

static void cmd_query(uint8_t seq, uint8_t what)
{
    if (what == DTHC_QUERY_STATUS) {
        send_query_reply(DTHC_MSG_STATUS, seq, status());
    } else if (what == DTHC_QUERY_HELLO_INFO) {
        send_query_reply(DTHC_MSG_HELLO_INFO, seq, hello_info());
    } else if (what == DTHC_QUERY_PROBE_RESULT && B.last_probe.valid) {
        uint8_t ended = B.last_probe.seq;
        B.last_probe.seq = seq; /* answered with the query's seq (section 3) */
        board_send_probe_result();
        B.last_probe.seq = ended;
    } else if (what == DTHC_QUERY_MOTION_DONE && B.last_motion.valid) {
        uint8_t ended = B.last_motion.seq;
        B.last_motion.seq = seq;
        board_send_motion_done();
        B.last_motion.seq = ended;
#if BOARD_HOMING
    } else if (what == DTHC_QUERY_HOME_RESULT && B.last_home.valid) {
        uint8_t ended = B.last_home.seq;
        B.last_home.seq = seq;
        board_send_home_result();
        B.last_home.seq = ended;
#endif
    } else {
        send_outcome(seq, DTHC_NAK_OUT_OF_RANGE, 0);
    }
}

static void cmd_z_velocity(const uint8_t *p)
{
    uint16_t stream_seq = dthc_z_velocity_get_stream_seq(p);
    uint16_t expiry_ms = dthc_z_velocity_get_expiry_ms(p);
    uint16_t delta = (uint16_t)(stream_seq - B.zvel_seq);
    if (!B.session || B.faults) {
        return;
    }
    if (B.zvel_applied && (delta == 0 || delta > DTHC_STREAM_SEQ_NEWER_MAX)) {
        return; /* not newer than the last applied one: late or duplicated */
    }
    if (expiry_ms < DTHC_ZVEL_EXPIRY_MIN_MS || expiry_ms > DTHC_ZVEL_EXPIRY_MAX_MS) {
        return;
    }
    B.zvel_seq = stream_seq;
    B.zvel_applied = true;
    board_z_velocity(dthc_z_velocity_get_velocity_um_s(p), expiry_ms);
}

static void cmd_z_move(uint8_t seq, const uint8_t *p)
{
    int32_t target = dthc_z_move_get_target_um(p);
    uint32_t feed = dthc_z_move_get_feed_um_s(p);
    if (target < B.cfg->z_min_um || target > B.cfg->z_max_um) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 0);
    } else if (feed == 0) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 1);
    } else if (B.faults && target <= board_z_um()) {
        reply(seq, DTHC_NAK_FAULT_LATCHED, board_lowest_fault()); /* only up while latched */
    } else {
        reply(seq, 0, 0);
        board_z_move(seq, target, feed);
    }
}

/* Z_PROBE (down until a sensor is active) and Z_PROBE_AWAY (up until every sensor is
 * released): one payload, one set of refusals (PROTOCOL.md section 6.1). */
static void cmd_z_probe(uint8_t seq, const uint8_t *p, bool away)
{
    uint32_t feed = dthc_z_probe_get_feed_um_s(p);
    uint32_t travel = dthc_z_probe_get_max_travel_um(p);
    uint16_t sensors = (uint16_t)(dthc_z_probe_get_sensors(p) & BOARD_CONTACT_SENSORS);
    if (B.faults) {
        reply(seq, DTHC_NAK_FAULT_LATCHED, board_lowest_fault());
    } else if (feed == 0) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 0);
    } else if (travel == 0) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 1);
    } else if (!sensors) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 2);
    } else {
        reply(seq, 0, 0);
        board_z_probe(seq, feed, travel, sensors, away);
    }
}

/* Z_HOME (1.3): the refusals of PROTOCOL.md section 6.1, then the cycle (board_motion.c). */
static void cmd_z_home(uint8_t seq, const uint8_t *p)
{
#if BOARD_HOMING
    uint32_t seek = dthc_z_home_get_seek_um_s(p);
    uint32_t locate = dthc_z_home_get_locate_um_s(p);
    uint32_t backoff = dthc_z_home_get_backoff_um(p);
    uint32_t travel = dthc_z_home_get_max_travel_um(p);
    uint16_t timeout = dthc_z_home_get_timeout_ms(p);
    int32_t park = B.cfg->z_home_um - (int32_t)(backoff > 0x10000000UL ? 0x10000000UL : backoff);
    if (!(B.cfg->capabilities & DTHC_CAP_HOMING)) {
        reply(seq, DTHC_NAK_UNSUPPORTED, 9);
    } else if (B.faults) {
        reply(seq, DTHC_NAK_FAULT_LATCHED, board_lowest_fault());
    } else if (seek == 0) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 0);
    } else if (locate == 0) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 1);
    } else if (backoff == 0 || park < B.cfg->z_min_um || park > B.cfg->z_max_um) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 2);
    } else if (travel == 0) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 3);
    } else if (timeout == 0) {
        reply(seq, DTHC_NAK_OUT_OF_RANGE, 4);
    } else {
        reply(seq, 0, 0);
        board_z_home(seq, seek, locate, backoff, travel, timeout);
    }
#else
    (void)p;
    reply(seq, DTHC_NAK_UNSUPPORTED, 9); /* built without homing: no switch input */
#endif
}

static void cmd_fault_reset(uint8_t seq, uint16_t mask)
{
    uint8_t code;
    mask &= B.faults;
    if ((mask & (1u << DTHC_FAULT_BREAKAWAY)) && (B.inputs & (1u << DTHC_INPUT_BREAKAWAY))) {
        reply(seq, DTHC_NAK_FAULT_ACTIVE, DTHC_FAULT_BREAKAWAY);
        return;
    }
    if ((mask & (1u << DTHC_FAULT_ESTOP)) && (B.inputs & (1u << DTHC_INPUT_ESTOP))) {
        reply(seq, DTHC_NAK_FAULT_ACTIVE, DTHC_FAULT_ESTOP);
        return;
    }
    if (mask & (1u << DTHC_FAULT_Z_LIMIT)) {
        int32_t z = board_z_um();
        if (z < B.cfg->z_min_um || z > B.cfg->z_max_um) {
            reply(seq, DTHC_NAK_FAULT_ACTIVE, DTHC_FAULT_Z_LIMIT);
            return;
        }
    }
    B.faults = (uint16_t)(B.faults & ~mask);
    for (code = 0; code < BOARD_FAULT_CODES; code++) {
        if (mask & (1u << code)) {
            B.fault_counter[code] = 0;
        }
    }
    if (mask & (1u << DTHC_FAULT_LEASE_EXPIRED)) {
        B.lease = LEASE_RUNNING; /* re-armed explicitly, from now */
        B.last_rx_us = hal_time_us();
    }
    reply(seq, 0, 0);
}

static void command(uint8_t type, uint8_t seq, const uint8_t *p)
{
    switch (type) {
    case DTHC_MSG_HEARTBEAT:
        reply(seq, 0, 0);
        break;
    case DTHC_MSG_SET_LEASE: {
        uint16_t lease = dthc_set_lease_get_lease_ms(p);
        if (lease < DTHC_LEASE_MIN_MS || lease > DTHC_LEASE_MAX_MS) {
            reply(seq, DTHC_NAK_OUT_OF_RANGE, 0);
        } else {
            B.lease_ms = lease;
            reply(seq, 0, 0);
        }
        break;
    }
    case DTHC_MSG_TORCH:
        if (dthc_torch_get_on(p) && B.faults) {
            reply(seq, DTHC_NAK_FAULT_LATCHED, board_lowest_fault());
        } else {
            board_set_torch(dthc_torch_get_on(p));
            reply(seq, 0, 0);
        }
        break;
    case DTHC_MSG_OHMIC_SENSE:
        board_set_ohmic(dthc_ohmic_sense_get_on(p));
        reply(seq, 0, 0);
        break;
    case DTHC_MSG_Z_MOVE:
        cmd_z_move(seq, p);
        break;
    case DTHC_MSG_Z_PROBE:
        cmd_z_probe(seq, p, false);
        break;
    case DTHC_MSG_Z_PROBE_AWAY:
        cmd_z_probe(seq, p, true);
        break;
    case DTHC_MSG_Z_HOME:
        cmd_z_home(seq, p);
        break;
    case DTHC_MSG_Z_STOP:
        board_z_end(DTHC_MOTION_STOPPED, DTHC_PROBE_ABORTED);
        board_z_stop();
        reply(seq, 0, 0);
        break;
    case DTHC_MSG_SET_CURRENT:
#if BOARD_CURRENT_OUT
        if (B.cfg->capabilities & DTHC_CAP_CURRENT_OUT) {
            B.current_da = dthc_set_current_get_current_da(p);
            hal_set_current_da(B.current_da);
            reply(seq, 0, 0);
            break;
        }
#endif
        reply(seq, DTHC_NAK_UNSUPPORTED, 5); /* no CURRENT_OUT on this board */
        break;
    case DTHC_MSG_CONFIGURE: {
        uint8_t bad;
        if (board_configure(p, &bad)) {
            reply(seq, 0, 0);
        } else {
            reply(seq, DTHC_NAK_OUT_OF_RANGE, bad);
        }
        break;
    }
    case DTHC_MSG_FAULT_RESET:
        cmd_fault_reset(seq, dthc_fault_reset_get_mask(p));
        break;
    default: /* a board-to-host type sent to the board */
        reply(seq, DTHC_NAK_UNKNOWN_TYPE, 0);
        break;
    }
}

/* The lease runs from the frame's arrival (its delimiter's receive interrupt), not from
 * now: the main loop may decode it up to a millisecond later. */
static void renew_lease(void)
{
    if (B.session && B.lease != LEASE_EXPIRED) {
        B.last_rx_us = hal_uart_delimiter_us();
        B.lease = LEASE_RUNNING; /* an idle lapse ends here: no re-arm (section 4) */
    }
}

static void frame(const dthc_frame_t *f)
{
    const outcome_t *dup;
    renew_lease();
    switch (f->type) {
    case DTHC_MSG_HELLO:
        cmd_hello(f->seq, f->payload);
        return;
    case DTHC_MSG_QUERY:
        cmd_query(f->seq, dthc_query_get_what(f->payload));
        return;
    case DTHC_MSG_CLOCK_QUERY:
        dthc_clock_put_t_us(QUERY_AT, hal_time_us64());
        send_query_reply(DTHC_MSG_CLOCK, f->seq, DTHC_CLOCK_SIZE);
        return;
    case DTHC_MSG_Z_VELOCITY:
        cmd_z_velocity(f->payload);
        return;
    default:
        break;
    }
    if (!B.session) {
        if (f->seq) {
            send_outcome(f->seq, DTHC_NAK_NO_SESSION, 0);
        }
        return;
    }
    dup = remembered(f->seq);
    if (dup) { /* a retransmission: answer again, act once */
        if (B.rx_duplicates != 0xFFFFu) {
            B.rx_duplicates++;
        }
        send_outcome(f->seq, dup->code, dup->detail);
        return;
    }
    command(f->type, f->seq, f->payload);
}

bool board_poll(void)
{
    uint8_t budget = POLL_BYTES_MAX;
    bool did = false;
    if (reply_waiting_len && !queue_waiting_reply()) {
        return board_flush_samples(); /* replies keep their order: no frame read yet */
    }
    while (budget--) {
        dthc_frame_t f;
        int rc;
        int16_t c;
        if (board_rx.enc_len == 0 && hal_uart_tx_free() < board_tx_reserve()) {
            /* Between frames, a query is read only when the transmit ring has room for
             * its reply and the next SAMPLES batch: replies to a bunched burst of queries
             * that fill the ring make the batch wait (tick running) until the next one
             * completes: SAMPLE_OVERFLOW. Its bytes wait in the receive ring meanwhile;
             * the transmit ring drains at line rate. */
            break;
        }
        c = hal_uart_getc();
        if (c < 0) {
            break;
        }
        did = true;
        rc = dthc_rx_feed(&board_rx, (uint8_t)c, &f);
        if (rc == 0) {
            continue;
        }
        if (rc == 1 || rc == DTHC_ERR_UNKNOWN_TYPE || rc == DTHC_ERR_BAD_LENGTH) {
#ifdef BOARD_TIMING
            frame_done_us = hal_time_us();
#endif
            finalise_boot_id();
            hal_tick_lock();
            if (rc == 1) {
                frame(&f);
            } else {
                renew_lease(); /* a valid CRC: the host is alive */
                if (f.seq) {
                    send_outcome(f.seq, rc == DTHC_ERR_UNKNOWN_TYPE ? DTHC_NAK_UNKNOWN_TYPE
                                                                   : DTHC_NAK_BAD_LENGTH, 0);
                }
            }
            hal_tick_unlock();
#ifdef BOARD_TIMING
            if (stack_scan_due) {
                stack_scan_due = false;
                stack_unused = hal_stack_unused();
            }
#endif
            if (reply_waiting_len) {
                break; /* its room first */
            }
            if (board_samples_waiting()) {
                break; /* a burst of queries: the batch goes between two replies, not
                          after all of them (the next would complete meanwhile) */
            }
        }
    }
    /* Replies first: a batch waiting here is not time-critical, a reply is (1 ms). */
    return board_flush_samples() || did;
}
