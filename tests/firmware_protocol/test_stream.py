"""The streaming decoder: any split, any corruption, never raises, always resyncs."""

from __future__ import annotations

import itertools
import random

from hypothesis import given, settings
from hypothesis import strategies as st

import firmware_protocol as fp

from .strategies import any_message


def _feed_all(decoder: fp.StreamDecoder, chunks: list[bytes]) -> list[fp.Message]:
    out: list[fp.Message] = []
    for chunk in chunks:
        out.extend(decoder.feed(chunk))
    return out


def _split(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    bounds = [0, *points, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(bounds)]


@given(st.lists(any_message, min_size=1, max_size=20), st.lists(st.integers(0, 10_000)))
def test_any_split_of_a_valid_stream_decodes_to_the_same_messages(
    msgs: list[fp.Message], cuts: list[int]
) -> None:
    """However the bytes are chunked (one at a time included), the same messages come out."""
    stream = b"".join(fp.encode(m) for m in msgs)
    decoder = fp.StreamDecoder()
    assert _feed_all(decoder, _split(stream, cuts)) == msgs
    assert decoder.stats.frames_ok == len(msgs)
    assert decoder.stats.dropped_bytes == 0
    assert decoder.pending_bytes == 0


def test_byte_at_a_time_equals_whole_stream() -> None:
    """Feeding one byte per call gives exactly what one big feed gives."""
    rng = random.Random(5)
    msgs = [fp.Ack(rng.randrange(256), rng.randrange(2**32)) for _ in range(50)]
    stream = b"".join(fp.encode(m) for m in msgs)
    assert _feed_all(fp.StreamDecoder(), [stream[i : i + 1] for i in range(len(stream))]) == msgs


@settings(max_examples=300)
@given(
    st.lists(any_message, min_size=1, max_size=8),
    st.binary(max_size=600),
    st.lists(st.integers(0, 10_000), max_size=5),
    any_message,
)
def test_garbage_never_raises_and_resyncs_by_the_next_delimiter(
    before: list[fp.Message], garbage: bytes, cuts: list[int], after: fp.Message
) -> None:
    """Arbitrary garbage mid-stream raises nothing; the frame after the next delimiter decodes."""
    stream = b"".join(fp.encode(m) for m in before) + garbage + b"\x00" + fp.encode(after)
    decoder = fp.StreamDecoder()
    out = _feed_all(decoder, _split(stream, cuts))
    assert out[-1] == after
    assert decoder.pending_bytes <= fp.MAX_ENCODED_FRAME


@settings(max_examples=300)
@given(st.lists(any_message, min_size=3, max_size=12), st.data())
def test_bit_flips_lose_at_most_the_frames_they_touch(
    msgs: list[fp.Message], data: st.DataObject
) -> None:
    """Flipping bits inside one frame loses at most that frame and its neighbour, never more."""
    frames = [fp.encode(m) for m in msgs]
    victim = data.draw(st.integers(0, len(frames) - 1))
    frame = bytearray(frames[victim])
    for _ in range(data.draw(st.integers(1, 4))):
        pos = data.draw(st.integers(0, len(frame) - 1))
        frame[pos] ^= 1 << data.draw(st.integers(0, 7))
    frames[victim] = bytes(frame)
    decoder = fp.StreamDecoder()
    out = decoder.feed(b"".join(frames))
    survivors = [m for i, m in enumerate(msgs) if i not in (victim, victim + 1)]
    for m in survivors:
        assert m in out
    assert len(out) >= len(msgs) - 2
    # Nothing invented: every decoded message is one that was sent (CRC-16 catches the rest).
    for m in out:
        assert m in msgs


def test_buffer_is_capped_and_overlong_runs_are_counted() -> None:
    """10 kB without a delimiter never grows the buffer past one maximum frame."""
    decoder = fp.StreamDecoder()
    for _ in range(100):
        assert decoder.feed(b"\x55" * 100) == []
        assert decoder.pending_bytes <= fp.MAX_ENCODED_FRAME
    ack = fp.Ack(1, 2)
    assert decoder.feed(b"\x00" + fp.encode(ack)) == [ack]
    assert decoder.stats.dropped_bytes == 10_001  # the run and the delimiter that ends it
    assert decoder.stats.framing_errors >= 1


def test_errors_are_reported_with_data_through_the_callback() -> None:
    """on_error receives the typed exception for each bad frame; last_error keeps the latest."""
    seen: list[fp.DecodeError] = []
    decoder = fp.StreamDecoder(on_error=seen.append)
    body = fp.encode_message(fp.Torch(4, True))
    crc = fp.crc16(body) ^ 0xFFFF
    from cobs import cobs

    decoder.feed(cobs.encode(body + crc.to_bytes(2, "big")) + b"\x00")
    assert len(seen) == 1
    assert isinstance(seen[0], fp.CrcMismatch)
    assert seen[0].received == crc
    assert decoder.last_error is seen[0]
    assert decoder.stats.crc_errors == 1


def test_frame_one_byte_over_the_maximum_is_dropped_not_raised() -> None:
    """A 257-byte decoded frame (fits 258 COBS bytes when it holds zeros) is a framing error."""
    from cobs import cobs

    body = bytes([fp.MsgType.SAMPLES, 0]) + bytes(21 - 2) + b"\x00\x01" * 117
    raw = body + fp.crc16(body).to_bytes(2, "big")
    assert len(raw) == fp.MAX_FRAME + 1
    enc = cobs.encode(raw)
    assert len(enc) <= fp.MAX_ENCODED_FRAME
    decoder = fp.StreamDecoder()
    ack = fp.Ack(1, 2)
    assert decoder.feed(enc + b"\x00" + fp.encode(ack)) == [ack]
    assert decoder.stats.framing_errors == 1
    import pytest

    with pytest.raises(fp.BadLength):
        fp.decode_frame(enc)


def test_dropped_bytes_do_not_depend_on_how_reads_split_the_stream() -> None:
    """An over-long run and its delimiter count the same fed whole or one byte at a time."""
    stream = b"\x01" * 300 + b"\x00" + fp.encode(fp.Ack(1, 2))
    whole = fp.StreamDecoder()
    whole.feed(stream)
    bytewise = fp.StreamDecoder()
    for i in range(len(stream)):
        bytewise.feed(stream[i : i + 1])
    assert whole.stats.dropped_bytes == bytewise.stats.dropped_bytes == 301
    assert whole.stats.frames_ok == bytewise.stats.frames_ok == 1
