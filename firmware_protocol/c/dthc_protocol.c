/*
 * dthc_protocol.c - C99 reference codec of the DTHC board wire protocol (PROTOCOL.md).
 * See dthc_protocol.h for the interface.
 */
#include "dthc_protocol.h"

#include <string.h>

/* cal_scale is moved as the 4 bytes of an IEEE-754 binary32 `float`. */
typedef char dthc_float_must_be_32_bits[(sizeof(float) == 4) ? 1 : -1];

/* --- CRC-16/CCITT-FALSE ------------------------------------------------------------------ */

/* Table-free bytewise form of the polynomial 0x1021 (x^16 + x^12 + x^5 + 1). */
uint16_t dthc_crc16_update(uint16_t crc, uint8_t byte)
{
    uint16_t x = (uint16_t)(((crc >> 8) ^ byte) & 0xFFu);
    x = (uint16_t)(x ^ (x >> 4));
    return (uint16_t)((crc << 8) ^ (x << 12) ^ (x << 5) ^ x);
}

uint16_t dthc_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = DTHC_CRC_INIT;
    size_t i;
    for (i = 0; i < len; i++) {
        crc = dthc_crc16_update(crc, data[i]);
    }
    return crc;
}

/* --- message table ------------------------------------------------------------------------ */

int dthc_payload_size(uint8_t type)
{
    switch (type) {
    case DTHC_MSG_HELLO: return 6;
    case DTHC_MSG_HEARTBEAT: return 0;
    case DTHC_MSG_SET_LEASE: return 2;
    case DTHC_MSG_TORCH: return 1;
    case DTHC_MSG_OHMIC_SENSE: return 1;
    case DTHC_MSG_Z_MOVE: return 8;
    case DTHC_MSG_Z_PROBE: return 10;
    case DTHC_MSG_Z_VELOCITY: return 8;
    case DTHC_MSG_Z_STOP: return 0;
    case DTHC_MSG_SET_CURRENT: return 2;
    case DTHC_MSG_CONFIGURE: return 16;
    case DTHC_MSG_QUERY: return 1;
    case DTHC_MSG_CLOCK_QUERY: return 0;
    case DTHC_MSG_FAULT_RESET: return 2;
    case DTHC_MSG_ACK: return 4;
    case DTHC_MSG_NAK: return 6;
    case DTHC_MSG_HELLO_INFO: return 45;
    case DTHC_MSG_SAMPLES: return DTHC_SAMPLES_HEADER_SIZE;
    case DTHC_MSG_EVENT: return 16;
    case DTHC_MSG_FAULT: return 16;
    case DTHC_MSG_MOTION_DONE: return 9;
    case DTHC_MSG_PROBE_RESULT: return 15;
    case DTHC_MSG_STATUS: return 35;
    case DTHC_MSG_CLOCK: return 8;
    default: return -1;
    }
}

/* --- COBS encoder ------------------------------------------------------------------------
 * A byte-at-a-time encoder writing straight into the caller's buffer, so no copy of the
 * frame body is needed. It produces the same bytes as the Python `cobs` package: a block
 * of 254 non-zero bytes (code 0xFF) at the very end is not followed by an extra 0x01. */

typedef struct {
    uint8_t *out;
    size_t cap;
    size_t pos;      /* next free output byte */
    size_t code_pos; /* where the code byte of the open block goes */
    uint8_t code;    /* 1 + data bytes in the open block */
    bool open;       /* a block is open (false right after a full 0xFF block) */
    bool ok;         /* false once the output did not fit */
} cobs_writer_t;

static void cw_open(cobs_writer_t *w)
{
    if (w->pos >= w->cap) {
        w->ok = false;
        return;
    }
    w->code_pos = w->pos++;
    w->code = 1;
    w->open = true;
}

static void cw_init(cobs_writer_t *w, uint8_t *out, size_t cap)
{
    w->out = out;
    w->cap = cap;
    w->pos = 0;
    w->code_pos = 0;
    w->code = 1;
    w->open = false;
    w->ok = true;
    cw_open(w);
}

