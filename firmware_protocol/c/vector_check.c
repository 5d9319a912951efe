/*
 * vector_check.c - drive the C reference codec from text lines on stdin (used by
 * tests/firmware_protocol/test_c_codec.py; handy by hand too).
 *
 * Input lines (hex without separators, any case; lines of any length):
 *   F <hex>   wire frame(s): fed byte by byte to a fresh streaming receiver. For each
 *             message: "OK <MessageName> key=value ..." then "RE <hex>" (the message
 *             re-encoded by dthc_encode); for each dropped frame "ERR <code>"; if the
 *             bytes complete nothing at all, "ERR INCOMPLETE".
 *   B <hex>   one decoded frame (type, seq, payload, crc) for dthc_decode_body:
 *             "OK ..." and "BODY <hex>" (dthc_encode_body), or "ERR <code>".
 *   S <hex>   a (damaged) stream, fed byte by byte to a fresh receiver: "MSG <MessageName>
 *             key=value ..." per message, then "STATS frames_ok=.. crc_errors=..
 *             framing_errors=.. unknown_type=.. length_errors=.. dropped_bytes=..".
 *   C <hex>   "CRC <4 hex digits>" (CRC-16/CCITT-FALSE).
 *   E <hex>   "COBS <hex>" (dthc_cobs_encode), or "ERR <code>".
 *   D <hex>   "RAW <hex>" (dthc_cobs_decode), or "ERR <code>".
 *   K         every constant of dthc_protocol.h as "NAME value" lines, then "END".
 *
 * The frame-view API (dthc_rx_feed, dthc_frame_to_msg, dthc_encode_frame, dthc_get/put_*):
 *   N <hex>   a stream fed byte by byte to a fresh receiver through dthc_rx_feed. For each
 *             frame delivered: "FRAME type=.. seq=.. len=.. payload=<hex> inbuf=<0|1>"
 *             (inbuf: the payload view points into rx.buf, i.e. nothing was copied), then
 *             "OK <MessageName> ..." (dthc_frame_to_msg) or "ERR <code>", "RE <hex>"
 *             (dthc_encode_frame from the view into another buffer) and "IP <hex>" (the
 *             payload copied to DTHC_TX_PAYLOAD_OFFSET and encoded in place). For each
 *             dropped frame "ERR <code> type=.. seq=.. len=.. payload=<hex> inbuf=.." when
 *             the frame was filled, "ERR <code> untouched" when it was not. Then a STATS
 *             line as for S.
 *   R <hex>   a stream through the old dthc_rx_feed_byte: "MSG ..." per message, "ERR <code>
 *             reject_type=.. reject_seq=.." per dropped frame, then a STATS line.
 *   P <hex>   type, seq, payload for dthc_encode_frame: "WIRE <hex>" and "INPLACE <hex>"
 *             (payload at DTHC_TX_PAYLOAD_OFFSET of the output buffer), "STREAM <n> <hex>"
 *             (dthc_frame_seal's wire length, the bytes dthc_frame_stream gave its sink),
 *             "SEALED <hex>" (dthc_encode_in_place; " WROTE PAST <i>" if it wrote beyond
 *             len + DTHC_TX_PAYLOAD_OFFSET + 4 bytes),
 *             then "CAP <n>": the
 *             smallest cap that works, checking that every smaller cap returns 0 and every
 *             larger one the same bytes, and that nothing is written past the cap or the
 *             frame ("CAP BAD <cap>" otherwise). Or "ERR TOO_LONG".
 *   L <hex>   8 bytes: "LE u16=.. u32=.. i32=.. u64=.. put=<hex>" (dthc_get_* of the
 *             bytes, then dthc_put_u16/u32/i32/u64 of those values, 18 bytes).
 *   U <hex>   "CRC <4 hex digits>" by dthc_crc16_update, byte by byte from DTHC_CRC_INIT.
 * Empty lines and lines starting with '#' are ignored; anything else prints "ERR SYNTAX".
 *
 * Fields are printed in the order of firmware_protocol/declaration.py (dthc_messages.h's
 * DTHC_FOR_EACH_FIELD, the order of firmware_protocol/messages.py): integers in decimal,
 * bool as 0/1, samples_cv comma-separated (empty when there are none), cal_scale with
 * %.9g (enough to restore the binary32 exactly), serial as its characters with '\\' and
 * bytes outside 0x21..0x7E written as \xNN.
 */
