/*
 * dthc_protocol.c - C99 reference codec of the DTHC board wire protocol (PROTOCOL.md).
 * See dthc_protocol.h for the interface.
 */
#include "dthc_protocol.h"

#include <string.h>

/* cal_scale is moved as the 4 bytes of an IEEE-754 binary32 `float`. */
typedef char dthc_float_must_be_32_bits[(sizeof(float) == 4) ? 1 : -1];

/* --- CRC-16/CCITT-FALSE ------------------------------------------------------------------
 * Table-driven, one lookup per byte: crc' = (crc << 8) ^ T[(crc >> 8) ^ byte], where T[i] is
 * the CRC register after shifting i << 8 through the polynomial 0x1021 eight times. The 512
 * bytes go to flash on AVR (a const table would otherwise be copied to its 2 KB of RAM). */

#ifdef __AVR__
#include <avr/pgmspace.h>
#define DTHC_FLASH_ATTR PROGMEM
#define DTHC_CRC_TABLE_READ(i) ((uint16_t)pgm_read_word(&dthc_crc_table[(i)]))
#define DTHC_FLASH_READ_BYTE(p) ((uint8_t)pgm_read_byte(p))
#else
#define DTHC_FLASH_ATTR
#define DTHC_CRC_TABLE_READ(i) (dthc_crc_table[(i)])
#define DTHC_FLASH_READ_BYTE(p) (*(p))
#endif

static const uint16_t dthc_crc_table[256] DTHC_FLASH_ATTR = {
    0x0000, 0x1021, 0x2042, 0x3063, 0x4084, 0x50A5, 0x60C6, 0x70E7,
    0x8108, 0x9129, 0xA14A, 0xB16B, 0xC18C, 0xD1AD, 0xE1CE, 0xF1EF,
    0x1231, 0x0210, 0x3273, 0x2252, 0x52B5, 0x4294, 0x72F7, 0x62D6,
    0x9339, 0x8318, 0xB37B, 0xA35A, 0xD3BD, 0xC39C, 0xF3FF, 0xE3DE,
    0x2462, 0x3443, 0x0420, 0x1401, 0x64E6, 0x74C7, 0x44A4, 0x5485,
    0xA56A, 0xB54B, 0x8528, 0x9509, 0xE5EE, 0xF5CF, 0xC5AC, 0xD58D,
    0x3653, 0x2672, 0x1611, 0x0630, 0x76D7, 0x66F6, 0x5695, 0x46B4,
    0xB75B, 0xA77A, 0x9719, 0x8738, 0xF7DF, 0xE7FE, 0xD79D, 0xC7BC,
    0x48C4, 0x58E5, 0x6886, 0x78A7, 0x0840, 0x1861, 0x2802, 0x3823,
    0xC9CC, 0xD9ED, 0xE98E, 0xF9AF, 0x8948, 0x9969, 0xA90A, 0xB92B,
    0x5AF5, 0x4AD4, 0x7AB7, 0x6A96, 0x1A71, 0x0A50, 0x3A33, 0x2A12,
    0xDBFD, 0xCBDC, 0xFBBF, 0xEB9E, 0x9B79, 0x8B58, 0xBB3B, 0xAB1A,
    0x6CA6, 0x7C87, 0x4CE4, 0x5CC5, 0x2C22, 0x3C03, 0x0C60, 0x1C41,
    0xEDAE, 0xFD8F, 0xCDEC, 0xDDCD, 0xAD2A, 0xBD0B, 0x8D68, 0x9D49,
    0x7E97, 0x6EB6, 0x5ED5, 0x4EF4, 0x3E13, 0x2E32, 0x1E51, 0x0E70,
    0xFF9F, 0xEFBE, 0xDFDD, 0xCFFC, 0xBF1B, 0xAF3A, 0x9F59, 0x8F78,
    0x9188, 0x81A9, 0xB1CA, 0xA1EB, 0xD10C, 0xC12D, 0xF14E, 0xE16F,
    0x1080, 0x00A1, 0x30C2, 0x20E3, 0x5004, 0x4025, 0x7046, 0x6067,
    0x83B9, 0x9398, 0xA3FB, 0xB3DA, 0xC33D, 0xD31C, 0xE37F, 0xF35E,
    0x02B1, 0x1290, 0x22F3, 0x32D2, 0x4235, 0x5214, 0x6277, 0x7256,
    0xB5EA, 0xA5CB, 0x95A8, 0x8589, 0xF56E, 0xE54F, 0xD52C, 0xC50D,
    0x34E2, 0x24C3, 0x14A0, 0x0481, 0x7466, 0x6447, 0x5424, 0x4405,
    0xA7DB, 0xB7FA, 0x8799, 0x97B8, 0xE75F, 0xF77E, 0xC71D, 0xD73C,
    0x26D3, 0x36F2, 0x0691, 0x16B0, 0x6657, 0x7676, 0x4615, 0x5634,
    0xD94C, 0xC96D, 0xF90E, 0xE92F, 0x99C8, 0x89E9, 0xB98A, 0xA9AB,
    0x5844, 0x4865, 0x7806, 0x6827, 0x18C0, 0x08E1, 0x3882, 0x28A3,
    0xCB7D, 0xDB5C, 0xEB3F, 0xFB1E, 0x8BF9, 0x9BD8, 0xABBB, 0xBB9A,
    0x4A75, 0x5A54, 0x6A37, 0x7A16, 0x0AF1, 0x1AD0, 0x2AB3, 0x3A92,
    0xFD2E, 0xED0F, 0xDD6C, 0xCD4D, 0xBDAA, 0xAD8B, 0x9DE8, 0x8DC9,
    0x7C26, 0x6C07, 0x5C64, 0x4C45, 0x3CA2, 0x2C83, 0x1CE0, 0x0CC1,
    0xEF1F, 0xFF3E, 0xCF5D, 0xDF7C, 0xAF9B, 0xBFBA, 0x8FD9, 0x9FF8,
    0x6E17, 0x7E36, 0x4E55, 0x5E74, 0x2E93, 0x3EB2, 0x0ED1, 0x1EF0,
};