static void cw_byte(cobs_writer_t *w, uint8_t b)
{
    if (!w->ok) {
        return;
    }
    if (!w->open) {
        cw_open(w);
        if (!w->ok) {
            return;
        }
    }
    if (b == 0) {
        w->out[w->code_pos] = w->code;
        cw_open(w);
        return;
    }
    if (w->pos >= w->cap) {
        w->ok = false;
        return;
    }
    w->out[w->pos++] = b;
    if (++w->code == 0xFF) {
        w->out[w->code_pos] = 0xFF;
        w->open = false;
    }
}

/* Close the last block; returns the encoded length or 0 if it did not fit. */
static size_t cw_finish(cobs_writer_t *w)
{
    if (!w->ok) {
        return 0;
    }
    if (w->open) {
        w->out[w->code_pos] = w->code;
        w->open = false;
    }
    return w->pos;
}

size_t dthc_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap)
{
    cobs_writer_t w;
    size_t i;
    cw_init(&w, out, cap);
    for (i = 0; i < len; i++) {
        cw_byte(&w, in[i]);
    }
    return cw_finish(&w);
}

/* --- COBS decoder -------------------------------------------------------------------------- */

int dthc_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len)
{
    size_t i = 0;
    size_t n = 0;
    while (i < len) {
        uint8_t code = in[i++];
        size_t k;
        if (code == 0 || (size_t)(code - 1) > len - i) {
            return DTHC_ERR_COBS;
        }
        for (k = 1; k < code; k++) {
            uint8_t b = in[i++];
            if (b == 0) {
                return DTHC_ERR_COBS;
            }
            if (n >= cap) {
                return DTHC_ERR_TOO_LONG;
            }
            out[n++] = b; /* n < i: safe when out == in */
        }
        if (code != 0xFF && i < len) {
            if (n >= cap) {
                return DTHC_ERR_TOO_LONG;
            }
            out[n++] = 0;
        }
    }
    *out_len = n;
    return DTHC_OK;
}

/* --- field serialisation ------------------------------------------------------------------
 * A sink receives the body bytes (type, seq, payload) one at a time: into a plain buffer
 * (dthc_encode_body) or through the CRC into the COBS writer (dthc_encode). */

typedef struct {
    cobs_writer_t *cw; /* NULL: write raw into buf */
    uint8_t *buf;
    size_t cap;
    size_t n;
    uint16_t crc;
    bool ok;
} sink_t;

static void put_u8(sink_t *s, uint8_t b)
{
    s->crc = dthc_crc16_update(s->crc, b);
    if (s->cw != NULL) {
        cw_byte(s->cw, b);
    } else if (s->n < s->cap) {
        s->buf[s->n] = b;
    } else {
        s->ok = false;
    }
    s->n++;
}

static void put_u16(sink_t *s, uint16_t v)
{
    put_u8(s, (uint8_t)(v & 0xFFu));
    put_u8(s, (uint8_t)(v >> 8));
}

static void put_u32(sink_t *s, uint32_t v)
{
    put_u8(s, (uint8_t)(v & 0xFFu));
    put_u8(s, (uint8_t)((v >> 8) & 0xFFu));
    put_u8(s, (uint8_t)((v >> 16) & 0xFFu));
    put_u8(s, (uint8_t)(v >> 24));
}

static void put_i32(sink_t *s, int32_t v)
{
    put_u32(s, (uint32_t)v); /* modulo 2^32: two's complement bytes on every host */
}

static void put_u64(sink_t *s, uint64_t v)
{
    put_u32(s, (uint32_t)(v & 0xFFFFFFFFu));
    put_u32(s, (uint32_t)(v >> 32));
}

static void put_f32(sink_t *s, float f)
{
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    put_u32(s, bits);
}

static void put_bool(sink_t *s, bool v)
{
    put_u8(s, (uint8_t)(v ? 1u : 0u));
}

/* Length of the serial before its NUL, or DTHC_SERIAL_LEN + 1 if it has none in time. */
static size_t serial_len(const char *serial)
{
    size_t n = 0;
    while (n <= DTHC_SERIAL_LEN && serial[n] != '\0') {
        n++;
    }
    return n;
}

