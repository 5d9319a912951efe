/*
 * dthc_protocol.h - C99 reference codec of the DTHC board wire protocol, version 1.3.
 *
 * Normative spec: firmware_protocol/PROTOCOL.md. Golden vectors:
 * firmware_protocol/vectors/frames.json (checked by tests/firmware_protocol/test_c_codec.py).
 *
 * Made for microcontrollers: no malloc, no stdio, no floating-point arithmetic (the one f32
 * field is moved as its 4 bytes), only <stdint.h> <stddef.h> <string.h> <stdbool.h> (and
 * <avr/pgmspace.h> on AVR, for the CRC table in flash).
 * Every multi-byte field is read and written with explicit byte shifts, so the code is
 * independent of the host's byte order and alignment. The only assumption is that `float`
 * is IEEE-754 binary32 (checked at compile time for its size).
 *
 *   on the wire:   COBS( type | seq | payload | crc_hi | crc_lo ) | 0x00
 *   decoded frame: type u8 | seq u8 | payload (0..252 bytes) | crc u16 big-endian
 *
 * Two ways to use it:
 *
 * 1. Frame views (for small MCUs: no dthc_msg_t, which is about 254 bytes on AVR).
 *    Receiving: the receiver COBS-decodes in place into rx.buf and hands out a view:
 *        dthc_frame_t f;
 *        int rc = dthc_rx_feed(&rx, byte, &f);
 *        if (rc == 1) handle(f.type, f.seq, f.payload, f.len);
 *        else if (rc == DTHC_ERR_UNKNOWN_TYPE || rc == DTHC_ERR_BAD_LENGTH) nak(f.seq, ...);
 *    handle() reads the fields in place with the generated dthc_<message>_get_<field>
 *    (dthc_messages.h), e.g. dthc_z_move_get_target_um(f.payload).
 *    f.payload points into rx.buf: use it before feeding the next byte (feed from the main
 *    loop out of a ring buffer the UART ISR fills, not from the ISR itself).
 *    Sending: build the payload with dthc_<message>_put_<field> straight into the buffer at
 *    DTHC_TX_PAYLOAD_OFFSET and encode in place, one pass, CRC computed on the way:
 *        uint8_t *p = tx + DTHC_TX_PAYLOAD_OFFSET;  (tx of DTHC_MAX_WIRE_FRAME bytes)
 *        dthc_ack_put_boot_id(p, boot_id);
 *        n = dthc_encode_frame(DTHC_MSG_ACK, seq, p, DTHC_ACK_SIZE, tx, sizeof tx);
 *
 * 2. Messages (convenient on a host or a big MCU):
 *    Sending:   dthc_msg_t m = {DTHC_MSG_ACK, seq, {0}}; m.u.ack.boot_id = id;
 *               n = dthc_encode(&m, buf, sizeof buf);        (buf of DTHC_MAX_WIRE_FRAME)
 *    Receiving: dthc_rx_init(&rx); then for every received byte:
 *               if (dthc_rx_feed_byte(&rx, byte, &m) == 1) handle(&m);
 *
 * Speed, because a board has 1 ms to reply (PROTOCOL.md section 8): the CRC is table-driven
 * (512 bytes, in flash on AVR via PROGMEM, as is the payload-size table) and nothing is
 * copied. Measured in simavr at 16 MHz, avr-gcc -Os: a STATUS encoded by
 * dthc_encode_in_place about 75 us (ATmega2560 and ATmega328P; CRC and COBS in one pass
 * that rewrites only the zeros); with dthc_encode_frame about 175 us before its pointer
 * walk (dthc_encode about 295 us; the codec before this API 525 us); a QUERY received
 * through dthc_rx_feed about 95 us (dthc_rx_feed_byte 210 us, before 300 us). On the
 * emulated boards a lone QUERY(STATUS) gets its reply's first byte out 0.36 ms (p50; max
 * 0.51 ms) and its delimiter 0.76 ms (max 0.92 ms) after the query's delimiter arrived
 * (tests/emulated_board/test_firmware_board.py).
 *
 * Not thread-safe per object: one dthc_rx_t per link, fed from one context.
 */
