"""The Python codec against the golden vectors in firmware_protocol/vectors/frames.json."""

from __future__ import annotations

from typing import Any

import pytest

import firmware_protocol as fp
from firmware_protocol import vectors

GOLDEN = vectors.load()
FRAMES: list[dict[str, Any]] = GOLDEN["frames"]
CORRUPT: list[dict[str, Any]] = GOLDEN["corrupt"]


def test_vector_file_is_what_the_codec_produces() -> None:
    """The stored vectors equal a fresh rendering: any layout change shows up as a diff here."""
    assert vectors.render() == GOLDEN


def test_every_message_type_has_a_vector() -> None:
    """At least one golden frame per message type, host and board."""
    assert {f["message"] for f in FRAMES} == {cls.__name__ for cls in fp.LAYOUTS}


def test_crc_vector() -> None:
    """The CRC check value in the vector file is CRC-16/CCITT-FALSE of its input."""
    crc = GOLDEN["crc"]
    assert fp.crc16(bytes.fromhex(crc["input_hex"])) == int(crc["check"], 16)


@pytest.mark.parametrize("vector", FRAMES, ids=[f["name"] for f in FRAMES])
def test_golden_frame_decodes_to_its_fields(vector: dict[str, Any]) -> None:
    """Each stored wire frame decodes to the stored class and fields, and re-encodes exactly."""
    msg = fp.decode_frame(bytes.fromhex(vector["frame_hex"]))
    assert type(msg).__name__ == vector["message"]
    fields = msg._asdict()
    if isinstance(msg, fp.Samples):
        fields["samples_cv"] = list(msg.samples_cv)
    assert fields == vector["fields"]
    assert fp.encode(msg).hex() == vector["frame_hex"]
    assert fp.encode_message(msg).hex() == vector["body_hex"]


@pytest.mark.parametrize("vector", CORRUPT, ids=[c["name"] for c in CORRUPT])
def test_corrupt_stream_gives_the_expected_messages_and_counters(vector: dict[str, Any]) -> None:
    """Damaged streams yield exactly the expected surviving messages and error counts."""
    by_wire = {f["frame_hex"]: f["name"] for f in FRAMES}
    decoder = fp.StreamDecoder()
    out = decoder.feed(bytes.fromhex(vector["stream_hex"]))
    expect = dict(vector["expect"])
    assert [by_wire[fp.encode(m).hex()] for m in out] == expect.pop("messages")
    stats = decoder.stats.as_dict()
    for key in ("crc_errors", "framing_errors", "unknown_type", "length_errors"):
        assert stats[key] == expect.get(key, 0), key