/* Check that `msg` can be encoded at all (before any byte is written). */
static bool msg_encodable(const dthc_msg_t *msg)
{
    if (dthc_payload_size(msg->type) < 0) {
        return false;
    }
    if (msg->type == DTHC_MSG_SAMPLES && msg->u.samples.n_samples > DTHC_MAX_SAMPLES) {
        return false;
    }
    if (msg->type == DTHC_MSG_HELLO_INFO
        && serial_len(msg->u.hello_info.serial) > DTHC_SERIAL_LEN) {
        return false;
    }
    return true;
}

static void put_body(sink_t *s, const dthc_msg_t *msg)
{
    size_t i;
    put_u8(s, msg->type);
    put_u8(s, msg->seq);
    switch (msg->type) {
    case DTHC_MSG_HELLO: {
        const dthc_hello_t *p = &msg->u.hello;
        put_u8(s, p->proto_major);
        put_u8(s, p->proto_minor);
        put_u32(s, p->host_nonce);
        break;
    }
    case DTHC_MSG_HEARTBEAT:
    case DTHC_MSG_Z_STOP:
    case DTHC_MSG_CLOCK_QUERY:
        break;
    case DTHC_MSG_SET_LEASE:
        put_u16(s, msg->u.set_lease.lease_ms);
        break;
    case DTHC_MSG_TORCH:
        put_bool(s, msg->u.torch.on);
        break;
    case DTHC_MSG_OHMIC_SENSE:
        put_bool(s, msg->u.ohmic_sense.on);
        break;
    case DTHC_MSG_Z_MOVE:
        put_i32(s, msg->u.z_move.target_um);
        put_u32(s, msg->u.z_move.feed_um_s);
        break;
    case DTHC_MSG_Z_PROBE:
        put_u32(s, msg->u.z_probe.feed_um_s);
        put_u32(s, msg->u.z_probe.max_travel_um);
        put_u16(s, msg->u.z_probe.sensors);
        break;
    case DTHC_MSG_Z_VELOCITY:
        put_u16(s, msg->u.z_velocity.stream_seq);
        put_i32(s, msg->u.z_velocity.velocity_um_s);
        put_u16(s, msg->u.z_velocity.expiry_ms);
        break;
    case DTHC_MSG_SET_CURRENT:
        put_u16(s, msg->u.set_current.current_da);
        break;
    case DTHC_MSG_CONFIGURE: {
        const dthc_configure_t *p = &msg->u.configure;
        put_u16(s, p->sample_rate_hz);
        put_u8(s, p->batch_size);
        put_u8(s, p->filter_kind);
        put_u16(s, p->filter_param);
        put_u16(s, p->arc_lost_ms);
        put_i32(s, p->cal_offset);
        put_f32(s, p->cal_scale);
        break;
    }
    case DTHC_MSG_QUERY:
        put_u8(s, msg->u.query.what);
        break;
    case DTHC_MSG_FAULT_RESET:
        put_u16(s, msg->u.fault_reset.mask);
        break;
    case DTHC_MSG_ACK:
        put_u32(s, msg->u.ack.boot_id);
        break;
    case DTHC_MSG_NAK:
        put_u32(s, msg->u.nak.boot_id);
        put_u8(s, msg->u.nak.code);
        put_u8(s, msg->u.nak.detail);
        break;
    case DTHC_MSG_HELLO_INFO: {
        const dthc_hello_info_t *p = &msg->u.hello_info;
        size_t n = serial_len(p->serial);
        put_u8(s, p->proto_major);
        put_u8(s, p->proto_minor);
        put_u8(s, p->fw_major);
        put_u8(s, p->fw_minor);
        put_u8(s, p->fw_patch);
        put_u8(s, p->reset_reason);
        put_u32(s, p->boot_id);
        for (i = 0; i < DTHC_SERIAL_LEN; i++) {
            put_u8(s, (uint8_t)(i < n ? (unsigned char)p->serial[i] : 0u));
        }
        put_u16(s, p->sample_rate_hz);
        put_u8(s, p->batch_size);
        put_u32(s, p->capabilities);
        put_i32(s, p->z_min_um);
        put_i32(s, p->z_max_um);
        put_u16(s, p->max_frame);
        put_u16(s, p->lease_ms);
        break;
    }
    case DTHC_MSG_SAMPLES: {
        const dthc_samples_t *p = &msg->u.samples;
        put_u16(s, p->stream_seq);
        put_u32(s, p->t0_us);
        put_u16(s, p->period_us);
        put_i32(s, p->z_um);
        put_u16(s, p->inputs);
        put_u16(s, p->zvel_seq);
        put_u16(s, p->xy_speed_dmm_s);
        put_u8(s, p->status);
        for (i = 0; i < p->n_samples; i++) {
            put_u16(s, p->samples_cv[i]);
        }
        break;
    }
    case DTHC_MSG_EVENT: {
        const dthc_event_t *p = &msg->u.event;
        put_u32(s, p->counter);
        put_u32(s, p->t_us);
        put_u8(s, p->input);
        put_u8(s, p->level);
        put_u16(s, p->inputs);
        put_i32(s, p->z_um);
        break;
    }
    case DTHC_MSG_FAULT: {
        const dthc_fault_t *p = &msg->u.fault;
        put_u32(s, p->counter);
        put_u32(s, p->t_us);
        put_u8(s, p->code);
        put_u8(s, p->detail);
        put_u16(s, p->faults);
        put_i32(s, p->z_um);
        break;
    }
    case DTHC_MSG_MOTION_DONE:
        put_u8(s, msg->u.motion_done.result);
        put_i32(s, msg->u.motion_done.z_um);
        put_u32(s, msg->u.motion_done.t_us);
        break;
    case DTHC_MSG_PROBE_RESULT: {
        const dthc_probe_result_t *p = &msg->u.probe_result;
        put_u8(s, p->result);
        put_u16(s, p->sensor);
        put_i32(s, p->contact_z_um);
        put_i32(s, p->stop_z_um);
        put_u32(s, p->t_us);
        break;
    }
    case DTHC_MSG_STATUS: {
        const dthc_status_t *p = &msg->u.status;
        put_u32(s, p->boot_id);
        put_u32(s, p->t_us);
        put_u16(s, p->faults);
        put_u16(s, p->inputs);
        put_u8(s, p->status);
        put_u16(s, p->lease_ms);
        put_u32(s, p->event_counter);
        put_u16(s, p->sample_seq);
        put_u16(s, p->zvel_seq);
        put_i32(s, p->z_um);
        put_u16(s, p->current_da);
        put_u16(s, p->rx_crc_errors);
        put_u16(s, p->rx_framing_errors);
        put_u16(s, p->rx_duplicates);
        break;
    }
    case DTHC_MSG_CLOCK:
        put_u64(s, msg->u.clock.t_us);
        break;
    default:
        s->ok = false; /* unreachable after msg_encodable() */
        break;
    }
}