#ifndef DTHC_PROTOCOL_H
#define DTHC_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#ifdef __cplusplus
extern "C" {
#endif

/* --- numbers (PROTOCOL.md sections 1-4, 8; firmware_protocol/constants.py) ------------- */

#define DTHC_PROTOCOL_MAJOR 1
/* 1.1: the idle lease lapse (PROTOCOL.md section 4); 1.2: Z_PROBE_AWAY; 1.3: Z_HOME
 * (section 6.1) */
#define DTHC_PROTOCOL_MINOR 3

#define DTHC_DELIMITER 0x00
/* Decoded frame = type(1) seq(1) payload(0..DTHC_MAX_PAYLOAD) crc(2). */
#define DTHC_MAX_FRAME 256
#define DTHC_MAX_PAYLOAD (DTHC_MAX_FRAME - 4)
/* COBS adds one code byte per started 254-byte block: 256 bytes need 2. */
#define DTHC_MAX_ENCODED_FRAME (DTHC_MAX_FRAME + 2)
/* One complete frame on the wire, delimiter included: the size of an encode buffer. */
#define DTHC_MAX_WIRE_FRAME (DTHC_MAX_ENCODED_FRAME + 1)
/* The receive buffer (PROTOCOL.md section 2: "never holds more than 259 bytes"). */
#define DTHC_RX_BUF_SIZE DTHC_MAX_WIRE_FRAME

/* dthc_encode_frame may read its payload from its own output buffer when the payload
 * starts at least this many bytes into it (type, seq and the first COBS code byte go
 * first; COBS never writes ahead of the byte it reads): encoding in place, no copy. */
#define DTHC_TX_PAYLOAD_OFFSET 3

/* CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, not reflected, xorout 0x0000. */
#define DTHC_CRC_POLY 0x1021
#define DTHC_CRC_INIT 0xFFFF
#define DTHC_CRC_CHECK_VALUE 0x29B1 /* CRC of the ASCII bytes "123456789" */

#define DTHC_DEFAULT_SAMPLE_RATE_HZ 1000
#define DTHC_SAMPLE_RATE_MIN_HZ 100
#define DTHC_SAMPLE_RATE_MAX_HZ 20000
#define DTHC_DEFAULT_BATCH_SIZE 5
#define DTHC_MAX_BATCH_SIZE 100 /* CONFIGURE.batch_size range 1..100 */
#define DTHC_MOVING_AVERAGE_MAX 32
#define DTHC_LOW_PASS_MAX_HZ 500
#define DTHC_ARC_LOST_MAX_MS 1000
#define DTHC_DEFAULT_LEASE_MS 250
#define DTHC_LEASE_MIN_MS 20
#define DTHC_LEASE_MAX_MS 2000
/* FAULT(LEASE_EXPIRED).detail (PROTOCOL.md sections 4-5): the lease ran out with the torch,
 * ohmic sensing or Z in use, the fault latched (until FAULT_RESET); or it ran out with the
 * board at rest: reported once per lapse, nothing latched, the next valid frame renews it. */
#define DTHC_LEASE_DETAIL_LATCHED 0
#define DTHC_LEASE_DETAIL_IDLE 1
/* FAULT(INTERNAL).detail (PROTOCOL.md section 5): which self-check failed. */
#define DTHC_INTERNAL_TICK_OVERRUN 1       /* the sample tick fell behind its schedule */
#define DTHC_INTERNAL_ADC_INCOMPLETE 2     /* an arc voltage sample's conversions missing */
#define DTHC_INTERNAL_WATCHDOG_NEAR_MISS 3 /* the main loop nearly let the watchdog fire */
#define DTHC_DEFAULT_ZVEL_EXPIRY_MS 20
#define DTHC_ZVEL_EXPIRY_MIN_MS 1
#define DTHC_ZVEL_EXPIRY_MAX_MS 200
/* Z_VELOCITY stream_seq is newer when (new - last) mod 2^16 is in 1..32767. */
#define DTHC_STREAM_SEQ_NEWER_MAX 32767
/* Sequenced commands outstanding at the host; outcomes remembered by the board. */
#define DTHC_HOST_WINDOW 8
#define DTHC_DEFAULT_ACK_TIMEOUT_MS 20
#define DTHC_MAX_ATTEMPTS 5 /* first transmission + 4 retransmissions */
#define DTHC_FAULT_REPEAT_MS 250
/* SAMPLES.xy_speed_dmm_s when the board does not measure XY speed. */
#define DTHC_XY_SPEED_UNKNOWN 0xFFFF

/* --- code tables (PROTOCOL.md sections 6 and 7) ---------------------------------------- */

/* Bit positions (indices) in the 16-bit input snapshot; bit = 1 when active.
 * EVENT.input carries such an index; masks are (1u << DTHC_INPUT_x). */
typedef enum {
    DTHC_INPUT_ARC_OK = 0,
    DTHC_INPUT_OHMIC = 1,
    DTHC_INPUT_FLOAT = 2,
    DTHC_INPUT_BREAKAWAY = 3,
    DTHC_INPUT_THC_UP = 4,
    DTHC_INPUT_THC_DOWN = 5,
    DTHC_INPUT_ESTOP = 6,
    DTHC_INPUT_Z_LIMIT_MIN = 7,
    DTHC_INPUT_Z_LIMIT_MAX = 8
} dthc_input_bit_t;

/* The 8-bit status byte of SAMPLES and STATUS (masks). */
typedef enum {
    DTHC_STATUS_TORCH_ON = 1 << 0,
    DTHC_STATUS_OHMIC_SENSE = 1 << 1,
    DTHC_STATUS_FAULT_LATCHED = 1 << 2,
    DTHC_STATUS_Z_BUSY = 1 << 3,
    DTHC_STATUS_SAMPLE_OVERFLOW = 1 << 4,
    DTHC_STATUS_SESSION = 1 << 5,
    DTHC_STATUS_HOMED = 1 << 6 /* Z homed since power-on (1.3) */
} dthc_status_bit_t;

/* HELLO_INFO capability bits (masks of the u32). */
typedef enum {
    DTHC_CAP_XY_SPEED = 1 << 0,
    DTHC_CAP_OHMIC = 1 << 1,
    DTHC_CAP_FLOAT = 1 << 2,
    DTHC_CAP_BREAKAWAY = 1 << 3,
    DTHC_CAP_THC_UPDOWN = 1 << 4,
    DTHC_CAP_CURRENT_OUT = 1 << 5,
    DTHC_CAP_ESTOP = 1 << 6,
    DTHC_CAP_Z_LIMITS = 1 << 7,
    DTHC_CAP_FILTERS = 1 << 8,
    DTHC_CAP_HOMING = 1 << 9 /* Z_HOME on a home switch at Z_LIMIT_MAX (1.3) */
} dthc_capability_t;

/* Latched faults; bit (1u << code) in the 16-bit fault set. */
typedef enum {
    DTHC_FAULT_LEASE_EXPIRED = 0,
    DTHC_FAULT_Z_LIMIT = 1,
    DTHC_FAULT_BREAKAWAY = 2,
    DTHC_FAULT_ESTOP = 3,
    DTHC_FAULT_ARC_LOST = 4,
    DTHC_FAULT_INTERNAL = 5
} dthc_fault_code_t;

typedef enum {
    DTHC_NAK_UNKNOWN_TYPE = 1,
    DTHC_NAK_BAD_LENGTH = 2,
    DTHC_NAK_OUT_OF_RANGE = 3,  /* detail: index of the offending payload field */
    DTHC_NAK_FAULT_LATCHED = 4, /* detail: lowest latched fault code */
    DTHC_NAK_BUSY = 5,
    DTHC_NAK_NO_SESSION = 6,
    DTHC_NAK_UNSUPPORTED = 7,   /* detail: capability bit index */
    DTHC_NAK_VERSION = 8,       /* detail: the board's protocol major */
    DTHC_NAK_FAULT_ACTIVE = 9   /* detail: the fault whose cause is still present */
} dthc_nak_code_t;

typedef enum {
    DTHC_RESET_POWER_ON = 0,
    DTHC_RESET_WATCHDOG = 1,
    DTHC_RESET_SOFTWARE = 2,
    DTHC_RESET_BROWNOUT = 3,
    DTHC_RESET_EXTERNAL = 4,
    DTHC_RESET_UNKNOWN = 5
} dthc_reset_reason_t;

typedef enum {
    DTHC_PROBE_CONTACT = 0,
    DTHC_PROBE_NO_CONTACT = 1, /* max travel reached */
    DTHC_PROBE_ABORTED = 2,    /* Z_STOP, fault or lease expiry */
    DTHC_PROBE_LIMIT = 3,      /* Z soft limit reached first */
    DTHC_PROBE_RELEASED = 4,   /* Z_PROBE_AWAY: every sensor of the set inactive (1.2) */
    DTHC_PROBE_NO_RELEASE = 5  /* Z_PROBE_AWAY: max travel reached, a sensor still active */
} dthc_probe_result_code_t;

typedef enum {
    DTHC_HOME_HOMED = 0,
    DTHC_HOME_NOT_FOUND = 1,  /* the switch did not close within max travel */
    DTHC_HOME_TIMEOUT = 2,    /* the cycle outlasted timeout_ms */
    DTHC_HOME_ABORTED = 3,    /* Z_STOP, a new Z command, a fault or the lease */
    DTHC_HOME_NO_RELEASE = 4  /* backing off by max travel did not open the switch */
} dthc_home_outcome_t;

typedef enum {
    DTHC_MOTION_REACHED = 0,
    DTHC_MOTION_STOPPED = 1,
    DTHC_MOTION_LIMIT = 2,
    DTHC_MOTION_FAULT = 3,
    DTHC_MOTION_SUPERSEDED = 4
} dthc_motion_result_t;

typedef enum {
    DTHC_FILTER_NONE = 0,
    DTHC_FILTER_MOVING_AVERAGE = 1, /* param: window in samples, 1..32 */
    DTHC_FILTER_LOW_PASS = 2,       /* param: first-order cut-off in Hz, 1..500 */
    DTHC_FILTER_MEDIAN3 = 3         /* param: ignored */
} dthc_filter_kind_t;

typedef enum {
    DTHC_QUERY_STATUS = 0,
    DTHC_QUERY_PROBE_RESULT = 1,
    DTHC_QUERY_HELLO_INFO = 2,
    DTHC_QUERY_MOTION_DONE = 3,
    DTHC_QUERY_HOME_RESULT = 4 /* 1.3 */
} dthc_query_what_t;

/* Results of the decoding functions: 0 or one of these. */
typedef enum {
    DTHC_OK = 0,
    DTHC_ERR_CRC = -1,          /* CRC over the decoded frame is not zero */
    DTHC_ERR_COBS = -2,         /* invalid COBS (a block runs past the end, or a 0x00) */
    DTHC_ERR_SHORT = -3,        /* decoded frame shorter than 4 bytes */
    DTHC_ERR_UNKNOWN_TYPE = -4, /* valid CRC, type not in dthc_msg_type_t */
    DTHC_ERR_BAD_LENGTH = -5,   /* known type, wrong payload length */
    DTHC_ERR_TOO_LONG = -6      /* longer than the maximum frame, or the output buffer */
} dthc_err_t;

/* --- little-endian field helpers --------------------------------------------------------
 * Read and write payload fields in place (PROTOCOL.md section 1: little-endian), with byte
 * shifts, so they work on any host byte order and any alignment. */

static inline void dthc_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static inline void dthc_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

static inline void dthc_put_i32(uint8_t *p, int32_t v)
{
    dthc_put_u32(p, (uint32_t)v); /* modulo 2^32: two's complement bytes on every host */
}

static inline void dthc_put_u64(uint8_t *p, uint64_t v)
{
    dthc_put_u32(p, (uint32_t)(v & 0xFFFFFFFFu));
    dthc_put_u32(p + 4, (uint32_t)(v >> 32));
}

static inline uint16_t dthc_get_u16(const uint8_t *p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

static inline uint32_t dthc_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16)
           | ((uint32_t)p[3] << 24);
}