#include <inttypes.h>
#include <stdio.h>
#include <string.h>

#include "dthc_protocol.h"

/* Raw bytes of the line being read (up to the largest stream a test sends). */
#define LINE_MAX_BYTES 65536

static uint8_t g_line[LINE_MAX_BYTES];

static const char *msg_name(uint8_t type)
{
    switch (type) {
#define NAME_CASE(NAME, member, Class) \
    case DTHC_MSG_##NAME: return #Class;
        DTHC_FOR_EACH_MESSAGE(NAME_CASE)
#undef NAME_CASE
    default: return "?";
    }
}

static const char *err_name(int rc)
{
    switch (rc) {
    case DTHC_ERR_CRC: return "CRC";
    case DTHC_ERR_COBS: return "COBS";
    case DTHC_ERR_SHORT: return "SHORT";
    case DTHC_ERR_UNKNOWN_TYPE: return "UNKNOWN_TYPE";
    case DTHC_ERR_BAD_LENGTH: return "BAD_LENGTH";
    case DTHC_ERR_TOO_LONG: return "TOO_LONG";
    default: return "?";
    }
}

static void print_hex(const uint8_t *p, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++) {
        printf("%02x", p[i]);
    }
}

static void pu(const char *key, uint32_t v) { printf(" %s=%" PRIu32, key, v); }
static void pi(const char *key, int32_t v) { printf(" %s=%" PRId32, key, v); }

static void print_serial(const char *key, const char *serial)
{
    size_t i;
    printf(" %s=", key);
    for (i = 0; i < DTHC_SERIAL_LEN && serial[i] != '\0'; i++) {
        unsigned c = (unsigned char)serial[i];
        if (c < 0x21 || c > 0x7E || c == '\\') {
            printf("\\x%02x", c);
        } else {
            putchar((int)c);
        }
    }
}

static void print_samples(const char *key, const uint16_t *samples, uint8_t n)
{
    uint8_t i;
    printf(" %s=", key);
    for (i = 0; i < n; i++) {
        printf(i ? ",%u" : "%u", (unsigned)samples[i]);
    }
}

/* One field of m->u.member by its kind (dthc_messages.h, DTHC_FOR_EACH_FIELD). */
#define PRINT_u(member, field) pu(#field, m->u.member.field)
#define PRINT_i(member, field) pi(#field, m->u.member.field)
#define PRINT_q(member, field) printf(" " #field "=%" PRIu64, m->u.member.field)
#define PRINT_f(member, field) printf(" " #field "=%.9g", (double)m->u.member.field)
#define PRINT_s(member, field) print_serial(#field, m->u.member.field)
#define PRINT_a(member, field) print_samples(#field, m->u.member.field, m->u.member.n_samples)
#define PRINT_FIELD(NAME, member, field, kind) \
    if (m->type == DTHC_MSG_##NAME) {          \
        PRINT_##kind(member, field);           \
    }

/* Every field in the order of the declaration (the order of firmware_protocol/messages.py). */
static void print_fields(const dthc_msg_t *m)
{
    printf("%s seq=%u", msg_name(m->type), (unsigned)m->seq);
    DTHC_FOR_EACH_FIELD(PRINT_FIELD)
}

