"""The C reference codec (firmware_protocol/c/) against the golden vectors and the Python codec.

The C sources are compiled once per module with the system compiler and strict flags into a
temporary directory; ``vector_check`` (see its header comment) drives the C codec from text
lines, so one process run checks a whole batch of frames. The small-MCU API (frame views,
in-place receive, one-pass encoding, the CRC table) is checked the same way, and the codec
is built with avr-gcc for an ATmega328P when that compiler is installed.
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
from hypothesis import example, given, settings
from hypothesis import strategies as st

import firmware_protocol as fp
from firmware_protocol import constants, vectors

C_DIR = Path(fp.__file__).resolve().parent / "c"
SOURCES = (C_DIR / "dthc_protocol.c", C_DIR / "vector_check.c")
CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2")
SANITIZE = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-g")
AVR_CFLAGS = ("-mmcu=atmega328p", "-Os", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic")
# DTHC_TX_PAYLOAD_OFFSET: a payload this far into the output buffer can be encoded in place.
TX_PAYLOAD_OFFSET = 3
CRC_POLY = 0x1021  # CRC-16/CCITT-FALSE (PROTOCOL.md 2); constants.py has no name for it

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
    "InternalFault": "DTHC_INTERNAL_",
    "NakCode": "DTHC_NAK_",
    "ResetReason": "DTHC_RESET_",
    "ProbeOutcome": "DTHC_PROBE_",
    "HomeOutcome": "DTHC_HOME_",
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
    """dthc_protocol.{h,c} and the generated dthc_messages.h include only
    stdint/stddef/string/stdbool (and, on AVR alone, avr/pgmspace.h for the CRC table in
    flash), never allocate or print."""
    allowed = {"<stdint.h>", "<stddef.h>", "<string.h>", "<stdbool.h>"}
    allowed |= {'"dthc_protocol.h"', '"dthc_messages.h"'}
    for path in (C_DIR / "dthc_protocol.h", C_DIR / "dthc_protocol.c", C_DIR / "dthc_messages.h"):
        text = path.read_text()
        # The AVR-only include must sit right under #ifdef __AVR__; other hosts never see it.
        text = text.replace("#ifdef __AVR__\n#include <avr/pgmspace.h>\n", "#ifdef __AVR__\n")
        includes = set(re.findall(r"^\s*#\s*include\s+(\S+)", text, re.MULTILINE))
        assert includes <= allowed, (path.name, includes - allowed)
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf)\s*\(", text), path.name


def test_crc_check_value(c_tool: CTool) -> None:
    """C dthc_crc16 and dthc_crc16_update give the CRC-16/CCITT-FALSE check value 0x29B1 for
    b"123456789"."""
    check = b"123456789".hex()
    want = f"CRC {constants.CRC_CHECK_VALUE:04X}"
    assert want == "CRC 29B1"
    assert c_tool.run([f"C {check}", f"U {check}"]) == [want, want]


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
    assert c_values["DTHC_TX_PAYLOAD_OFFSET"] == TX_PAYLOAD_OFFSET


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
        *(f"N {f['frame_hex']}" for f in FRAMES),
        *(f"N {c['stream_hex']}" for c in CORRUPT),
        *(f"R {c['stream_hex']}" for c in CORRUPT),
        f"N {_rejects_stream().hex()}",
        f"R {_rejects_stream().hex()}",
        "N " + rng.randbytes(3000).hex(),
        *(f"P {f['body_hex']}" for f in FRAMES),
        *(f"P {rng.randbytes(n).hex()}" for n in (2, 3, 200, 254, 255, 256)),
        *(f"L {rng.randbytes(8).hex()}" for _ in range(10)),
        *(f"U {rng.randbytes(rng.randrange(100)).hex()}" for _ in range(10)),
        "K",
    ]
    assert sanitized.run(lines) == c_tool.run(lines)


# --- the small-MCU API: CRC table, frame views, in-place receive, one-pass encoding -----------


def _crc16_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE one bit at a time, straight from the definition (PROTOCOL.md 2)."""
    crc = constants.CRC_INIT
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC_POLY) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def test_crc_table_is_the_polynomial_table_in_flash_on_avr() -> None:
    """dthc_protocol.c carries a 256-entry table T[i] = bitwise CRC register of i << 8, which
    dthc_crc16_update uses, and on AVR it is PROGMEM read with pgm_read_word."""
    source = (C_DIR / "dthc_protocol.c").read_text()
    found = re.search(r"dthc_crc_table\[256\][^=]*=\s*\{([^}]*)\}", source)
    assert found, "no 256-entry CRC table in dthc_protocol.c"
    table = [int(v, 16) for v in re.findall(r"0x([0-9A-Fa-f]{1,4})", found[1])]
    want = []
    for i in range(256):
        reg = i << 8
        for _ in range(8):
            reg = ((reg << 1) ^ CRC_POLY) if reg & 0x8000 else reg << 1
            reg &= 0xFFFF
        want.append(reg)
    assert table == want
    avr = source[source.index("#ifdef __AVR__") : source.index("#endif")]
    assert "PROGMEM" in avr, avr
    assert "pgm_read_word" in avr, avr
    update = source[source.index("uint16_t dthc_crc16_update(") :]
    assert "DTHC_CRC_STEP" in update[: update.index("}")]