static inline int32_t dthc_get_i32(const uint8_t *p)
{
    uint32_t u = dthc_get_u32(p);
    /* Two's complement without implementation-defined unsigned-to-signed conversion. */
    if (u <= 0x7FFFFFFFu) {
        return (int32_t)u;
    }
    return -(int32_t)(~u) - 1;
}

static inline uint64_t dthc_get_u64(const uint8_t *p)
{
    return (uint64_t)dthc_get_u32(p) | ((uint64_t)dthc_get_u32(p + 4) << 32);
}

/* f32 fields move as the 4 bytes of an IEEE-754 binary32 `float` (no float arithmetic). */
static inline void dthc_put_f32(uint8_t *p, float v)
{
    uint32_t bits;
    memcpy(&bits, &v, sizeof bits);
    dthc_put_u32(p, bits);
}

static inline float dthc_get_f32(const uint8_t *p)
{
    uint32_t bits = dthc_get_u32(p);
    float v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

/* --- messages ---------------------------------------------------------------------------
 * Generated from firmware_protocol/declaration.py: the message type codes, one struct per
 * message type (dthc_msg_t), payload sizes, and field accessors for frame views
 * (dthc_status_put_z_um(p, v), dthc_z_move_get_target_um(p), ...). */
#include "dthc_messages.h"

/* --- functions -------------------------------------------------------------------------- */

/* CRC-16/CCITT-FALSE of `len` bytes. dthc_crc16_update continues a running CRC (start
 * with DTHC_CRC_INIT). The CRC of a whole decoded frame, CRC bytes included, is 0. */
uint16_t dthc_crc16(const uint8_t *data, size_t len);
uint16_t dthc_crc16_update(uint16_t crc, uint8_t byte);

/* One pass, no body buffer: the complete wire frame
 * COBS(type | seq | payload | crc_hi | crc_lo) | 0x00 into `out`, the CRC computed as the
 * bytes go. `payload` may be NULL when len is 0, and may lie inside `out` at
 * DTHC_TX_PAYLOAD_OFFSET or later (in-place encoding). Returns the wire length, or 0 if
 * len > DTHC_MAX_PAYLOAD or it does not fit `cap` (DTHC_MAX_WIRE_FRAME always fits).
 * Type and length are not checked against the message table: a test can send anything. */
size_t dthc_encode_frame(uint8_t type, uint8_t seq, const uint8_t *payload, size_t len,
                         uint8_t *out, size_t cap);

/* Streaming (a board that feeds its UART's transmit ring while it encodes, so the first
 * byte leaves before the last is made):
 *   n = dthc_frame_seal(type, seq, buf, len);   payload at buf + DTHC_TX_PAYLOAD_OFFSET
 *   reserve n bytes of the ring (all or nothing), then
 *   dthc_frame_stream(buf, len, sink);          sink gets exactly those n bytes, in order
 * dthc_frame_seal puts type and seq in front of the payload (buf[1], buf[2]) and the CRC
 * behind it (buf needs len + DTHC_TX_PAYLOAD_OFFSET + 2 bytes), and returns the exact wire
 * length, delimiter included (0 when len > DTHC_MAX_PAYLOAD). dthc_frame_stream hands a
 * sealed frame's wire bytes to `sink` a COBS block at a time (a code byte, then its data
 * bytes, then the delimiter): the same bytes as dthc_encode_frame. */
/* dthc_encode_in_place: the complete wire frame at buf[0..n) from a payload at
 * buf + DTHC_TX_PAYLOAD_OFFSET (buf holds len + DTHC_TX_PAYLOAD_OFFSET + 4 bytes): sealed,
 * with COBS in the same pass, up to 254 body bytes, by rewriting only the zeros (every
 * other byte is already where COBS puts it): the fastest way to a queueable frame on AVR,
 * about 75 us for a STATUS at 16 MHz. Returns n, 0 when len > DTHC_MAX_PAYLOAD. */
size_t dthc_encode_in_place(uint8_t type, uint8_t seq, uint8_t *buf, size_t len);
typedef void (*dthc_sink_fn)(const uint8_t *bytes, uint8_t n);
size_t dthc_frame_seal(uint8_t type, uint8_t seq, uint8_t *buf, size_t len);
void dthc_frame_stream(const uint8_t *buf, size_t len, dthc_sink_fn sink);

/* Payload size of a message type: the fixed size, for SAMPLES the fixed part
 * (DTHC_SAMPLES_HEADER_SIZE, plus 2 per sample), or -1 for an unknown type. */
int dthc_payload_size(uint8_t type);

/* COBS-encode `len` bytes (no delimiter appended). Returns the encoded length (>= 1), or 0
 * if it does not fit `cap` bytes. The output is at most len + len / 254 + 1 bytes. */
size_t dthc_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);