static void print_constants(void)
{
#define K(name) printf("%s %ld\n", #name, (long)(name))
    K(DTHC_PROTOCOL_MAJOR); K(DTHC_PROTOCOL_MINOR); K(DTHC_DELIMITER); K(DTHC_MAX_FRAME);
    K(DTHC_MAX_PAYLOAD); K(DTHC_MAX_ENCODED_FRAME); K(DTHC_MAX_WIRE_FRAME);
    K(DTHC_RX_BUF_SIZE); K(DTHC_CRC_POLY); K(DTHC_CRC_INIT); K(DTHC_CRC_CHECK_VALUE);
    K(DTHC_DEFAULT_SAMPLE_RATE_HZ); K(DTHC_SAMPLE_RATE_MIN_HZ); K(DTHC_SAMPLE_RATE_MAX_HZ);
    K(DTHC_DEFAULT_BATCH_SIZE); K(DTHC_MAX_BATCH_SIZE); K(DTHC_MOVING_AVERAGE_MAX);
    K(DTHC_LOW_PASS_MAX_HZ); K(DTHC_ARC_LOST_MAX_MS); K(DTHC_DEFAULT_LEASE_MS);
    K(DTHC_LEASE_MIN_MS); K(DTHC_LEASE_MAX_MS); K(DTHC_LEASE_DETAIL_LATCHED);
    K(DTHC_LEASE_DETAIL_IDLE); K(DTHC_DEFAULT_ZVEL_EXPIRY_MS);
    K(DTHC_ZVEL_EXPIRY_MIN_MS); K(DTHC_ZVEL_EXPIRY_MAX_MS); K(DTHC_STREAM_SEQ_NEWER_MAX);
    K(DTHC_HOST_WINDOW); K(DTHC_DEFAULT_ACK_TIMEOUT_MS); K(DTHC_MAX_ATTEMPTS);
    K(DTHC_FAULT_REPEAT_MS); K(DTHC_XY_SPEED_UNKNOWN); K(DTHC_SERIAL_LEN);
    K(DTHC_SAMPLES_HEADER_SIZE); K(DTHC_MAX_SAMPLES); K(DTHC_TX_PAYLOAD_OFFSET);

    K(DTHC_MSG_HELLO); K(DTHC_MSG_HEARTBEAT); K(DTHC_MSG_SET_LEASE); K(DTHC_MSG_TORCH);
    K(DTHC_MSG_OHMIC_SENSE); K(DTHC_MSG_Z_MOVE); K(DTHC_MSG_Z_PROBE); K(DTHC_MSG_Z_VELOCITY);
    K(DTHC_MSG_Z_STOP); K(DTHC_MSG_SET_CURRENT); K(DTHC_MSG_CONFIGURE); K(DTHC_MSG_QUERY);
    K(DTHC_MSG_CLOCK_QUERY); K(DTHC_MSG_FAULT_RESET); K(DTHC_MSG_Z_PROBE_AWAY);
    K(DTHC_MSG_Z_HOME);
    K(DTHC_MSG_ACK); K(DTHC_MSG_NAK);
    K(DTHC_MSG_HELLO_INFO); K(DTHC_MSG_SAMPLES); K(DTHC_MSG_EVENT); K(DTHC_MSG_FAULT);
    K(DTHC_MSG_MOTION_DONE); K(DTHC_MSG_PROBE_RESULT); K(DTHC_MSG_STATUS); K(DTHC_MSG_CLOCK);
    K(DTHC_MSG_HOME_RESULT);

    K(DTHC_INPUT_ARC_OK); K(DTHC_INPUT_OHMIC); K(DTHC_INPUT_FLOAT); K(DTHC_INPUT_BREAKAWAY);
    K(DTHC_INPUT_THC_UP); K(DTHC_INPUT_THC_DOWN); K(DTHC_INPUT_ESTOP);
    K(DTHC_INPUT_Z_LIMIT_MIN); K(DTHC_INPUT_Z_LIMIT_MAX);

    K(DTHC_STATUS_TORCH_ON); K(DTHC_STATUS_OHMIC_SENSE); K(DTHC_STATUS_FAULT_LATCHED);
    K(DTHC_STATUS_Z_BUSY); K(DTHC_STATUS_SAMPLE_OVERFLOW); K(DTHC_STATUS_SESSION);
    K(DTHC_STATUS_HOMED);

    K(DTHC_CAP_XY_SPEED); K(DTHC_CAP_OHMIC); K(DTHC_CAP_FLOAT); K(DTHC_CAP_BREAKAWAY);
    K(DTHC_CAP_THC_UPDOWN); K(DTHC_CAP_CURRENT_OUT); K(DTHC_CAP_ESTOP); K(DTHC_CAP_Z_LIMITS);
    K(DTHC_CAP_FILTERS); K(DTHC_CAP_HOMING);

    K(DTHC_FAULT_LEASE_EXPIRED); K(DTHC_FAULT_Z_LIMIT); K(DTHC_FAULT_BREAKAWAY);
    K(DTHC_FAULT_ESTOP); K(DTHC_FAULT_ARC_LOST); K(DTHC_FAULT_INTERNAL);
    K(DTHC_INTERNAL_TICK_OVERRUN); K(DTHC_INTERNAL_ADC_INCOMPLETE);
    K(DTHC_INTERNAL_WATCHDOG_NEAR_MISS);

    K(DTHC_NAK_UNKNOWN_TYPE); K(DTHC_NAK_BAD_LENGTH); K(DTHC_NAK_OUT_OF_RANGE);
    K(DTHC_NAK_FAULT_LATCHED); K(DTHC_NAK_BUSY); K(DTHC_NAK_NO_SESSION);
    K(DTHC_NAK_UNSUPPORTED); K(DTHC_NAK_VERSION); K(DTHC_NAK_FAULT_ACTIVE);

    K(DTHC_RESET_POWER_ON); K(DTHC_RESET_WATCHDOG); K(DTHC_RESET_SOFTWARE);
    K(DTHC_RESET_BROWNOUT); K(DTHC_RESET_EXTERNAL); K(DTHC_RESET_UNKNOWN);

    K(DTHC_PROBE_CONTACT); K(DTHC_PROBE_NO_CONTACT); K(DTHC_PROBE_ABORTED);
    K(DTHC_PROBE_LIMIT); K(DTHC_PROBE_RELEASED); K(DTHC_PROBE_NO_RELEASE);

    K(DTHC_HOME_HOMED); K(DTHC_HOME_NOT_FOUND); K(DTHC_HOME_TIMEOUT); K(DTHC_HOME_ABORTED);
    K(DTHC_HOME_NO_RELEASE);

    K(DTHC_MOTION_REACHED); K(DTHC_MOTION_STOPPED); K(DTHC_MOTION_LIMIT);
    K(DTHC_MOTION_FAULT); K(DTHC_MOTION_SUPERSEDED);

    K(DTHC_FILTER_NONE); K(DTHC_FILTER_MOVING_AVERAGE); K(DTHC_FILTER_LOW_PASS);
    K(DTHC_FILTER_MEDIAN3);

    K(DTHC_QUERY_STATUS); K(DTHC_QUERY_PROBE_RESULT); K(DTHC_QUERY_HELLO_INFO);
    K(DTHC_QUERY_MOTION_DONE); K(DTHC_QUERY_HOME_RESULT);

    K(DTHC_OK); K(DTHC_ERR_CRC); K(DTHC_ERR_COBS); K(DTHC_ERR_SHORT);
    K(DTHC_ERR_UNKNOWN_TYPE); K(DTHC_ERR_BAD_LENGTH); K(DTHC_ERR_TOO_LONG);
#undef K
    printf("END\n");
}