@settings(max_examples=30, deadline=None)
@given(st.lists(st.binary(max_size=300), min_size=1, max_size=20))
@example([b"123456789", b"", b"\x00", b"\xff" * 300])
def test_crc_table_equals_bitwise_crc(c_tool: CTool, blobs: list[bytes]) -> None:
    """The table-driven dthc_crc16 and dthc_crc16_update equal the bitwise CRC on any data."""
    lines = c_tool.run([*(f"C {b.hex()}" for b in blobs), *(f"U {b.hex()}" for b in blobs)])
    want = [f"CRC {_crc16_bitwise(b):04X}" for b in blobs]
    assert lines == want + want


@pytest.fixture(scope="module")
def golden_views_in_c(c_tool: CTool) -> dict[str, list[str]]:
    """vector_check's ``N`` output (frame-view receiver) for each golden frame, by name."""
    out = {}
    lines = c_tool.run(f"N {f['frame_hex']}" for f in FRAMES)
    assert len(lines) == 5 * len(FRAMES), lines[:10]
    for i, f in enumerate(FRAMES):
        out[f["name"]] = lines[5 * i : 5 * i + 5]
    return out


@pytest.mark.parametrize("vector", FRAMES, ids=[f["name"] for f in FRAMES])
def test_golden_frame_through_frame_view(
    golden_views_in_c: dict[str, list[str]], vector: dict[str, Any]
) -> None:
    """dthc_rx_feed hands out the golden frame's type, seq and payload as a view into the
    receiver's own buffer (no copy); dthc_frame_to_msg unpacks it to the JSON fields; and
    dthc_encode_frame re-encodes the view to exactly the golden wire bytes, also in place."""
    frame_line, ok, re_line, ip_line, stats = golden_views_in_c[vector["name"]]
    body = bytes.fromhex(vector["body_hex"])
    assert frame_line == (
        f"FRAME type={body[0]} seq={body[1]} len={len(body) - 2} payload={body[2:].hex()} inbuf=1"
    )
    assert ok.startswith("OK "), ok
    _assert_same(_parse_message(ok[3:]), (vector["message"], vector["fields"]))
    assert re_line == f"RE {vector['frame_hex']}"
    assert ip_line == f"IP {vector['frame_hex']}"
    assert stats.startswith("STATS frames_ok=1 crc_errors=0 framing_errors=0 "), stats