/* COBS-decode `len` bytes (without the delimiter) into `out`; `out` may equal `in`
 * (in-place). Sets *out_len and returns 0, or returns DTHC_ERR_COBS (invalid input) or
 * DTHC_ERR_TOO_LONG (does not fit `cap`). */
int dthc_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len);

/* The decoded frame body without CRC (type, seq, payload) of `msg`. Returns its length, or
 * 0 on error (unknown type, n_samples > DTHC_MAX_SAMPLES, serial longer than 16, or it
 * does not fit `cap`). */
size_t dthc_encode_body(const dthc_msg_t *msg, uint8_t *out, size_t cap);

/* The complete wire frame of `msg`: COBS(body | crc_hi | crc_lo) | 0x00. Returns its length,
 * or 0 on error (as dthc_encode_body). A buffer of DTHC_MAX_WIRE_FRAME bytes always fits.
 * The payload is packed into `out` itself and encoded in place (dthc_encode_frame), so it
 * needs no stack buffer. */
size_t dthc_encode(const dthc_msg_t *msg, uint8_t *out, size_t cap);

/* Decode one decoded frame (type, seq, payload, crc; COBS already removed). Checks, in
 * order: length <= DTHC_MAX_FRAME (TOO_LONG), length >= 4 (SHORT), CRC, known type, exact
 * payload length. Returns 0 and fills *out, or a negative dthc_err_t (*out untouched). */