static int hex_digit(int c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    return -1;
}

/* Read the rest of the line as hex into g_line. Returns the byte count, or -1 on a
 * syntax error (odd digit count, bad character, too long); the line is consumed either way. */
static long read_hex_line(void)
{
    long n = 0;
    int hi = -1;
    int bad = 0;
    int c;
    while ((c = getchar()) != EOF && c != '\n') {
        int d;
        if (c == ' ' || c == '\t' || c == '\r') {
            continue;
        }
        d = hex_digit(c);
        if (d < 0 || n >= LINE_MAX_BYTES) {
            bad = 1;
            continue;
        }
        if (hi < 0) {
            hi = d;
        } else {
            g_line[n++] = (uint8_t)((hi << 4) | d);
            hi = -1;
        }
    }
    return (bad || hi >= 0) ? -1 : n;
}

static void skip_line(int c)
{
    while (c != EOF && c != '\n') {
        c = getchar();
    }
}

static void cmd_frame(size_t n)
{
    static dthc_rx_t rx;
    static dthc_msg_t msg;
    static uint8_t wire[DTHC_MAX_WIRE_FRAME];
    int any = 0;
    size_t i;
    dthc_rx_init(&rx);
    for (i = 0; i < n; i++) {
        int rc = dthc_rx_feed_byte(&rx, g_line[i], &msg);
        if (rc == 1) {
            size_t len = dthc_encode(&msg, wire, sizeof wire);
            printf("OK ");
            print_fields(&msg);
            printf("\n");
            if (len == 0) {
                printf("ERR ENCODE\n");
            } else {
                printf("RE ");
                print_hex(wire, len);
                printf("\n");
            }
            any = 1;
        } else if (rc < 0) {
            printf("ERR %s\n", err_name(rc));
            any = 1;
        }
    }
    if (!any) {
        printf("ERR INCOMPLETE\n");
    }
}