def test_golden_bodies_encode_in_one_pass(c_tool: CTool) -> None:
    """dthc_encode_frame(type, seq, payload) gives every golden wire frame, from a separate
    payload and in place at DTHC_TX_PAYLOAD_OFFSET, and so do dthc_frame_seal (its exact
    wire length) with dthc_frame_stream, and dthc_encode_in_place; a smaller cap returns 0
    and writes nothing past it."""
    lines = c_tool.run(f"P {f['body_hex']}" for f in FRAMES)
    assert len(lines) == 5 * len(FRAMES), lines[:10]
    for i, f in enumerate(FRAMES):
        wire = f["frame_hex"]
        assert lines[5 * i : 5 * i + 5] == [
            f"WIRE {wire}",
            f"INPLACE {wire}",
            f"STREAM {len(wire) // 2} {wire}",
            f"SEALED {wire}",
            f"CAP {len(wire) // 2}",
        ], f["name"]


@settings(max_examples=25, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=260)),
        min_size=1,
        max_size=12,
    )
)
@example([(0x83, 0, bytes(252)), (0x80, 7, b"\xff" * 252), (1, 1, b""), (2, 0, bytes(253))])
def test_encode_frame_matches_python(c_tool: CTool, frames: list[tuple[int, int, bytes]]) -> None:
    """Any type, seq and payload of up to 252 bytes encodes as the Python codec does (also in
    place, streamed, and with the smallest cap); a longer payload is refused with 0."""
    bodies = [bytes((t, q)) + payload for t, q, payload in frames]
    lines = iter(c_tool.run(f"P {b.hex()}" for b in bodies))
    for body in bodies:
        if len(body) - 2 > constants.MAX_PAYLOAD:
            assert next(lines) == "ERR TOO_LONG"
            continue
        wire = fp.encode_frame(body)
        assert [next(lines) for _ in range(5)] == [
            f"WIRE {wire.hex()}",
            f"INPLACE {wire.hex()}",
            f"STREAM {len(wire)} {wire.hex()}",
            f"SEALED {wire.hex()}",
            f"CAP {len(wire)}",
        ]
    assert next(lines, None) is None


def test_encode_frame_at_cobs_block_edges(c_tool: CTool) -> None:
    """Frames whose 254-byte COBS block ends at, just before or just after the last CRC byte
    (no zero, or a zero among the CRC bytes) encode as the Python codec does."""
    rng = random.Random(254)
    bodies = []
    for n in range(246, constants.MAX_PAYLOAD + 1):
        for _ in range(6):
            body = bytes((0x83, rng.randrange(1, 256))) + bytes(
                rng.randrange(1, 256) for _ in range(n)
            )
            bodies.append(body)
    crcs = [fp.crc16(b) for b in bodies]
    assert any(c & 0xFF00 and c & 0xFF for c in crcs), "no block ending on the CRC"
    assert any(not (c & 0xFF00 and c & 0xFF) for c in crcs), "no zero among the CRC bytes"
    lines = iter(c_tool.run(f"P {b.hex()}" for b in bodies))
    for body in bodies:
        wire = fp.encode_frame(body)
        assert [next(lines) for _ in range(5)] == [
            f"WIRE {wire.hex()}",
            f"INPLACE {wire.hex()}",
            f"STREAM {len(wire)} {wire.hex()}",
            f"SEALED {wire.hex()}",
            f"CAP {len(wire)}",
        ], body.hex()


def _framed(body: bytes) -> bytes:
    """A wire frame with a valid CRC, whatever the body says."""
    return fp.encode_frame(body)


# (body, the error dthc_rx_feed reports): valid CRC, unknown type or wrong payload length.
REJECTS: list[tuple[bytes, str]] = [
    (b"\x7f\x2a" + b"abc", "UNKNOWN_TYPE"),
    (b"\x00\x09", "UNKNOWN_TYPE"),
    (b"\x8b\xc8" + bytes(8), "UNKNOWN_TYPE"),
    (b"\x04\x2b\x01\x01", "BAD_LENGTH"),  # TORCH with 2 bytes
    (b"\x02\xff\x00", "BAD_LENGTH"),  # HEARTBEAT with a payload byte
    (b"\x01\x05" + bytes(5), "BAD_LENGTH"),  # HELLO one byte short
    (b"\x83\x00" + bytes(20), "BAD_LENGTH"),  # SAMPLES with half a sample
]