int dthc_decode_body(const uint8_t *raw, size_t len, dthc_msg_t *out);

/* A received frame, decoded in place: the header and a view of the payload. */
typedef struct {
    uint8_t type;
    uint8_t seq;
    const uint8_t *payload; /* points into the receiver's buffer: valid until the next feed */
    uint8_t len;            /* payload bytes (0..DTHC_MAX_PAYLOAD) */
} dthc_frame_t;

/* Unpack a frame's payload into a message (the old, RAM-hungry way: a dthc_msg_t is about
 * 254 bytes on AVR). Checks type and exact payload length first. Returns 0 and fills *out,
 * or DTHC_ERR_UNKNOWN_TYPE / DTHC_ERR_BAD_LENGTH (*out untouched). */
int dthc_frame_to_msg(const dthc_frame_t *frame, dthc_msg_t *out);

/* Streaming receiver (PROTOCOL.md section 2, "Receiving and resynchronising").
 * COBS decoding and the CRC run as the bytes arrive, into buf, so a byte costs O(1) and a
 * completed frame is handed out as a view of buf (dthc_rx_feed). The counters mean what
 * the Python firmware_protocol.stream.DecoderStats counters mean:
 *   frames_ok       valid messages delivered
 *   crc_errors      frames with a bad CRC
 *   framing_errors  invalid COBS, decoded length < 4 or > DTHC_MAX_FRAME, or more than
 *                   DTHC_MAX_ENCODED_FRAME bytes without a delimiter (one error; the rest
 *                   up to the next 0x00 is discarded)
 *   unknown_type    valid CRC, unknown type
 *   length_errors   known type, wrong payload length
 *   dropped_bytes   bytes of dropped frames, each with the delimiter that ended it
 *                   (idle delimiters, i.e. empty frames, count nothing)
 *   bytes_in        every byte fed */