static void cmd_body(size_t n)
{
    static dthc_msg_t msg;
    static uint8_t body[DTHC_MAX_FRAME];
    int rc = dthc_decode_body(g_line, n, &msg);
    size_t len;
    if (rc != DTHC_OK) {
        printf("ERR %s\n", err_name(rc));
        return;
    }
    printf("OK ");
    print_fields(&msg);
    printf("\n");
    len = dthc_encode_body(&msg, body, sizeof body);
    if (len == 0) {
        printf("ERR ENCODE\n");
        return;
    }
    printf("BODY ");
    print_hex(body, len);
    printf("\n");
}

static void print_stats(const dthc_rx_t *rx);

static void cmd_stream(size_t n)
{
    static dthc_rx_t rx;
    static dthc_msg_t msg;
    size_t i;
    dthc_rx_init(&rx);
    for (i = 0; i < n; i++) {
        if (dthc_rx_feed_byte(&rx, g_line[i], &msg) == 1) {
            printf("MSG ");
            print_fields(&msg);
            printf("\n");
        }
    }
    print_stats(&rx);
}

static void print_stats(const dthc_rx_t *rx)
{
    printf("STATS frames_ok=%" PRIu32 " crc_errors=%" PRIu32 " framing_errors=%" PRIu32
           " unknown_type=%" PRIu32 " length_errors=%" PRIu32 " dropped_bytes=%" PRIu32
           " bytes_in=%" PRIu32 "\n",
           rx->frames_ok, rx->crc_errors, rx->framing_errors, rx->unknown_type,
           rx->length_errors, rx->dropped_bytes, rx->bytes_in);
}

static void print_view(const dthc_rx_t *rx, const dthc_frame_t *f)
{
    printf("type=%u seq=%u len=%u payload=", (unsigned)f->type, (unsigned)f->seq,
           (unsigned)f->len);
    print_hex(f->payload, f->len);
    printf(" inbuf=%d", f->payload == rx->buf + 2 ? 1 : 0);
}

static void cmd_view_stream(size_t n)
{
    static dthc_rx_t rx;
    static dthc_msg_t msg;
    static uint8_t wire[DTHC_MAX_WIRE_FRAME];
    static const uint8_t marker = 0;
    /* Sentinel contents: a field the receiver writes no longer matches. */
    const dthc_frame_t sentinel = {0xA5, 0x5A, &marker, 0xC3};
    dthc_frame_t f;
    size_t i;
    dthc_rx_init(&rx);
    for (i = 0; i < n; i++) {
        int rc;
        f = sentinel;
        rc = dthc_rx_feed(&rx, g_line[i], &f);
        if (rc == 1) {
            size_t len;
            int rc2;
            printf("FRAME ");
            print_view(&rx, &f);
            printf("\n");
            rc2 = dthc_frame_to_msg(&f, &msg);
            if (rc2 == DTHC_OK) {
                printf("OK ");
                print_fields(&msg);
                printf("\n");
            } else {
                printf("ERR %s\n", err_name(rc2));
            }
            len = dthc_encode_frame(f.type, f.seq, f.payload, f.len, wire, sizeof wire);
            printf("RE ");
            print_hex(wire, len);
            printf("\n");
            memset(wire, 0xEE, sizeof wire);
            memcpy(wire + DTHC_TX_PAYLOAD_OFFSET, f.payload, f.len);
            len = dthc_encode_frame(f.type, f.seq, wire + DTHC_TX_PAYLOAD_OFFSET, f.len, wire,
                                    sizeof wire);
            printf("IP ");
            print_hex(wire, len);
            printf("\n");
        } else if (rc < 0) {
            printf("ERR %s ", err_name(rc));
            if (f.type == sentinel.type && f.seq == sentinel.seq
                && f.payload == sentinel.payload && f.len == sentinel.len) {
                printf("untouched");
            } else {
                print_view(&rx, &f);
            }
            printf("\n");
        } else if (f.type != sentinel.type || f.seq != sentinel.seq
                   || f.payload != sentinel.payload || f.len != sentinel.len) {
            printf("ERR FRAME_WRITTEN_ON_0\n");
        }
    }
    print_stats(&rx);
}