def _rejects_stream() -> bytes:
    """Each rejected frame, then a CRC-damaged frame and a torn COBS frame (which carry no
    usable seq), then a valid TORCH: the receiver must deliver the last one."""
    torch = bytes.fromhex(FRAME_BY_NAME["torch_on"]["frame_hex"])  # TORCH on, seq 4
    bad_crc = bytearray(_framed(bytes.fromhex("0c1100")))
    bad_crc[-2] ^= 0x01
    return b"".join(_framed(b) for b, _ in REJECTS) + bytes(bad_crc) + b"\x05\x01\x00" + torch


def test_rejected_frame_yields_its_seq_and_type(c_tool: CTool) -> None:
    """A frame with a valid CRC but an unknown type or a wrong payload length comes out of
    dthc_rx_feed as DTHC_ERR_UNKNOWN_TYPE / DTHC_ERR_BAD_LENGTH with *frame filled (type, seq,
    payload, length, a view into rx.buf), so a firmware can NAK its seq (PROTOCOL.md 7);
    after a CRC or COBS error *frame is untouched; the counters are the old receiver's."""
    stream = _rejects_stream()
    lines = c_tool.run([f"N {stream.hex()}", f"S {stream.hex()}"])
    want = [
        f"ERR {err} type={b[0]} seq={b[1]} len={len(b) - 2} payload={b[2:].hex()} inbuf=1"
        for b, err in REJECTS
    ]
    want += ["ERR CRC untouched", "ERR COBS untouched"]
    assert lines[: len(want)] == want
    assert lines[len(want)] == "FRAME type=4 seq=4 len=1 payload=01 inbuf=1"
    assert lines[len(want) + 1].startswith("OK Torch seq=4 on=1"), lines[len(want) + 1]
    view_stats, old_stats = lines[len(want) + 4], lines[-1]
    assert view_stats == old_stats
    stats = {k: int(v) for k, v in (p.split("=") for p in view_stats.split(" ")[1:])}
    assert (stats["unknown_type"], stats["length_errors"]) == (3, 4)
    assert (stats["crc_errors"], stats["framing_errors"], stats["frames_ok"]) == (1, 1, 1)


def test_old_api_reports_reject_seq_and_type(c_tool: CTool) -> None:
    """dthc_rx_feed_byte sets rx.reject_type and rx.reject_seq for a frame dropped for an
    unknown type or a bad length, and leaves them alone for other errors."""
    lines = c_tool.run([f"R {_rejects_stream().hex()}"])
    want = [f"ERR {err} reject_type={b[0]} reject_seq={b[1]}" for b, err in REJECTS]
    last = REJECTS[-1][0]
    want += [f"ERR {e} reject_type={last[0]} reject_seq={last[1]}" for e in ("CRC", "COBS")]
    assert lines[: len(want)] == want
    assert lines[len(want)].startswith("MSG Torch seq=4 on=1"), lines[len(want)]


@pytest.mark.parametrize("vector", CORRUPT, ids=[c["name"] for c in CORRUPT])
def test_frame_view_receiver_counts_like_the_message_receiver(
    c_tool: CTool, vector: dict[str, Any]
) -> None:
    """On every damaged golden stream dthc_rx_feed delivers the same messages (through
    dthc_frame_to_msg) and the same counters as dthc_rx_feed_byte."""
    stream = vector["stream_hex"]
    view = c_tool.run([f"N {stream}"])
    msgs, stats = _parse_stream(c_tool.run([f"S {stream}"]))
    ok = [_parse_message(line[3:]) for line in view if line.startswith("OK ")]
    assert ok == msgs
    assert view[-1].startswith("STATS ")
    assert {k: int(v) for k, v in (p.split("=") for p in view[-1].split(" ")[1:])} == stats
    frames = [line for line in view if line.startswith("FRAME ")]
    assert len(frames) == len(msgs)
    assert all(f.endswith(" inbuf=1") for f in frames)


