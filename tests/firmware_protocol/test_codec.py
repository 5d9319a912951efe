"""Encoding and decoding of single frames, and the errors bad frames raise."""

from __future__ import annotations

import pytest
from hypothesis import given

import firmware_protocol as fp
from firmware_protocol.codec import _SAMPLES_OFFSET

from .strategies import MAX_SAMPLES, any_message


def test_crc_is_ccitt_false_with_check_value_0x29b1() -> None:
    """The CRC variant is the one PROTOCOL.md names, proven by its catalogue check value."""
    assert fp.crc16(b"123456789") == fp.CRC_CHECK_VALUE == 0x29B1


@given(any_message)
def test_every_message_round_trips(msg: fp.Message) -> None:
    """encode then decode gives back an equal message of the same class, for any field values."""
    wire = fp.encode(msg)
    assert wire.endswith(b"\x00")
    assert b"\x00" not in wire[:-1]
    decoded = fp.decode_frame(wire)
    assert type(decoded) is type(msg)
    assert decoded == msg


@given(any_message)
def test_decoded_frame_including_crc_has_zero_residue(msg: fp.Message) -> None:
    """The big-endian CRC makes the CRC over the whole decoded frame zero, as the spec says."""
    body = fp.encode_message(msg)
    crc = fp.crc16(body)
    assert fp.crc16(body + crc.to_bytes(2, "big")) == 0
    assert len(body) + 2 <= fp.MAX_FRAME


def test_crc_mismatch_carries_expected_and_received_values() -> None:
    """A damaged payload raises CrcMismatch naming both CRCs and holding the raw frame."""
    body = fp.encode_message(fp.Torch(4, True))
    good = fp.crc16(body)
    bad = fp.encode_frame(body)
    raw = body + (good ^ 0x0101).to_bytes(2, "big")
    from cobs import cobs

    bad = cobs.encode(raw) + b"\x00"
    with pytest.raises(fp.CrcMismatch) as info:
        fp.decode_frame(bad)
    assert info.value.expected == good
    assert info.value.received == good ^ 0x0101
    assert info.value.raw == raw


def test_unknown_type_and_bad_length_are_typed_errors() -> None:
    """A valid frame of an unknown type, or with the wrong payload size, raises with the type."""
    with pytest.raises(fp.UnknownMessageType) as unknown:
        fp.decode_frame(fp.encode_frame(b"\x7f\x01"))
    assert unknown.value.msg_type == 0x7F
    with pytest.raises(fp.BadLength) as length:
        fp.decode_frame(fp.encode_frame(b"\x04\x01\x01\x01"))
    assert length.value.msg_type == fp.MsgType.TORCH
    assert length.value.received == 2


def test_invalid_cobs_and_short_frames_are_framing_errors() -> None:
    """Bytes that are not COBS, or decode to fewer than 4 bytes, raise CobsError / BadLength."""
    with pytest.raises(fp.CobsError):
        fp.decode_frame(b"\x09\x01\x02")
    with pytest.raises(fp.BadLength):
        fp.decode_frame(fp.encode_frame(b""))
    with pytest.raises(fp.FrameTooLong):
        fp.decode_frame(b"\x01" * (fp.MAX_ENCODED_FRAME + 1))


def test_samples_batch_size_is_bounded_by_the_frame_size() -> None:
    """The largest batch that fits one frame encodes; one more sample is refused, not truncated."""
    largest = fp.Samples(0, 1, 2, 1000, 0, 0, 0, 0, 0, tuple(range(1, MAX_SAMPLES + 1)))
    assert len(fp.encode_message(largest)) + 2 == _SAMPLES_OFFSET + 2 * MAX_SAMPLES + 2
    assert MAX_SAMPLES >= fp.MAX_BATCH_SIZE
    with pytest.raises(fp.EncodeError, match="exceeds"):
        fp.encode(largest._replace(samples_cv=(*largest.samples_cv, 1)))


@pytest.mark.parametrize(
    ("msg", "detail"),
    [
        (fp.SetLease(1, 70000), "SetLease"),
        (fp.ZMove(1, 2**31, 1), "ZMove"),
        (fp.Ack(256, 0), "Ack"),
        (fp.Samples(0, 1, 2, 3, 4, 5, 6, 7, 8, (70000,)), "Samples"),
    ],
)
def test_out_of_range_fields_raise_encode_error(msg: fp.Message, detail: str) -> None:
    """A field that does not fit its wire type raises EncodeError naming the message."""
    with pytest.raises(fp.EncodeError) as info:
        fp.encode(msg)
    assert info.value.message_name == detail


def test_hello_info_serial_is_ascii_and_at_most_16_characters() -> None:
    """A serial of 16 characters round-trips; a longer one is refused."""
    info = fp.HelloInfo(1, 1, 0, 0, 1, 0, 0, 7, "A" * 16, 1000, 5, 0, 0, 100_000, 256, 250)
    assert fp.decode_frame(fp.encode(info)) == info
    with pytest.raises(fp.EncodeError, match="16"):
        fp.encode(info._replace(serial="A" * 17))


def test_layout_sizes_match_the_spec_tables() -> None:
    """Payload sizes equal those in PROTOCOL.md §6 (pinned here so a layout edit is seen)."""
    import struct

    sizes = {t: struct.calcsize("<" + fmt) for t, fmt in fp.LAYOUTS.values()}
    assert sizes == {
        fp.MsgType.HELLO: 6, fp.MsgType.HEARTBEAT: 0, fp.MsgType.SET_LEASE: 2,
        fp.MsgType.TORCH: 1, fp.MsgType.OHMIC_SENSE: 1, fp.MsgType.Z_MOVE: 8,
        fp.MsgType.Z_PROBE: 10, fp.MsgType.Z_VELOCITY: 8, fp.MsgType.Z_STOP: 0,
        fp.MsgType.SET_CURRENT: 2, fp.MsgType.CONFIGURE: 16, fp.MsgType.QUERY: 1,
        fp.MsgType.CLOCK_QUERY: 0, fp.MsgType.FAULT_RESET: 2, fp.MsgType.Z_PROBE_AWAY: 10,
        fp.MsgType.Z_HOME: 18, fp.MsgType.ACK: 4,
        fp.MsgType.NAK: 6, fp.MsgType.HELLO_INFO: 45, fp.MsgType.SAMPLES: 19,
        fp.MsgType.EVENT: 16, fp.MsgType.FAULT: 16, fp.MsgType.MOTION_DONE: 9,
        fp.MsgType.PROBE_RESULT: 15, fp.MsgType.STATUS: 35, fp.MsgType.CLOCK: 8,
        fp.MsgType.HOME_RESULT: 13,
    }  # fmt: skip
