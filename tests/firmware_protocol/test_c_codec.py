"""The C reference codec (firmware_protocol/c/) against the golden vectors and the Python codec.

The C sources are compiled once per module with the system compiler and strict flags into a
temporary directory; ``vector_check`` (see its header comment) drives the C codec from text
lines, so one process run checks a whole batch of frames.
"""

from __future__ import annotations

import math
import random
import re
import shutil
import struct
import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from pathlib import Path
from typing import Any

import pytest
from cobs import cobs

import firmware_protocol as fp
from firmware_protocol import constants, vectors

C_DIR = Path(fp.__file__).resolve().parent / "c"
SOURCES = (C_DIR / "dthc_protocol.c", C_DIR / "vector_check.c")
CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2")
SANITIZE = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-g")

GOLDEN = vectors.load()
FRAMES: list[dict[str, Any]] = GOLDEN["frames"]
CORRUPT: list[dict[str, Any]] = GOLDEN["corrupt"]
FRAME_BY_NAME = {f["name"]: f for f in FRAMES}
COUNTERS = (
    "frames_ok",
    "crc_errors",
    "framing_errors",
    "unknown_type",
    "length_errors",
    "dropped_bytes",
)
# The largest SAMPLES batch that fits one frame: payload 19 + 2N <= 252.
MAX_SAMPLES = (constants.MAX_PAYLOAD - 19) // 2

# C enum prefix of each code table (IntEnum/IntFlag class) of constants.py.
ENUM_PREFIX = {
    "MsgType": "DTHC_MSG_",
    "InputBit": "DTHC_INPUT_",
    "StatusBit": "DTHC_STATUS_",
    "Capability": "DTHC_CAP_",
    "FaultCode": "DTHC_FAULT_",
    "NakCode": "DTHC_NAK_",
    "ResetReason": "DTHC_RESET_",
    "ProbeOutcome": "DTHC_PROBE_",
    "MotionResult": "DTHC_MOTION_",
    "FilterKind": "DTHC_FILTER_",
    "QueryWhat": "DTHC_QUERY_",
}

Fields = dict[str, Any]
Decoded = tuple[str, Fields]  # (message class name, fields in printed order)


# --- building and running the C tool -------------------------------------------------------


def _compiler() -> str | None:
    return shutil.which("cc") or shutil.which("gcc")