typedef struct {
    uint8_t buf[DTHC_RX_BUF_SIZE]; /* decoded bytes of the frame being received */
    uint16_t enc_len;              /* encoded bytes received since the last delimiter */
    uint16_t dec_len;              /* decoded bytes in buf */
    uint16_t crc;                  /* running CRC over buf[0..dec_len) */
    uint8_t block_left;            /* data bytes left in the current COBS block */
    bool zero_pending;             /* the current block ends in an implied 0x00 */
    bool discarding;               /* after an over-long run: drop up to the next 0x00 */
    /* type and seq of the last frame rejected for an unknown type or a bad payload length
     * (its CRC was valid, so its seq can be NAKed; PROTOCOL.md section 7). Kept by
     * dthc_rx_reset, cleared by dthc_rx_init. For callers of dthc_rx_feed_byte. */
    uint8_t reject_type;
    uint8_t reject_seq;
    uint32_t bytes_in;
    uint32_t frames_ok;
    uint32_t crc_errors;
    uint32_t framing_errors;
    uint32_t unknown_type;
    uint32_t length_errors;
    uint32_t dropped_bytes;
} dthc_rx_t;

/* Clear the receiver, counters included. */
void dthc_rx_init(dthc_rx_t *rx);

/* Forget a partial frame (after reopening the link); keeps the counters. */
void dthc_rx_reset(dthc_rx_t *rx);