/* The step, inlined into the loops below (a call per byte costs as much as the lookup). */
#define DTHC_CRC_STEP(crc, byte) \
    ((uint16_t)(((uint16_t)((crc) << 8)) ^ DTHC_CRC_TABLE_READ((((crc) >> 8) ^ (byte)) & 0xFFu)))

uint16_t dthc_crc16_update(uint16_t crc, uint8_t byte)
{
    return DTHC_CRC_STEP(crc, byte);
}

uint16_t dthc_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = DTHC_CRC_INIT;
    size_t i;
    for (i = 0; i < len; i++) {
        crc = DTHC_CRC_STEP(crc, data[i]);
    }
    return crc;
}

/* --- message table ------------------------------------------------------------------------ */

/* Payload sizes by type (generated from the declaration), in flash: not a switch, which gcc
 * turns into a 137-byte lookup table that avr-gcc puts in RAM. */
static const uint8_t dthc_host_sizes[DTHC_HOST_SIZES_LAST - DTHC_HOST_SIZES_FIRST + 1]
    DTHC_FLASH_ATTR = DTHC_HOST_SIZES;
static const uint8_t dthc_board_sizes[DTHC_BOARD_SIZES_LAST - DTHC_BOARD_SIZES_FIRST + 1]
    DTHC_FLASH_ATTR = DTHC_BOARD_SIZES;