def _compile(exe: Path, extra: Sequence[str] = ()) -> subprocess.CompletedProcess[str]:
    cc = _compiler()
    assert cc is not None
    cmd = [cc, *CFLAGS, *extra, *(str(s) for s in SOURCES), "-o", str(exe)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


@dataclass(frozen=True)
class CTool:
    """The compiled ``vector_check``: feeds it lines, returns its output lines."""

    exe: Path
    env: dict[str, str] | None = None

    def run(self, lines: Iterable[str]) -> list[str]:
        proc = subprocess.run(
            [str(self.exe)],
            input="".join(f"{line}\n" for line in lines),
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
            env=self.env,
        )
        assert proc.returncode == 0, f"vector_check exited {proc.returncode}: {proc.stderr}"
        assert proc.stderr == "", proc.stderr
        return proc.stdout.splitlines()


@pytest.fixture(scope="module")
def c_tool(tmp_path_factory: pytest.TempPathFactory) -> CTool:
    """``vector_check`` built from the C sources with the strict flags (module-scoped)."""
    if _compiler() is None:
        pytest.skip("no C compiler: neither cc nor gcc is on PATH")
    exe = tmp_path_factory.mktemp("c_codec") / "vector_check"
    proc = _compile(exe)
    assert proc.returncode == 0, f"C codec does not compile with {' '.join(CFLAGS)}:\n{proc.stderr}"
    return CTool(exe)


# --- parsing its output --------------------------------------------------------------------


def _unescape(text: str) -> str:
    return re.sub(r"\\x([0-9a-f]{2})", lambda m: chr(int(m[1], 16)), text)


def _parse_message(text: str) -> Decoded:
    """``Name key=value ...`` as printed by vector_check."""
    name, *pairs = text.split(" ")
    fields: Fields = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        assert sep, pair
        if key == "samples_cv":
            fields[key] = [int(v) for v in value.split(",")] if value else []
        elif key == "serial":
            fields[key] = _unescape(value)
        elif key == "cal_scale":
            fields[key] = float(value)
        else:
            fields[key] = int(value)
    return name, fields


def _parse_stream(lines: list[str]) -> tuple[list[Decoded], dict[str, int]]:
    """The MSG lines and the final STATS line of one ``S`` command."""
    assert lines, "no output"
    assert lines[-1].startswith("STATS "), lines
    msgs = []
    for line in lines[:-1]:
        assert line.startswith("MSG "), line
        msgs.append(_parse_message(line[4:]))
    stats = {k: int(v) for k, v in (p.split("=") for p in lines[-1].split(" ")[1:])}
    return msgs, stats


def _py_fields(msg: fp.Message) -> Fields:
    fields: Fields = msg._asdict()
    if isinstance(msg, fp.Samples):
        fields["samples_cv"] = list(msg.samples_cv)
    return fields


def _assert_same(got: Decoded, want: Decoded) -> None:
    """Same class, same field names in the same order, same values (f32 to 1e-7 relative)."""
    assert got[0] == want[0]
    got_fields, want_fields = got[1], want[1]
    assert list(got_fields) == list(want_fields), got[0]
    for key, value in want_fields.items():
        if isinstance(value, float):
            assert math.isclose(got_fields[key], value, rel_tol=1e-7), (got[0], key)
        elif isinstance(value, bool):
            assert got_fields[key] == int(value), (got[0], key)
        else:
            assert got_fields[key] == value, (got[0], key)


def _py_stream(stream: bytes) -> tuple[list[Decoded], dict[str, int]]:
    """The Python StreamDecoder on a stream fed in one piece."""
    decoder = fp.StreamDecoder()
    msgs = [(type(m).__name__, _py_fields(m)) for m in decoder.feed(stream)]
    return msgs, decoder.stats.as_dict()


# --- random valid messages -------------------------------------------------------------------


def _random_f32(rng: random.Random) -> float:
    while True:
        (value,) = struct.unpack("<f", rng.getrandbits(32).to_bytes(4, "little"))
        if math.isfinite(value):
            return float(value)


def _random_value(code: str, rng: random.Random) -> Any:
    if code == "B":
        return rng.randrange(1 << 8)
    if code == "H":
        return rng.randrange(1 << 16)
    if code == "I":
        return rng.randrange(1 << 32)
    if code == "Q":
        return rng.randrange(1 << 64)
    if code == "i":
        return rng.randrange(-(1 << 31), 1 << 31)
    if code == "?":
        return rng.random() < 0.5
    if code == "f":
        return _random_f32(rng)
    if code == "16s":
        return "".join(chr(rng.randrange(0x20, 0x7F)) for _ in range(rng.randrange(17)))
    raise AssertionError(f"no generator for struct code {code!r}")


def _random_message(cls: type[Any], rng: random.Random) -> fp.Message:
    """Every field drawn uniformly from its wire type's range (LAYOUTS gives the types)."""
    fmt = fp.LAYOUTS[cls][1]
    codes = ["16s" if c == "s" else c for c in fmt.replace("16s", "s")]
    values = [rng.randrange(1 << 8), *(_random_value(c, rng) for c in codes)]
    if cls is fp.Samples:
        values.append(tuple(rng.randrange(1 << 16) for _ in range(rng.randrange(MAX_SAMPLES + 1))))
    msg: fp.Message = cls(*values)
    return msg


def _random_messages(count: int, seed: int) -> list[fp.Message]:
    """``count`` messages cycling through every message type."""
    rng = random.Random(seed)
    classes = list(fp.LAYOUTS)
    return [_random_message(classes[i % len(classes)], rng) for i in range(count)]


# --- golden results, computed once -----------------------------------------------------------


@pytest.fixture(scope="module")
def golden_frames_in_c(c_tool: CTool) -> dict[str, list[str]]:
    """vector_check's ``F`` output lines for each golden frame, by vector name."""
    lines = c_tool.run(f"F {f['frame_hex']}" for f in FRAMES)
    assert len(lines) == 2 * len(FRAMES), lines
    return {f["name"]: lines[2 * i : 2 * i + 2] for i, f in enumerate(FRAMES)}


# --- tests -------------------------------------------------------------------------------------


def test_library_uses_only_the_allowed_headers() -> None:
    """dthc_protocol.{h,c} include only stdint/stddef/string/stdbool (and, on AVR alone,
    avr/pgmspace.h for the CRC table in flash), never allocate or print."""
    allowed = {"<stdint.h>", "<stddef.h>", "<string.h>", "<stdbool.h>", '"dthc_protocol.h"'}
    for path in (C_DIR / "dthc_protocol.h", C_DIR / "dthc_protocol.c"):
        text = path.read_text()
        # The AVR-only include must sit right under #ifdef __AVR__; other hosts never see it.
        text = text.replace("#ifdef __AVR__\n#include <avr/pgmspace.h>\n", "#ifdef __AVR__\n")
        includes = set(re.findall(r"^\s*#\s*include\s+(\S+)", text, re.MULTILINE))
        assert includes <= allowed, (path.name, includes - allowed)
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf)\s*\(", text), path.name


def test_crc_check_value(c_tool: CTool) -> None:
    """C dthc_crc16 gives the CRC-16/CCITT-FALSE check value 0x29B1 for b"123456789"."""
    assert c_tool.run([f"C {b'123456789'.hex()}"]) == [f"CRC {constants.CRC_CHECK_VALUE:04X}"]


def test_crc_agrees_with_python(c_tool: CTool) -> None:
    """C and Python CRC agree on random data of lengths 0..300, and on the empty input."""
    rng = random.Random(16)
    blobs = [rng.randbytes(n) for n in range(0, 301, 7)]
    lines = c_tool.run(f"C {b.hex()}" for b in blobs)
    assert lines == [f"CRC {fp.crc16(b):04X}" for b in blobs]


def test_constants_match_python(c_tool: CTool) -> None:
    """Every number and code table of constants.py exists in dthc_protocol.h with its value."""
    lines = c_tool.run(["K"])
    assert lines[-1] == "END"
    c_values = {name: int(value) for name, value in (line.split(" ") for line in lines[:-1])}
    for name in constants.__all__:
        value = getattr(constants, name)
        if value is constants.InputMask:  # the host's masks over InputBit, not a wire table
            assert all(m == 1 << constants.InputBit[str(m.name)] for m in constants.InputMask)
            assert len(constants.InputMask) == len(constants.InputBit)
        elif isinstance(value, type) and issubclass(value, IntEnum | IntFlag):
            assert name in ENUM_PREFIX, f"code table {name} has no C counterpart in this test"
            for member in value:
                c_name = f"{ENUM_PREFIX[name]}{member.name}"
                assert c_values.get(c_name) == int(member), c_name
        elif isinstance(value, int):
            assert c_values.get(f"DTHC_{name}") == value, name
    assert c_values["DTHC_MAX_SAMPLES"] == MAX_SAMPLES
    assert c_values["DTHC_RX_BUF_SIZE"] == constants.MAX_ENCODED_FRAME + 1


@pytest.mark.parametrize("vector", FRAMES, ids=[f["name"] for f in FRAMES])
def test_golden_frame_decodes_and_reencodes(
    golden_frames_in_c: dict[str, list[str]], vector: dict[str, Any]
) -> None:
    """The C streaming receiver decodes the golden wire frame to exactly its JSON fields, and
    dthc_encode re-encodes those fields to exactly the golden wire bytes."""
    ok, re_line = golden_frames_in_c[vector["name"]]
    assert ok.startswith("OK "), ok
    _assert_same(_parse_message(ok[3:]), (vector["message"], vector["fields"]))
    assert re_line == f"RE {vector['frame_hex']}"


def test_golden_bodies_decode_and_reencode(c_tool: CTool) -> None:
    """dthc_decode_body takes every golden decoded frame (body + CRC) to its JSON fields, and
    dthc_encode_body gives back exactly the golden body."""
    bodies = []
    for f in FRAMES:
        body = bytes.fromhex(f["body_hex"])
        bodies.append(body + fp.crc16(body).to_bytes(2, "big"))
    lines = c_tool.run(f"B {b.hex()}" for b in bodies)
    assert len(lines) == 2 * len(FRAMES), lines
    for i, f in enumerate(FRAMES):
        ok, body_line = lines[2 * i : 2 * i + 2]
        assert ok.startswith("OK "), (f["name"], ok)
        _assert_same(_parse_message(ok[3:]), (f["message"], f["fields"]))
        assert body_line == f"BODY {f['body_hex']}", f["name"]


def test_decode_body_rejects_bad_frames(c_tool: CTool) -> None:
    """dthc_decode_body returns the documented error for each kind of bad decoded frame."""

    def framed(body: bytes) -> bytes:
        return body + fp.crc16(body).to_bytes(2, "big")

    torch = framed(bytes.fromhex("040401"))
    cases = {
        "SHORT": framed(b"\x02"),
        "CRC": torch[:-1] + bytes([torch[-1] ^ 1]),
        "UNKNOWN_TYPE": framed(b"\x7f\x01"),
        "BAD_LENGTH": framed(bytes.fromhex("04040101")),
        "TOO_LONG": framed(b"\x83\x00" + bytes(253)),
    }
    samples_odd = framed(b"\x83\x00" + bytes(20))  # 19 + 1: half a sample
    lines = c_tool.run([*(f"B {raw.hex()}" for raw in cases.values()), f"B {samples_odd.hex()}"])
    assert lines == [*(f"ERR {code}" for code in cases), "ERR BAD_LENGTH"]


@pytest.mark.parametrize("vector", CORRUPT, ids=[c["name"] for c in CORRUPT])
def test_corrupt_stream_matches_expectation_and_python(
    c_tool: CTool, vector: dict[str, Any]
) -> None:
    """A damaged stream fed byte by byte to the C receiver yields the expected messages and
    the counters named in `expect`, and every counter equals the Python StreamDecoder's."""
    stream = bytes.fromhex(vector["stream_hex"])
    msgs, stats = _parse_stream(c_tool.run([f"S {stream.hex()}"]))
    expect = dict(vector["expect"])
    want = [FRAME_BY_NAME[name] for name in expect.pop("messages")]
    assert len(msgs) == len(want), msgs
    for got, frame in zip(msgs, want, strict=True):
        _assert_same(got, (frame["message"], frame["fields"]))
    for key in COUNTERS[1:5]:
        assert stats[key] == expect.pop(key, 0), key
    assert expect == {}, f"unchecked expectations: {expect}"

    py_msgs, py_stats = _py_stream(stream)
    assert len(py_msgs) == len(msgs)
    for got, py in zip(msgs, py_msgs, strict=True):
        _assert_same(got, py)
    assert {k: stats[k] for k in COUNTERS} == {k: py_stats[k] for k in COUNTERS}
    assert stats["bytes_in"] == len(stream)


def test_decoded_frame_over_256_bytes_is_a_framing_error(c_tool: CTool) -> None:
    """258 encoded bytes can decode to 257: one byte over the maximum frame. With a valid CRC
    it is still dropped as a framing error (as in Python), and the next frame survives."""
    ack = FRAME_BY_NAME["ack"]
    for body in (b"\x83\x00" + bytes(19 + 2 * (MAX_SAMPLES + 1)), b"\x80\x01" + bytes(253)):
        frame = fp.encode_frame(body)
        assert len(frame) == constants.MAX_ENCODED_FRAME + 1
        stream = frame + bytes.fromhex(ack["frame_hex"])
        msgs, stats = _parse_stream(c_tool.run([f"S {stream.hex()}"]))
        assert len(msgs) == 1
        _assert_same(msgs[0], (ack["message"], ack["fields"]))
        assert stats["framing_errors"] == 1
        assert stats["dropped_bytes"] == len(frame)
        py_stats = _py_stream(stream)[1]
        assert {k: stats[k] for k in COUNTERS} == {k: py_stats[k] for k in COUNTERS}


def _garbage(rng: random.Random, frames: list[bytes]) -> bytes:
    """One piece of line noise: random bytes, an over-long run, a torn or bit-flipped frame."""
    kind = rng.randrange(5)
    if kind == 0:
        return rng.randbytes(rng.randrange(1, 40))
    if kind == 1:  # longer than any frame, no delimiter: forces the over-long path
        return bytes(rng.randrange(1, 256) for _ in range(rng.randrange(259, 400)))
    frame = rng.choice(frames)[:-1]
    if kind == 2:  # torn: a frame cut short
        return frame[: rng.randrange(len(frame))]
    if kind == 3:  # one bit flipped (the flip may create or remove a zero)
        damaged = bytearray(frame)
        damaged[rng.randrange(len(damaged))] ^= 1 << rng.randrange(8)
        return bytes(damaged)
    return b""  # nothing but the delimiter


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_resync_through_random_garbage(
    c_tool: CTool, golden_frames_in_c: dict[str, list[str]], seed: int
) -> None:
    """Every C-encoded golden frame, each preceded by random garbage and a lone delimiter (as
    a sender sends after opening the port), survives when fed byte by byte; the C receiver
    reports the same messages and counters as the Python StreamDecoder."""
    rng = random.Random(seed)
    frames = [bytes.fromhex(golden_frames_in_c[f["name"]][1][3:]) for f in FRAMES]
    stream = b"".join(_garbage(rng, frames) + b"\x00" + frame for frame in frames)
    msgs, stats = _parse_stream(c_tool.run([f"S {stream.hex()}"]))

    # The golden frames come out in order (garbage may, rarely, decode to extra messages).
    remaining = iter(msgs)
    for f in FRAMES:
        want = (f["message"], f["fields"])
        for got in remaining:
            if got[0] == want[0] and list(got[1].values()) == list(want[1].values()):
                break
        else:
            pytest.fail(f"golden frame {f['name']} lost in the stream")
    assert stats["framing_errors"] + stats["crc_errors"] > 0, "the garbage did no damage"

    py_msgs, py_stats = _py_stream(stream)
    assert len(py_msgs) == len(msgs)
    for got, py in zip(msgs, py_msgs, strict=True):
        _assert_same(got, py)
    assert {k: stats[k] for k in COUNTERS} == {k: py_stats[k] for k in COUNTERS}


def test_random_messages_agree_with_python(c_tool: CTool) -> None:
    """200 random valid messages (every type, every field over its full wire range) encoded
    by Python decode in C to the same fields, and C re-encodes them to the same bytes."""
    messages = _random_messages(200, seed=2024)
    wires = [fp.encode(m) for m in messages]
    lines = c_tool.run(f"F {w.hex()}" for w in wires)
    assert len(lines) == 2 * len(messages), lines[:4]
    for i, (msg, wire) in enumerate(zip(messages, wires, strict=True)):
        ok, re_line = lines[2 * i : 2 * i + 2]
        assert ok.startswith("OK "), (msg, ok)
        _assert_same(_parse_message(ok[3:]), (type(msg).__name__, _py_fields(msg)))
        assert re_line == f"RE {wire.hex()}", msg


def _cobs_inputs(rng: random.Random) -> list[bytes]:
    out = [b"", b"\x00", b"\x00\x00", b"\x01"]
    for n in (253, 254, 255, 256, 508, 509, 600):
        out.append(bytes(rng.randrange(1, 256) for _ in range(n)))  # no zeros: block edges
        out.append(bytes(rng.randrange(1, 256) for _ in range(n)) + b"\x00")
    for _ in range(60):
        density = rng.choice((0.0, 0.01, 0.2, 0.9))
        n = rng.randrange(300)
        out.append(bytes(0 if rng.random() < density else rng.randrange(1, 256) for _ in range(n)))
    return out


def test_cobs_matches_the_python_package(c_tool: CTool) -> None:
    """dthc_cobs_encode produces exactly the bytes of the `cobs` package (also at 254-byte
    block edges), dthc_cobs_decode inverts it, and both reject the same invalid input."""
    rng = random.Random(254)
    data = _cobs_inputs(rng)
    lines = c_tool.run(f"E {d.hex()}" for d in data)
    assert lines == [f"COBS {cobs.encode(d).hex()}" for d in data]
    encoded = [cobs.encode(d) for d in data]
    lines = c_tool.run(f"D {e.hex()}" for e in encoded)
    assert lines == [f"RAW {d.hex()}" for d in data]

    invalid = [b"\x09\x01\x02", b"\x03\x01", b"\x02\x01\x00\x01", b"\x00", b"\xff" + bytes(10)]
    for enc in invalid:
        with pytest.raises(cobs.DecodeError):
            cobs.decode(enc)
    assert c_tool.run(f"D {e.hex()}" for e in invalid) == ["ERR COBS"] * len(invalid)


def test_sanitized_build_runs_every_vector(
    c_tool: CTool, tmp_path: Path, golden_frames_in_c: dict[str, list[str]]
) -> None:
    """Built with -fsanitize=address,undefined (skipped if the compiler lacks it), the C codec
    runs all golden, corrupt, random and COBS inputs without a report and with the same output."""
    exe = tmp_path / "vector_check_asan"
    proc = _compile(exe, SANITIZE)
    if proc.returncode != 0:
        pytest.skip(f"compiler cannot build with {' '.join(SANITIZE)}: {proc.stderr[-300:]}")
    sanitized = CTool(exe, env={"ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0"})
    probe = subprocess.run(
        [str(exe)], input="K\n", capture_output=True, text=True, timeout=60, check=False
    )
    if probe.returncode != 0 and "Sanitizer" in probe.stderr and "END" not in probe.stdout:
        pytest.skip(f"sanitizer runtime unusable here: {probe.stderr[-300:]}")

    rng = random.Random(7)
    frames = [bytes.fromhex(lines[1][3:]) for lines in golden_frames_in_c.values()]
    lines = [
        *(f"F {f['frame_hex']}" for f in FRAMES),
        *(f"B {f['body_hex']}{fp.crc16(bytes.fromhex(f['body_hex'])):04x}" for f in FRAMES),
        *(f"S {c['stream_hex']}" for c in CORRUPT),
        "S " + b"".join(_garbage(rng, frames) + b"\x00" + fr for fr in frames).hex(),
        "S " + rng.randbytes(5000).hex(),
        *(f"F {fp.encode(m).hex()}" for m in _random_messages(200, seed=99)),
        *(f"E {d.hex()}" for d in _cobs_inputs(rng)),
        *(f"D {rng.randbytes(rng.randrange(300)).hex()}" for _ in range(50)),
        f"F {'01' * 600}00",
        "K",
    ]
    assert sanitized.run(lines) == c_tool.run(lines)