def test_random_messages_through_frame_views(c_tool: CTool) -> None:
    """200 random valid messages of every type encoded by Python come out of dthc_rx_feed
    with the Python fields, and dthc_encode_frame gives back the same wire bytes."""
    messages = _random_messages(200, seed=328)
    wires = [fp.encode(m) for m in messages]
    lines = c_tool.run(f"N {w.hex()}" for w in wires)
    assert len(lines) == 5 * len(messages), lines[:5]
    for i, (msg, wire) in enumerate(zip(messages, wires, strict=True)):
        frame, ok, re_line, ip_line, _stats = lines[5 * i : 5 * i + 5]
        body = fp.encode_message(msg)
        assert frame == (
            f"FRAME type={body[0]} seq={body[1]} len={len(body) - 2} payload={body[2:].hex()}"
            " inbuf=1"
        )
        _assert_same(_parse_message(ok[3:]), (type(msg).__name__, _py_fields(msg)))
        assert re_line == ip_line.replace("IP", "RE", 1) == f"RE {wire.hex()}"


@settings(max_examples=20, deadline=None)
@given(st.lists(st.binary(min_size=8, max_size=8), min_size=1, max_size=50))
@example([bytes(8), b"\xff" * 8, b"\x00\x00\x00\x80" * 2, b"\xff\xff\xff\x7f" * 2])
def test_little_endian_helpers_match_struct(c_tool: CTool, blobs: list[bytes]) -> None:
    """dthc_get_u16/u32/i32/u64 read little-endian fields as struct does, and
    dthc_put_u16/u32/i32/u64 write them back byte for byte."""
    lines = c_tool.run(f"L {b.hex()}" for b in blobs)
    for blob, line in zip(blobs, lines, strict=True):
        (u16,) = struct.unpack_from("<H", blob)
        (u32,) = struct.unpack_from("<I", blob)
        (i32,) = struct.unpack_from("<i", blob)
        (u64,) = struct.unpack_from("<Q", blob)
        put = struct.pack("<HIiQ", u16, u32, i32, u64)
        assert line == f"LE u16={u16} u32={u32} i32={i32} u64={u64} put={put.hex()}"


# --- the codec on an 8-bit MCU (avr-gcc, ATmega328P) ---------------------------------------

AVR_PROGRAM = r"""
#include <avr/io.h>
#include "dthc_protocol.h"

/* A minimal board loop on the frame-view API alone: receive, ACK or NAK in place. */
static dthc_rx_t rx;
static uint8_t tx[DTHC_MAX_WIRE_FRAME];

static void send(size_t n)
{
    size_t i;
    for (i = 0; i < n; i++) {
        while (!(UCSR0A & (1 << UDRE0))) {
        }
        UDR0 = tx[i];
    }
}

int main(void)
{
    dthc_frame_t f;
    uint8_t *p = tx + DTHC_TX_PAYLOAD_OFFSET;
    dthc_rx_init(&rx);
    for (;;) {
        int rc;
        while (!(UCSR0A & (1 << RXC0))) {
        }
        rc = dthc_rx_feed(&rx, UDR0, &f);
        if (rc == 1) {
            dthc_put_u32(p, dthc_get_u32(f.payload) + 1u);
            send(dthc_encode_frame(DTHC_MSG_ACK, f.seq, p, 4, tx, sizeof tx));
        } else if (rc == DTHC_ERR_UNKNOWN_TYPE || rc == DTHC_ERR_BAD_LENGTH) {
            dthc_put_u32(p, 0);
            p[4] = (uint8_t)(rc == DTHC_ERR_UNKNOWN_TYPE ? DTHC_NAK_UNKNOWN_TYPE
                                                         : DTHC_NAK_BAD_LENGTH);
            p[5] = 0;
            send(dthc_encode_frame(DTHC_MSG_NAK, f.seq, p, 6, tx, sizeof tx));
        }
    }
}
"""


