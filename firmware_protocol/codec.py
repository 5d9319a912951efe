"""Sans-io encoder and decoder: messages <-> frames <-> bytes on the wire.

A frame on the wire is ``COBS(type | seq | payload | crc16_be) | 0x00``. The CRC is
CRC-16/CCITT-FALSE over type, seq and payload, sent big-endian so that the CRC of the whole
decoded frame is zero: the receive path checks a frame with one C call and no slicing.
"""

from __future__ import annotations

import struct
from binascii import crc_hqx
from collections.abc import Callable
from typing import Any, Final

from cobs.cobs import DecodeError as _CobsDecodeError
from cobs.cobs import decode as _cobs_decode
from cobs.cobs import encode as _cobs_encode

from .constants import CRC_INIT, MAX_ENCODED_FRAME, MAX_FRAME, MsgType
from .errors import (
    BadLength,
    CobsError,
    CrcMismatch,
    EncodeError,
    FrameTooLong,
    UnknownMessageType,
)
from .messages import LAYOUTS, HelloInfo, Message, Samples

__all__ = [
    "LAYOUTS",
    "MAX_SAMPLES_PER_FRAME",
    "crc16",
    "decode_frame",
    "decode_message",
    "encode",
    "encode_frame",
    "encode_message",
    "message_type",
]


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0)."""
    return crc_hqx(data, CRC_INIT)


_PACKERS: dict[type[Any], tuple[int, struct.Struct]] = {
    cls: (int(t), struct.Struct("<BB" + fmt)) for cls, (t, fmt) in LAYOUTS.items()
}
_SAMPLES_HEAD = struct.Struct("<xB" + LAYOUTS[Samples][1])
_SAMPLES_OFFSET: Final = _SAMPLES_HEAD.size
# Samples that fit one frame after the fixed SAMPLES fields (header included in the offset).
MAX_SAMPLES_PER_FRAME: Final = (MAX_FRAME - 2 - _SAMPLES_OFFSET) // 2
_SAMPLE_STRUCTS = [struct.Struct(f"<{n}H") for n in range(MAX_SAMPLES_PER_FRAME + 1)]


def message_type(msg: Message) -> MsgType:
    return LAYOUTS[type(msg)][0]


# --- encoding ------------------------------------------------------------------------------


def encode_message(msg: Message) -> bytes:
    """The decoded frame body (type, seq, payload) without CRC."""
    cls = type(msg)
    try:
        msg_type, packer = _PACKERS[cls]
    except KeyError:
        raise EncodeError(cls.__name__, "not a protocol message") from None
    try:
        if cls is Samples:
            assert isinstance(msg, Samples)
            if len(msg.samples_cv) > MAX_SAMPLES_PER_FRAME:
                raise EncodeError(
                    cls.__name__,
                    f"{len(msg.samples_cv)} samples: frame exceeds {MAX_FRAME} bytes "
                    f"(at most {MAX_SAMPLES_PER_FRAME} samples)",
                )
            body = packer.pack(msg_type, *msg[:-1]) + _SAMPLE_STRUCTS[len(msg.samples_cv)].pack(
                *msg.samples_cv
            )
        elif cls is HelloInfo:
            assert isinstance(msg, HelloInfo)
            serial = msg.serial.encode("ascii")
            if len(serial) > 16:
                raise EncodeError(cls.__name__, "serial longer than 16 characters")
            body = packer.pack(msg_type, *msg._replace(serial=serial))  # type: ignore[arg-type]
        else:
            body = packer.pack(msg_type, *msg)
    except (struct.error, IndexError, UnicodeEncodeError) as exc:
        raise EncodeError(cls.__name__, f"{exc} in {msg!r}") from None
    if len(body) > MAX_FRAME - 2:
        raise EncodeError(cls.__name__, f"frame of {len(body) + 2} bytes exceeds {MAX_FRAME}")
    return body


def encode_frame(body: bytes) -> bytes:
    """Append the CRC to a frame body, COBS-encode it and add the delimiter."""
    crc = crc_hqx(body, CRC_INIT)
    encoded: bytes = _cobs_encode(body + bytes((crc >> 8, crc & 0xFF)))
    return encoded + b"\x00"


def encode(msg: Message) -> bytes:
    """Bytes to write to the link for one message."""
    return encode_frame(encode_message(msg))


# --- decoding ------------------------------------------------------------------------------


def _fixed_decoder(cls: type[Any], fmt: str) -> Callable[[bytes], Message]:
    st = struct.Struct("<xB" + fmt)
    size = st.size + 2  # + crc
    unpack_from = st.unpack_from
    new = tuple.__new__
    msg_type = LAYOUTS[cls][0]

    def decode(raw: bytes) -> Message:
        if len(raw) != size:
            raise BadLength(msg_type, str(size - 4), len(raw) - 4, raw)
        return new(cls, unpack_from(raw))  # type: ignore[no-any-return]

    return decode


def _decode_samples(raw: bytes) -> Message:
    n2 = len(raw) - _SAMPLES_OFFSET - 2
    if n2 < 0 or n2 & 1:
        raise BadLength(MsgType.SAMPLES, f"{_SAMPLES_OFFSET - 2}+2N", len(raw) - 4, raw)
    return tuple.__new__(
        Samples,
        (
            *_SAMPLES_HEAD.unpack_from(raw),
            _SAMPLE_STRUCTS[n2 >> 1].unpack_from(raw, _SAMPLES_OFFSET),
        ),
    )


_hello_info_fixed = _fixed_decoder(HelloInfo, LAYOUTS[HelloInfo][1])


def _decode_hello_info(raw: bytes) -> Message:
    msg = _hello_info_fixed(raw)
    assert isinstance(msg, HelloInfo)
    serial_raw: bytes = msg.serial  # type: ignore[assignment]
    serial = serial_raw.split(b"\x00", 1)[0].decode("ascii", "replace")
    return msg._replace(serial=serial)


_DECODERS: dict[int, Callable[[bytes], Message]] = {}
for _cls, (_type, _fmt) in LAYOUTS.items():
    _DECODERS[int(_type)] = _fixed_decoder(_cls, _fmt)
_DECODERS[MsgType.SAMPLES] = _decode_samples
_DECODERS[MsgType.HELLO_INFO] = _decode_hello_info


def decode_message(raw: bytes) -> Message:
    """Turn a CRC-checked decoded frame (type, seq, payload, crc) into a message."""
    if not 4 <= len(raw) <= MAX_FRAME:
        raise BadLength(raw[0] if raw else 0, f"0..{MAX_FRAME - 4}", len(raw) - 4, raw)
    decoder = _DECODERS.get(raw[0])
    if decoder is None:
        raise UnknownMessageType(raw[0], raw)
    return decoder(raw)


def decode_frame(encoded: bytes) -> Message:
    """Decode one COBS frame (with or without its trailing delimiter); raises DecodeError."""
    if encoded.endswith(b"\x00"):
        encoded = encoded[:-1]
    if len(encoded) > MAX_ENCODED_FRAME:
        raise FrameTooLong("frame longer than the maximum", encoded)
    try:
        raw = _cobs_decode(encoded)
    except _CobsDecodeError as exc:
        raise CobsError(f"invalid COBS: {exc}", encoded) from None
    if not 4 <= len(raw) <= MAX_FRAME:
        raise BadLength(raw[0] if raw else 0, f"0..{MAX_FRAME - 4}", len(raw) - 4, raw)
    if crc_hqx(raw, CRC_INIT):
        computed = crc_hqx(raw[:-2], CRC_INIT)
        raise CrcMismatch(computed, int.from_bytes(raw[-2:], "big"), raw)
    return decode_message(raw)