/* Feed one received byte. Returns 1 with *frame filled when a frame with valid COBS,
 * length and CRC, a known type and the exact payload length completed; 0 when more bytes
 * are needed (or on an idle delimiter); a negative dthc_err_t when a frame was dropped (it
 * is counted). For DTHC_ERR_UNKNOWN_TYPE and DTHC_ERR_BAD_LENGTH *frame is ALSO filled
 * (type, seq, payload, len), so a firmware can NAK it with the frame's seq (PROTOCOL.md
 * section 7); for the other errors *frame is untouched. Nothing is copied: frame->payload
 * points into rx->buf and is valid until the next call. O(1) per byte. */
int dthc_rx_feed(dthc_rx_t *rx, uint8_t byte, dthc_frame_t *frame);

/* The old API: dthc_rx_feed, then dthc_frame_to_msg. Returns 1 when it completed a valid
 * message (written to *out), 0 when more bytes are needed (or on an idle delimiter), or a
 * negative dthc_err_t when a frame was dropped (it is counted; *out is untouched; for
 * UNKNOWN_TYPE and BAD_LENGTH rx->reject_type and rx->reject_seq say which frame). */
int dthc_rx_feed_byte(dthc_rx_t *rx, uint8_t byte, dthc_msg_t *out);

#ifdef __cplusplus
}
#endif

#endif /* DTHC_PROTOCOL_H */