def _avr_size(path: Path) -> dict[str, int]:
    """avr-size's Berkeley columns text/data/bss of an object or ELF file."""
    proc = subprocess.run(
        ["avr-size", str(path)], capture_output=True, text=True, timeout=60, check=True
    )
    header, row = proc.stdout.splitlines()[:2]
    return dict(zip(header.split()[:3], (int(v) for v in row.split()[:3]), strict=True))


def test_codec_builds_for_atmega328p(tmp_path: Path) -> None:
    """dthc_protocol.c compiles warning-free with avr-gcc -mmcu=atmega328p -Os -std=c99
    -pedantic -Werror; no function needs a stack frame over 64 bytes (the old parser kept a
    254-byte message on the stack); a board loop on the frame-view API links, and neither it
    nor the whole codec puts a byte in .data: the CRC table and the payload-size table stay in
    flash (a const table or a switch gcc turns into a table would be copied to RAM on AVR).
    Sizes are printed (pytest -s)."""
    if shutil.which("avr-gcc") is None or shutil.which("avr-size") is None:
        pytest.skip("avr-gcc or avr-size not installed (Debian: gcc-avr binutils-avr avr-libc)")
    obj = tmp_path / "dthc_protocol.o"
    cmd = [
        "avr-gcc",
        *AVR_CFLAGS,
        "-fstack-usage",
        "-c",
        str(C_DIR / "dthc_protocol.c"),
        "-o",
        str(obj),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, f"avr-gcc failed:\n{proc.stderr}"
    assert proc.stderr == "", proc.stderr
    size = _avr_size(obj)
    assert (size["data"], size["bss"]) == (0, 0), size
    assert size["text"] < 8 * 1024, size
    whole = tmp_path / "whole.elf"
    (tmp_path / "empty.c").write_text("int main(void) { return 0; }\n")
    link_all = ["avr-gcc", *AVR_CFLAGS, str(tmp_path / "empty.c"), str(obj), "-o", str(whole)]
    proc = subprocess.run(link_all, capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    assert _avr_size(whole)["data"] == 0, "the codec puts tables in RAM on AVR"

    frames = {}
    for line in (tmp_path / "dthc_protocol.su").read_text().splitlines():
        where, nbytes, _kind = line.split("\t")
        frames[where.rsplit(":", 1)[-1]] = int(nbytes)
    assert {"dthc_rx_feed", "dthc_encode_frame"} <= set(frames), frames
    assert max(frames.values()) <= 64, frames

    main_c = tmp_path / "board.c"
    main_c.write_text(AVR_PROGRAM)
    elf = tmp_path / "board.elf"
    link = [
        "avr-gcc",
        *AVR_CFLAGS,
        "-ffunction-sections",
        "-fdata-sections",
        "-Wl,--gc-sections",
        f"-I{C_DIR}",
        str(main_c),
        str(C_DIR / "dthc_protocol.c"),
        "-o",
        str(elf),
    ]
    proc = subprocess.run(link, capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, f"avr-gcc (board loop) failed:\n{proc.stderr}"
    board = _avr_size(elf)
    assert board["data"] == 0, board
    print(
        f"\navr-gcc {' '.join(AVR_CFLAGS)} dthc_protocol.c: .text {size['text']} B "
        f"(CRC table 512 B of it, in flash), .data {size['data']} B, .bss {size['bss']} B; "
        f"largest stack frame {max(frames.values())} B ({max(frames, key=frames.__getitem__)})"
        f"\nminimal board loop on the frame-view API, linked with --gc-sections: "
        f".text {board['text']} B, .data {board['data']} B, .bss {board['bss']} B"
    )