size_t dthc_encode_body(const dthc_msg_t *msg, uint8_t *out, size_t cap)
{
    sink_t s;
    if (msg == NULL || out == NULL || !msg_encodable(msg)) {
        return 0;
    }
    s.cw = NULL;
    s.buf = out;
    s.cap = cap;
    s.n = 0;
    s.crc = DTHC_CRC_INIT;
    s.ok = true;
    put_body(&s, msg);
    return s.ok ? s.n : 0;
}

size_t dthc_encode(const dthc_msg_t *msg, uint8_t *out, size_t cap)
{
    cobs_writer_t w;
    sink_t s;
    size_t n;
    if (msg == NULL || out == NULL || !msg_encodable(msg)) {
        return 0;
    }
    cw_init(&w, out, cap);
    s.cw = &w;
    s.buf = NULL;
    s.cap = 0;
    s.n = 0;
    s.crc = DTHC_CRC_INIT;
    s.ok = true;
    put_body(&s, msg);
    if (!s.ok || s.n + 2 > DTHC_MAX_FRAME) {
        return 0;
    }
    cw_byte(&w, (uint8_t)(s.crc >> 8)); /* the CRC alone is big-endian */
    cw_byte(&w, (uint8_t)(s.crc & 0xFFu));
    n = cw_finish(&w);
    if (n == 0 || n >= cap) {
        return 0;
    }
    out[n] = DTHC_DELIMITER;
    return n + 1;
}

/* --- field parsing -------------------------------------------------------------------------- */

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16)
           | ((uint32_t)p[3] << 24);
}