int dthc_payload_size(uint8_t type)
{
    uint8_t size = DTHC_NO_TYPE;
    if (type >= DTHC_HOST_SIZES_FIRST && type <= DTHC_HOST_SIZES_LAST) {
        size = DTHC_FLASH_READ_BYTE(&dthc_host_sizes[type - DTHC_HOST_SIZES_FIRST]);
    } else if (type >= DTHC_BOARD_SIZES_FIRST && type <= DTHC_BOARD_SIZES_LAST) {
        size = DTHC_FLASH_READ_BYTE(&dthc_board_sizes[type - DTHC_BOARD_SIZES_FIRST]);
    }
    return size == DTHC_NO_TYPE ? -1 : (int)size;
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

/* --- one-pass frame encoder ---------------------------------------------------------------- */

/* The COBS writer above inlined with its state in pointers: this runs for every reply a
 * board sends. The bytes are the same (the tests compare it with the `cobs` package through
 * the golden vectors). A body byte b: a zero closes the open block (its code byte goes where
 * the block began), anything else is copied; 254 data bytes close a block too (code 0xFF,
 * no zero implied). */
#define DTHC_COBS_PUT(b)                                                                     \
    do {                                                                                     \
        uint8_t b_ = (b);                                                                    \
        if (b_ == 0) {                                                                       \
            *code_p = code;                                                                  \
            code_p = dst++;                                                                  \
            code = 1;                                                                        \
        } else {                                                                             \
            *dst++ = b_;                                                                     \
            if (++code == 0xFF) {                                                            \
                *code_p = 0xFF;                                                              \
                code_p = dst++;                                                              \
                code = 1;                                                                    \
            }                                                                                \
        }                                                                                    \
    } while (0)

/* No body's wire length exceeds this: one code byte per started 254-byte block,
 * the delimiter. With cap at least this, the loop checks no bounds. */
#define DTHC_WIRE_BOUND(total) ((total) + ((total) >= 254u ? 3u : 2u)) /* total <= 256 */

/* The checked path, for a cap below the bound (a caller probing the exact size). */
static size_t encode_frame_checked(uint8_t type, uint8_t seq, const uint8_t *payload,
                                   size_t len, uint8_t *out, size_t cap)
{
    uint16_t crc = DTHC_CRC_INIT;
    size_t total = len + 4; /* type, seq, payload, crc */
    size_t k;
    size_t pos = 1;      /* next free output byte; out[0] is the first code byte */
    size_t code_pos = 0; /* where the code byte of the open block goes */
    uint8_t code = 1;    /* 1 + data bytes in the open block */
    bool fresh = false;  /* the open block was opened by a full 254-byte block, not a zero */
    for (k = 0; k < total; k++) {
        uint8_t b;
        if (k < 2) {
            b = k == 0 ? type : seq;
            crc = DTHC_CRC_STEP(crc, b);
        } else if (k < len + 2) {
            b = payload[k - 2];
            crc = DTHC_CRC_STEP(crc, b);
        } else {
            b = (uint8_t)(k == len + 2 ? crc >> 8 : crc & 0xFFu); /* the CRC is big-endian */
        }
        if (pos >= cap) {
            return 0;
        }
        if (b == 0) {
            out[code_pos] = code;
            code_pos = pos++;
            code = 1;
            fresh = false;
        } else {
            out[pos++] = b;
            fresh = false;
            if (++code == 0xFF) {
                out[code_pos] = 0xFF;
                code_pos = pos++;
                code = 1;
                fresh = true;
            }
        }
    }
    if (fresh) {
        pos--; /* a full block at the very end is not followed by an empty one */
    } else {
        out[code_pos] = code;
    }
    if (pos >= cap) {
        return 0;
    }
    out[pos] = DTHC_DELIMITER;
    return pos + 1;
}

size_t dthc_encode_frame(uint8_t type, uint8_t seq, const uint8_t *payload, size_t len,
                         uint8_t *out, size_t cap)
{
    uint16_t crc = DTHC_CRC_INIT;
    uint8_t *code_p = out; /* where the code byte of the open block goes */
    uint8_t *dst = out + 1;
    uint8_t code = 1; /* 1 + data bytes in the open block */
    const uint8_t *src = payload;
    const uint8_t *end;
    uint8_t lo;
    if (out == NULL || len > DTHC_MAX_PAYLOAD || (payload == NULL && len != 0) || cap == 0) {
        return 0;
    }
    if (cap < DTHC_WIRE_BOUND(len + 4)) {
        return encode_frame_checked(type, seq, payload, len, out, cap);
    }
    end = src + len;
    crc = DTHC_CRC_STEP(crc, type);
    DTHC_COBS_PUT(type);
    crc = DTHC_CRC_STEP(crc, seq);
    DTHC_COBS_PUT(seq);
    /* In place (payload in `out` at DTHC_TX_PAYLOAD_OFFSET or later): each byte is read
     * before any write reaches it, the writes stay below src + 1. */
    while (src != end) {
        uint8_t b = *src++;
        crc = DTHC_CRC_STEP(crc, b);
        DTHC_COBS_PUT(b);
    }
    DTHC_COBS_PUT((uint8_t)(crc >> 8)); /* the CRC is big-endian */
    lo = (uint8_t)(crc & 0xFFu);
    DTHC_COBS_PUT(lo);
    if (code == 1 && lo != 0) {
        dst--; /* a full block ended the frame: no empty one after it */
    } else {
        *code_p = code;
    }
    *dst++ = DTHC_DELIMITER;
    return (size_t)(dst - out);
}

/* --- streaming frame encoder ----------------------------------------------------------------- */

size_t dthc_frame_seal(uint8_t type, uint8_t seq, uint8_t *buf, size_t len)
{
    uint8_t *p = buf + 1;
    uint8_t *end;
    uint8_t hi = (uint8_t)(DTHC_CRC_INIT >> 8);
    uint8_t lo = (uint8_t)(DTHC_CRC_INIT & 0xFFu);
    size_t total = len + 4;
    size_t wire = total + 2; /* a code byte, the delimiter: exact up to 254 body bytes */
    if (len > DTHC_MAX_PAYLOAD) {
        return 0;
    }
    buf[1] = type;
    buf[2] = seq;
    end = p + 2 + len;
    /* The register as two bytes: on AVR the 16-bit form costs twice the cycles. */
    while (p != end) {
        uint16_t t = DTHC_CRC_TABLE_READ((uint8_t)(hi ^ *p++));
        hi = (uint8_t)(lo ^ (uint8_t)(t >> 8));
        lo = (uint8_t)t;
    }
    p[0] = hi;
    p[1] = lo;
    if (total > 254) { /* a run of 254 non-zero bytes before the end costs a code byte */
        size_t run = 0;
        size_t k;
        for (k = 0; k < total; k++) {
            if (!buf[1 + k]) {
                run = 0;
            } else if (++run == 254 && k + 1 < total) {
                wire++;
                run = 0;
            }
        }
    }
    return wire;
}

size_t dthc_encode_in_place(uint8_t type, uint8_t seq, uint8_t *buf, size_t len)
{
    uint8_t *p = buf + 1;
    uint8_t *end;
    uint8_t *code_p = buf; /* the open block's code byte: buf[0], then each zero in turn */
    uint8_t hi = (uint8_t)(DTHC_CRC_INIT >> 8);
    uint8_t lo = (uint8_t)(DTHC_CRC_INIT & 0xFFu);
    if (len + 4 > 254) { /* a full block may shift the bytes: the one-pass encoder */
        if (len > DTHC_MAX_PAYLOAD) {
            return 0;
        }
        return dthc_encode_frame(type, seq, buf + DTHC_TX_PAYLOAD_OFFSET, len, buf,
                                 len + DTHC_TX_PAYLOAD_OFFSET + 4);
    }
    /* Up to 254 body bytes COBS keeps every byte where it is, one to the right of its
     * body index: the body at buf + 1 is its own encoding once buf[0] and each zero hold
     * the distance to the next zero (or to the delimiter). One pass: CRC and codes. */
    buf[1] = type;
    buf[2] = seq;
    end = p + 2 + len;
    while (p != end) {
        uint8_t b = *p;
        uint16_t t = DTHC_CRC_TABLE_READ((uint8_t)(hi ^ b));
        hi = (uint8_t)(lo ^ (uint8_t)(t >> 8));
        lo = (uint8_t)t;
        if (!b) {
            *code_p = (uint8_t)(p - code_p);
            code_p = p;
        }
        p++;
    }
    p[0] = hi;
    if (!hi) {
        *code_p = (uint8_t)(p - code_p);
        code_p = p;
    }
    p[1] = lo;
    if (!lo) {
        *code_p = (uint8_t)(p + 1 - code_p);
        code_p = p + 1;
    }
    *code_p = (uint8_t)(p + 2 - code_p);
    p[2] = DTHC_DELIMITER;
    return len + 6;
}

void dthc_frame_stream(const uint8_t *buf, size_t len, dthc_sink_fn sink)
{
    uint8_t delimiter = DTHC_DELIMITER; /* not static: that would sit in RAM on AVR */
    const uint8_t *p = buf + 1;
    size_t left = len + 4;
    for (;;) {
        uint8_t run = 0;
        uint8_t code;
        size_t lim = left < 254 ? left : 254;
        while (run < lim && p[run]) {
            run++;
        }
        code = (uint8_t)(run + 1);
        sink(&code, 1);
        if (run) {
            sink(p, run);
        }
        if (run == left) {
            break; /* the body ended (a full block at the very end: no empty one after) */
        }
        if (run == 254) {
            p += 254; /* a full block: no zero implied */
            left -= 254;
        } else {
            p += run + 1; /* the zero this block's code stands for */
            left -= (size_t)run + 1u;
        }
    }
    sink(&delimiter, 1);
}

/* --- messages ------------------------------------------------------------------------------
 * The payload of each message is packed and unpacked by the code generated from
 * firmware_protocol/declaration.py (dthc_messages.h: dthc_pack_payload, dthc_unpack_payload). */

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

/* The payload length of an encodable `msg`. */
static size_t payload_len(const dthc_msg_t *msg)
{
    if (msg->type == DTHC_MSG_SAMPLES) {
        return DTHC_SAMPLES_HEADER_SIZE + 2u * (size_t)msg->u.samples.n_samples;
    }
    return (size_t)dthc_payload_size(msg->type);
}

size_t dthc_encode_body(const dthc_msg_t *msg, uint8_t *out, size_t cap)
{
    size_t n;
    if (msg == NULL || out == NULL || !msg_encodable(msg)) {
        return 0;
    }
    n = payload_len(msg);
    if (cap < n + 2) {
        return 0;
    }
    out[0] = msg->type;
    out[1] = msg->seq;
    dthc_pack_payload(out + 2, msg);
    return n + 2;
}

size_t dthc_encode(const dthc_msg_t *msg, uint8_t *out, size_t cap)
{
    size_t n;
    if (msg == NULL || out == NULL || !msg_encodable(msg) || cap <= DTHC_TX_PAYLOAD_OFFSET) {
        return 0;
    }
    /* Pack the payload where dthc_encode_frame may read it in place: no body buffer. A
     * payload that does not fit there cannot fit as a wire frame either (6 bytes more). */
    n = payload_len(msg);
    if (n > cap - DTHC_TX_PAYLOAD_OFFSET) {
        return 0;
    }
    dthc_pack_payload(out + DTHC_TX_PAYLOAD_OFFSET, msg);
    return dthc_encode_frame(msg->type, msg->seq, out + DTHC_TX_PAYLOAD_OFFSET, n, out, cap);
}

/* --- field parsing -------------------------------------------------------------------------- */

/* Type and exact payload length (PROTOCOL.md section 2, the last two checks). */
static int check_payload(uint8_t type, size_t payload)
{
    int size = dthc_payload_size(type);
    if (size < 0) {
        return DTHC_ERR_UNKNOWN_TYPE;
    }
    if (type == DTHC_MSG_SAMPLES) {
        if (payload < DTHC_SAMPLES_HEADER_SIZE || ((payload - DTHC_SAMPLES_HEADER_SIZE) & 1u)
            || (payload - DTHC_SAMPLES_HEADER_SIZE) / 2 > DTHC_MAX_SAMPLES) {
            return DTHC_ERR_BAD_LENGTH;
        }
    } else if (payload != (size_t)size) {
        return DTHC_ERR_BAD_LENGTH;
    }
    return DTHC_OK;
}

/* Checked first, then unpacked straight into *out (no message-sized local: on AVR the
 * stack is as scarce as the static RAM). */
int dthc_frame_to_msg(const dthc_frame_t *frame, dthc_msg_t *out)
{
    const uint8_t *p;
    size_t payload;
    dthc_msg_t *m = out;
    int rc;

    if (frame == NULL || out == NULL || (frame->payload == NULL && frame->len != 0)) {
        return DTHC_ERR_BAD_LENGTH;
    }
    p = frame->payload;
    payload = frame->len;
    rc = check_payload(frame->type, payload);
    if (rc != DTHC_OK) {
        return rc;
    }

    memset(m, 0, sizeof *m);
    m->type = frame->type;
    m->seq = frame->seq;
    dthc_unpack_payload(m->type, p, payload, m);
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
    {
        dthc_frame_t f;
        f.type = raw[0];
        f.seq = raw[1];
        f.payload = raw + 2;
        f.len = (uint8_t)(len - 4);
        return dthc_frame_to_msg(&f, out);
    }
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
    rx->crc = DTHC_CRC_STEP(rx->crc, b);
}

/* A frame ended at a delimiter: check it in the order of PROTOCOL.md section 2 (valid
 * COBS, 4 <= decoded length <= DTHC_MAX_FRAME, CRC, known type, payload length). The frame
 * stays in buf; dthc_rx_reset only rewinds the counts, so the view stays valid until the
 * next byte is fed. */
static int rx_end_frame(dthc_rx_t *rx, dthc_frame_t *frame)
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
        size_t len = (size_t)rx->dec_len - 4u;
        rc = check_payload(rx->buf[0], len);
        frame->type = rx->buf[0];
        frame->seq = rx->buf[1];
        frame->payload = rx->buf + 2;
        frame->len = (uint8_t)len; /* dec_len <= 256: len <= 252 */
        if (rc == DTHC_OK) {
            rx->frames_ok++;
            dthc_rx_reset(rx);
            return 1;
        }
        rx->reject_type = frame->type;
        rx->reject_seq = frame->seq;
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

int dthc_rx_feed(dthc_rx_t *rx, uint8_t byte, dthc_frame_t *frame)
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
        return rx_end_frame(rx, frame);
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

int dthc_rx_feed_byte(dthc_rx_t *rx, uint8_t byte, dthc_msg_t *out)
{
    dthc_frame_t frame;
    int rc = dthc_rx_feed(rx, byte, &frame);
    if (rc == 1) {
        /* Cannot fail: dthc_rx_feed checked type and length already. */
        rc = dthc_frame_to_msg(&frame, out);
        return rc == DTHC_OK ? 1 : rc;
    }
    return rc;
}