static void cmd_old_stream(size_t n)
{
    static dthc_rx_t rx;
    static dthc_msg_t msg;
    size_t i;
    dthc_rx_init(&rx);
    for (i = 0; i < n; i++) {
        int rc = dthc_rx_feed_byte(&rx, g_line[i], &msg);
        if (rc == 1) {
            printf("MSG ");
            print_fields(&msg);
            printf("\n");
        } else if (rc < 0) {
            printf("ERR %s reject_type=%u reject_seq=%u\n", err_name(rc),
                   (unsigned)rx.reject_type, (unsigned)rx.reject_seq);
        }
    }
    print_stats(&rx);
}

static uint8_t g_sink[2 * DTHC_MAX_WIRE_FRAME];
static size_t g_sink_len;

static void sink_collect(const uint8_t *bytes, uint8_t n)
{
    while (n-- && g_sink_len < sizeof g_sink) {
        g_sink[g_sink_len++] = *bytes++;
    }
}

static void cmd_encode_frame(size_t n)
{
    static uint8_t wire[DTHC_MAX_WIRE_FRAME + 8];
    static uint8_t other[DTHC_MAX_WIRE_FRAME + 8];
    size_t len;
    size_t cap;
    size_t k;
    const uint8_t *payload = g_line + 2;
    size_t plen = n >= 2 ? n - 2 : 0;
    if (n < 2) {
        printf("ERR SYNTAX\n");
        return;
    }
    len = dthc_encode_frame(g_line[0], g_line[1], payload, plen, wire, sizeof wire);
    if (len == 0) {
        printf("ERR TOO_LONG\n");
        return;
    }
    printf("WIRE ");
    print_hex(wire, len);
    printf("\n");

    memset(other, 0xEE, sizeof other);
    memcpy(other + DTHC_TX_PAYLOAD_OFFSET, payload, plen);
    printf("INPLACE ");
    print_hex(other, dthc_encode_frame(g_line[0], g_line[1], other + DTHC_TX_PAYLOAD_OFFSET,
                                       plen, other, sizeof other));
    printf("\n");

    /* Streamed: sealed in a buffer, the blocks collected from the sink. */
    memset(other, 0xEE, sizeof other);
    memcpy(other + DTHC_TX_PAYLOAD_OFFSET, payload, plen);
    g_sink_len = 0;
    cap = dthc_frame_seal(g_line[0], g_line[1], other, plen);
    dthc_frame_stream(other, plen, sink_collect);
    printf("STREAM %u ", (unsigned)cap);
    print_hex(g_sink, g_sink_len);
    printf("\n");

    memset(other, 0xEE, sizeof other);
    memcpy(other + DTHC_TX_PAYLOAD_OFFSET, payload, plen);
    cap = dthc_encode_in_place(g_line[0], g_line[1], other, plen);
    printf("SEALED ");
    print_hex(other, cap);
    for (k = cap; k < sizeof other; k++) {
        if (other[k] != 0xEE && k >= plen + DTHC_TX_PAYLOAD_OFFSET + 4) {
            printf(" WROTE PAST %u", (unsigned)k);
            break;
        }
    }
    printf("\n");

    for (cap = 0; cap < sizeof other; cap++) {
        size_t got;
        memset(other, 0xEE, sizeof other);
        got = dthc_encode_frame(g_line[0], g_line[1], payload, plen, other, cap);
        if (cap < len ? got != 0 : (got != len || memcmp(other, wire, len) != 0)) {
            printf("CAP BAD %u\n", (unsigned)cap);
            return;
        }
        for (k = cap < len ? cap : len; k < sizeof other; k++) {
            if (other[k] != 0xEE) { /* wrote past cap, or past the frame */
                printf("CAP BAD %u\n", (unsigned)cap);
                return;
            }
        }
    }
    printf("CAP %u\n", (unsigned)len);
}