static int32_t get_i32(const uint8_t *p)
{
    uint32_t u = get_u32(p);
    /* Two's complement without implementation-defined unsigned-to-signed conversion. */
    if (u <= 0x7FFFFFFFu) {
        return (int32_t)u;
    }
    return -(int32_t)(~u) - 1;
}

static uint64_t get_u64(const uint8_t *p)
{
    return (uint64_t)get_u32(p) | ((uint64_t)get_u32(p + 4) << 32);
}

static float get_f32(const uint8_t *p)
{
    uint32_t bits = get_u32(p);
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

/* Type and length check, then unpack. `raw` holds type, seq, payload (len bytes, CRC
 * already checked and excluded). */
static int parse_body(const uint8_t *raw, size_t len, dthc_msg_t *out)
{
    const uint8_t *p = raw + 2;
    size_t payload = len - 2;
    int size = dthc_payload_size(raw[0]);
    size_t i;
    dthc_msg_t m;

    if (size < 0) {
        return DTHC_ERR_UNKNOWN_TYPE;
    }
    if (raw[0] == DTHC_MSG_SAMPLES) {
        if (payload < DTHC_SAMPLES_HEADER_SIZE || ((payload - DTHC_SAMPLES_HEADER_SIZE) & 1u)
            || (payload - DTHC_SAMPLES_HEADER_SIZE) / 2 > DTHC_MAX_SAMPLES) {
            return DTHC_ERR_BAD_LENGTH;
        }
    } else if (payload != (size_t)size) {
        return DTHC_ERR_BAD_LENGTH;
    }

    memset(&m, 0, sizeof m);
    m.type = raw[0];
    m.seq = raw[1];
    switch (m.type) {
    case DTHC_MSG_HELLO:
        m.u.hello.proto_major = p[0];
        m.u.hello.proto_minor = p[1];
        m.u.hello.host_nonce = get_u32(p + 2);
        break;
    case DTHC_MSG_HEARTBEAT:
    case DTHC_MSG_Z_STOP:
    case DTHC_MSG_CLOCK_QUERY:
        break;
    case DTHC_MSG_SET_LEASE:
        m.u.set_lease.lease_ms = get_u16(p);
        break;
    case DTHC_MSG_TORCH:
        m.u.torch.on = p[0] != 0; /* any non-zero byte is true */
        break;
    case DTHC_MSG_OHMIC_SENSE:
        m.u.ohmic_sense.on = p[0] != 0;
        break;
    case DTHC_MSG_Z_MOVE:
        m.u.z_move.target_um = get_i32(p);
        m.u.z_move.feed_um_s = get_u32(p + 4);
        break;
    case DTHC_MSG_Z_PROBE:
        m.u.z_probe.feed_um_s = get_u32(p);
        m.u.z_probe.max_travel_um = get_u32(p + 4);
        m.u.z_probe.sensors = get_u16(p + 8);
        break;
    case DTHC_MSG_Z_VELOCITY:
        m.u.z_velocity.stream_seq = get_u16(p);
        m.u.z_velocity.velocity_um_s = get_i32(p + 2);
        m.u.z_velocity.expiry_ms = get_u16(p + 6);
        break;
    case DTHC_MSG_SET_CURRENT:
        m.u.set_current.current_da = get_u16(p);
        break;
    case DTHC_MSG_CONFIGURE: {
        dthc_configure_t *c = &m.u.configure;
        c->sample_rate_hz = get_u16(p);
        c->batch_size = p[2];
        c->filter_kind = p[3];
        c->filter_param = get_u16(p + 4);
        c->arc_lost_ms = get_u16(p + 6);
        c->cal_offset = get_i32(p + 8);
        c->cal_scale = get_f32(p + 12);
        break;
    }
    case DTHC_MSG_QUERY:
        m.u.query.what = p[0];
        break;
    case DTHC_MSG_FAULT_RESET:
        m.u.fault_reset.mask = get_u16(p);
        break;
    case DTHC_MSG_ACK:
        m.u.ack.boot_id = get_u32(p);
        break;
    case DTHC_MSG_NAK:
        m.u.nak.boot_id = get_u32(p);
        m.u.nak.code = p[4];
        m.u.nak.detail = p[5];
        break;
    case DTHC_MSG_HELLO_INFO: {
        dthc_hello_info_t *h = &m.u.hello_info;
        h->proto_major = p[0];
        h->proto_minor = p[1];
        h->fw_major = p[2];
        h->fw_minor = p[3];
        h->fw_patch = p[4];
        h->reset_reason = p[5];
        h->boot_id = get_u32(p + 6);
        for (i = 0; i < DTHC_SERIAL_LEN && p[10 + i] != 0; i++) {
            h->serial[i] = (char)p[10 + i];
        }
        h->serial[i] = '\0';
        h->sample_rate_hz = get_u16(p + 26);
        h->batch_size = p[28];
        h->capabilities = get_u32(p + 29);
        h->z_min_um = get_i32(p + 33);
        h->z_max_um = get_i32(p + 37);
        h->max_frame = get_u16(p + 41);
        h->lease_ms = get_u16(p + 43);
        break;
    }
    case DTHC_MSG_SAMPLES: {
        dthc_samples_t *sm = &m.u.samples;
        sm->stream_seq = get_u16(p);
        sm->t0_us = get_u32(p + 2);
        sm->period_us = get_u16(p + 6);
        sm->z_um = get_i32(p + 8);
        sm->inputs = get_u16(p + 12);
        sm->zvel_seq = get_u16(p + 14);
        sm->xy_speed_dmm_s = get_u16(p + 16);
        sm->status = p[18];
        sm->n_samples = (uint8_t)((payload - DTHC_SAMPLES_HEADER_SIZE) / 2);
        for (i = 0; i < sm->n_samples; i++) {
            sm->samples_cv[i] = get_u16(p + DTHC_SAMPLES_HEADER_SIZE + 2 * i);
        }
        break;
    }
    case DTHC_MSG_EVENT: {
        dthc_event_t *e = &m.u.event;
        e->counter = get_u32(p);
        e->t_us = get_u32(p + 4);
        e->input = p[8];
        e->level = p[9];
        e->inputs = get_u16(p + 10);
        e->z_um = get_i32(p + 12);
        break;
    }
    case DTHC_MSG_FAULT: {
        dthc_fault_t *f = &m.u.fault;
        f->counter = get_u32(p);
        f->t_us = get_u32(p + 4);
        f->code = p[8];
        f->detail = p[9];
        f->faults = get_u16(p + 10);
        f->z_um = get_i32(p + 12);
        break;
    }
    case DTHC_MSG_MOTION_DONE:
        m.u.motion_done.result = p[0];
        m.u.motion_done.z_um = get_i32(p + 1);
        m.u.motion_done.t_us = get_u32(p + 5);
        break;
    case DTHC_MSG_PROBE_RESULT: {
        dthc_probe_result_t *r = &m.u.probe_result;
        r->result = p[0];
        r->sensor = get_u16(p + 1);
        r->contact_z_um = get_i32(p + 3);
        r->stop_z_um = get_i32(p + 7);
        r->t_us = get_u32(p + 11);
        break;
    }
    case DTHC_MSG_STATUS: {
        dthc_status_t *st = &m.u.status;
        st->boot_id = get_u32(p);
        st->t_us = get_u32(p + 4);
        st->faults = get_u16(p + 8);
        st->inputs = get_u16(p + 10);
        st->status = p[12];
        st->lease_ms = get_u16(p + 13);
        st->event_counter = get_u32(p + 15);
        st->sample_seq = get_u16(p + 19);
        st->zvel_seq = get_u16(p + 21);
        st->z_um = get_i32(p + 23);
        st->current_da = get_u16(p + 27);
        st->rx_crc_errors = get_u16(p + 29);
        st->rx_framing_errors = get_u16(p + 31);
        st->rx_duplicates = get_u16(p + 33);
        break;
    }
    case DTHC_MSG_CLOCK:
        m.u.clock.t_us = get_u64(p);
        break;
    default:
        return DTHC_ERR_UNKNOWN_TYPE; /* unreachable: dthc_payload_size() knows the types */
    }
    memcpy(out, &m, sizeof m);
    return DTHC_OK;
}

int dthc_decode_body(const uint8_t *raw, size_t len, dthc_msg_t *out)
{
    if (len > DTHC_MAX_FRAME) {
        return DTHC_ERR_TOO_LONG;
    }
    if (len < 4) {
        return DTHC_ERR_SHORT;
    }
    if (dthc_crc16(raw, len) != 0) {
        return DTHC_ERR_CRC;
    }
    return parse_body(raw, len - 2, out);
}

/* --- streaming receiver ------------------------------------------------------------------ */

void dthc_rx_reset(dthc_rx_t *rx)
{
    rx->enc_len = 0;
    rx->dec_len = 0;
    rx->crc = DTHC_CRC_INIT;
    rx->block_left = 0;
    rx->zero_pending = false;
    rx->discarding = false;
}

void dthc_rx_init(dthc_rx_t *rx)
{
    memset(rx, 0, sizeof *rx);
    dthc_rx_reset(rx);
}

static void rx_push(dthc_rx_t *rx, uint8_t b)
{
    /* dec_len < enc_len <= DTHC_MAX_ENCODED_FRAME: always inside buf. */
    rx->buf[rx->dec_len++] = b;
    rx->crc = dthc_crc16_update(rx->crc, b);
}

/* A frame ended at a delimiter: check it in the order of PROTOCOL.md section 2 (valid
 * COBS, 4 <= decoded length <= DTHC_MAX_FRAME, CRC, known type, payload length). */
static int rx_end_frame(dthc_rx_t *rx, dthc_msg_t *out)
{
    int rc;
    if (rx->block_left != 0) {
        rc = DTHC_ERR_COBS; /* the last code byte promised more bytes */
        rx->framing_errors++;
    } else if (rx->dec_len < 4) {
        rc = DTHC_ERR_SHORT;
        rx->framing_errors++;
    } else if (rx->dec_len > DTHC_MAX_FRAME) {
        /* 258 encoded bytes can hold 257 decoded ones: one more than any frame. */
        rc = DTHC_ERR_TOO_LONG;
        rx->framing_errors++;
    } else if (rx->crc != 0) {
        rc = DTHC_ERR_CRC;
        rx->crc_errors++;
    } else {
        rc = parse_body(rx->buf, (size_t)rx->dec_len - 2u, out);
        if (rc == DTHC_OK) {
            rx->frames_ok++;
            dthc_rx_reset(rx);
            return 1;
        }
        if (rc == DTHC_ERR_UNKNOWN_TYPE) {
            rx->unknown_type++;
        } else {
            rx->length_errors++;
        }
    }
    rx->dropped_bytes += (uint32_t)rx->enc_len + 1u; /* with its delimiter */
    dthc_rx_reset(rx);
    return rc;
}

int dthc_rx_feed_byte(dthc_rx_t *rx, uint8_t byte, dthc_msg_t *out)
{
    rx->bytes_in++;
    if (byte == DTHC_DELIMITER) {
        if (rx->discarding) {
            /* The delimiter ends the over-long run, and is dropped with it. */
            rx->dropped_bytes++;
            dthc_rx_reset(rx);
            return 0;
        }
        if (rx->enc_len == 0) {
            return 0; /* empty frame: idle or resynchronising delimiter */
        }
        return rx_end_frame(rx, out);
    }
    if (rx->discarding) {
        rx->dropped_bytes++;
        return 0;
    }
    if (rx->enc_len >= DTHC_MAX_ENCODED_FRAME) {
        /* More than the longest legal frame without a delimiter: one framing error, then
         * discard everything up to the next delimiter. */
        rx->framing_errors++;
        rx->dropped_bytes += (uint32_t)rx->enc_len + 1u;
        dthc_rx_reset(rx);
        rx->discarding = true;
        return DTHC_ERR_TOO_LONG;
    }
    rx->enc_len++;
    if (rx->block_left == 0) {
        /* A COBS code byte: the previous block (if shorter than 254) ended in a zero. */
        if (rx->zero_pending) {
            rx_push(rx, 0);
        }
        rx->block_left = (uint8_t)(byte - 1u);
        rx->zero_pending = byte != 0xFF;
    } else {
        rx_push(rx, byte);
        rx->block_left--;
    }
    return 0;
}