static void cmd_le(size_t n)
{
    uint8_t out[18];
    uint16_t u16;
    uint32_t u32;
    int32_t i32;
    uint64_t u64;
    if (n != 8) {
        printf("ERR SYNTAX\n");
        return;
    }
    u16 = dthc_get_u16(g_line);
    u32 = dthc_get_u32(g_line);
    i32 = dthc_get_i32(g_line);
    u64 = dthc_get_u64(g_line);
    dthc_put_u16(out, u16);
    dthc_put_u32(out + 2, u32);
    dthc_put_i32(out + 6, i32);
    dthc_put_u64(out + 10, u64);
    printf("LE u16=%u u32=%" PRIu32 " i32=%" PRId32 " u64=%" PRIu64 " put=", (unsigned)u16, u32,
           i32, u64);
    print_hex(out, sizeof out);
    printf("\n");
}

static void cmd_crc_update(size_t n)
{
    uint16_t crc = DTHC_CRC_INIT;
    size_t i;
    for (i = 0; i < n; i++) {
        crc = dthc_crc16_update(crc, g_line[i]);
    }
    printf("CRC %04X\n", (unsigned)crc);
}

static void cmd_cobs(int decode, size_t n)
{
    static uint8_t out[LINE_MAX_BYTES + LINE_MAX_BYTES / 254 + 2];
    size_t len = 0;
    if (decode) {
        int rc = dthc_cobs_decode(g_line, n, out, sizeof out, &len);
        if (rc != DTHC_OK) {
            printf("ERR %s\n", err_name(rc));
            return;
        }
        printf("RAW ");
    } else {
        len = dthc_cobs_encode(g_line, n, out, sizeof out);
        if (len == 0) {
            printf("ERR TOO_LONG\n");
            return;
        }
        printf("COBS ");
    }
    print_hex(out, len);
    printf("\n");
}

int main(void)
{
    int c;
    while ((c = getchar()) != EOF) {
        long n;
        if (c == '\n') {
            continue;
        }
        if (c == '#') {
            skip_line(c);
            continue;
        }
        if (c == 'K') {
            skip_line(c);
            print_constants();
            continue;
        }
        if (c == 0 || strchr("FBSCEDNRPLU", c) == NULL) {
            skip_line(c);
            printf("ERR SYNTAX\n");
            continue;
        }
        n = read_hex_line();
        if (n < 0) {
            printf("ERR SYNTAX\n");
            continue;
        }
        switch (c) {
        case 'F': cmd_frame((size_t)n); break;
        case 'B': cmd_body((size_t)n); break;
        case 'S': cmd_stream((size_t)n); break;
        case 'C': printf("CRC %04X\n", (unsigned)dthc_crc16(g_line, (size_t)n)); break;
        case 'E': cmd_cobs(0, (size_t)n); break;
        case 'N': cmd_view_stream((size_t)n); break;
        case 'R': cmd_old_stream((size_t)n); break;
        case 'P': cmd_encode_frame((size_t)n); break;
        case 'L': cmd_le((size_t)n); break;
        case 'U': cmd_crc_update((size_t)n); break;
        default: cmd_cobs(1, (size_t)n); break;
        }
        fflush(stdout);
    }
    return 0;
}
