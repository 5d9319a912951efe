"""``bench fuzz``: bad bytes and bad requests at the daemon's process boundaries, mid-cut.

The whole stack runs (mosquitto, the mock board on a pty, the daemon as its own process)
and a sender cuts a long part. Meanwhile:

- **frames**: mutated board frames are written into the daemon's pty by the mock (its
  ``inject`` op: the real pty, the real decoder): valid frames with flipped bits, cut
  short, oversized, of unknown types, of wrong lengths (those two with a good CRC), random
  bytes, replayed SAMPLES, and at the very end a few HELLO_INFO/ACK frames of another boot
  id (the board seen to reboot mid-cut);
- **payloads**: random and mutated MQTT payloads and topics are published through
  mosquitto to every request topic (wrong types, huge or missing fields, invalid UTF-8,
  deep nesting, oversize, names the daemon does not know). A candidate that happens to be
  a valid, state-changing command (an ``M3``, an ``abort``) is not sent: this fuzzes the
  refusal paths, not the command set, and the cut must go on.

Checked: the daemon never exits or restarts (same pid, availability never offline), every
well-formed request (a JSON object with a transaction, a valid name, within the size
limit) gets exactly one response, the board executes no torch-on beyond the cuts the
sender started (arc retries included), and the daemon's memory (RSS) before and after.
The seed is printed first, so a failure reproduces with ``--seed``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import struct
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiomqtt

import firmware_protocol as fp
from dthc_bridge.controller.commands import CommandError
from dthc_bridge.controller.gcode import parse_line
from dthc_bridge.mqtt.topics import REQUEST_NAME
from dthc_bridge.requests import GCODE_REQUEST, REQUESTS, parse_request

from ..demo import Stack, StackOptions
from .mock_control import mock_control
from .report import Goal, goals_block

__all__ = ["FrameFuzzer", "PayloadFuzzer", "add_arguments", "run"]

BOARD_TYPES = (fp.Ack, fp.Nak, fp.HelloInfo, fp.Samples, fp.Event, fp.Fault,
               fp.MotionDone, fp.ProbeResult, fp.Status, fp.Clock)  # fmt: skip
KNOWN_TYPES = frozenset(int(t) for t, _ in fp.LAYOUTS.values())
CHUNK_BYTES = 1800  # per inject op: its hex fits the control port's 4 kB line
MAX_PAYLOAD = 4096  # the daemon's max_payload_bytes (default)
# Requests whose valid payloads change nothing of the cut: read-only ones, and the anti-dive
# speed (the sender's next report replaces it). Every other request of the table is sent
# only when it is refused (a command whose arguments do not parse) or not at all.
SAFE_REQUESTS = frozenset({"status", "materials", "material_get", "motion"})
assert REQUESTS.keys() >= SAFE_REQUESTS
FRAMES_PER_CUT = 100_000  # a 1 m cut at 3 m/min lasts 20 s; the fuzzer writes ~5,800 frames/s


def program(frames: int) -> list[str]:
    """Long cuts, enough to last while the frames go in: the fuzzing happens mid-cut."""
    lines = ["G21 G90", "T112 M6", "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S0"]
    for i in range(1 + frames // FRAMES_PER_CUT):
        y = 100 + 50 * i
        lines += [f"G0 X50 Y{y}", "M3", "M667 F600", f"G1 X1050 Y{y} F3000", "M666", "M5"]
    return [*lines, "G0 X0 Y0", "M30"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=100_000, help="mutated frames to write")
    parser.add_argument("--payloads", type=int, default=10_000, help="MQTT payloads to publish")
    parser.add_argument("--seed", type=int, help="reproduce a run (default: a new one, printed)")
    parser.add_argument(
        "--reboots", type=int, default=3,
        help="frames of another boot id at the end (the board seen to reboot mid-cut)",
    )  # fmt: skip


# --- frames ----------------------------------------------------------------------------------


class FrameFuzzer:
    """Seeded board frames, each mutated one way; ``kinds`` counts them."""

    def __init__(self, rng: random.Random, boot_id: int = 0) -> None:
        self.rng = rng
        self.boot_id = boot_id
        self.kinds: Counter[str] = Counter()
        self.redrawn = 0  # mutations that were valid frames by chance, drawn again

    def _body(self) -> bytes:
        """A frame body of a board message type with random fields of the right size."""
        rng = self.rng
        cls = rng.choice(BOARD_TYPES)
        msg_type, layout = fp.LAYOUTS[cls]
        size = struct.calcsize("<" + layout)
        if cls is fp.Samples:
            size += 2 * rng.randint(1, 10)
        return bytes((int(msg_type), rng.randrange(256))) + rng.randbytes(size)

    def frames(self, count: int, tail_reboots: int = 3) -> Iterator[bytes]:
        """``count`` mutated frames. The last ``tail_reboots`` are valid frames that can only
        mean the board restarted: replayed SAMPLES from long ago (board time going back) and
        HELLO_INFO/ACK of another boot id. The daemon must end the cut safely and
        re-handshake, not crash; before them the cut must go on."""
        for _ in range(max(0, count - tail_reboots)):
            yield b"\x00" + self._invalid()
        for i in range(min(count, tail_reboots)):
            if i % 3 == 0:
                self.kinds["replayed_samples"] += 1
                yield b"\x00" + self._samples()
            else:
                self.kinds["other_boot_id"] += 1
                yield b"\x00" + self._other_boot(i)

    def _invalid(self) -> bytes:
        """A mutation that is no valid frame. Now and then flipped bits or random bytes
        happen to make one with a good CRC (a random boot id: the board seen to reboot);
        those are drawn again, so only the tail's deliberate frames end the cut."""
        while True:
            kind, data = self._one()
            if not list(fp.StreamDecoder().feed(b"\x00" + data + b"\x00")):
                self.kinds[kind] += 1
                return data
            self.redrawn += 1

    def _one(self) -> tuple[str, bytes]:
        rng = self.rng
        roll = rng.random()
        if roll < 0.40:
            kind = "bit_flips"
            frame = bytearray(fp.encode_frame(self._body()))
            for _ in range(rng.randint(1, 3)):
                at = rng.randrange(len(frame) - 1)  # the delimiter stays: one frame each
                frame[at] ^= 1 << rng.randrange(8)
            return kind, bytes(frame)
        if roll < 0.55:
            kind = "truncated"
            whole = fp.encode_frame(self._body())
            return kind, whole[: rng.randrange(1, len(whole) - 1)]  # no delimiter: ends at the next
        if roll < 0.65:
            kind = "oversized"
            return kind, fp.encode_frame(
                self._body() + rng.randbytes(fp.MAX_FRAME + rng.randint(1, 64))
            )
        if roll < 0.75:
            kind = "unknown_type"
            unknown = rng.choice([t for t in range(256) if t not in KNOWN_TYPES])
            return kind, fp.encode_frame(bytes((unknown,)) + self._body()[1:])
        if roll < 0.85:
            kind = "wrong_length"
            body = self._body()
            # Odd for SAMPLES, whose length says how many 2-byte samples follow.
            delta = rng.choice((-1, 1)) * (2 * rng.randint(0, 3) + 1)
            body = body[:delta] if delta < 0 else body + rng.randbytes(delta)
            return kind, fp.encode_frame(body)
        return "garbage", rng.randbytes(rng.randint(1, 64))

    def _samples(self) -> bytes:
        """A plausible SAMPLES frame from long ago (old stream counter, old board time)."""
        rng = self.rng
        msg = fp.Samples(0, rng.randrange(100), rng.randrange(10**6), 1000, 1500, 0, 0,
                         fp.XY_SPEED_UNKNOWN, 0, (12000,) * 5)  # fmt: skip
        return fp.encode(msg)

    def _other_boot(self, i: int) -> bytes:
        other = (self.boot_id + 1 + i) & 0xFFFFFFFF
        if i % 2 == 0:
            return fp.encode(fp.Ack(self.rng.randrange(1, 256), other))
        return fp.encode(fp.HelloInfo(0, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 1, 0, 0, 0,
                                      other, "FUZZ", 1000, 5, 0, 0, 100_000, fp.MAX_FRAME,
                                      500))  # fmt: skip


# --- MQTT payloads --------------------------------------------------------------------------


class PayloadFuzzer:
    """Seeded request topics and payloads; ``expected`` maps each well-formed request's
    transaction to its topic (it must get exactly one response)."""

    NAMES = tuple(sorted(REQUESTS))  # the daemon's request table

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.expected: dict[str, str] = {}
        self.kinds: Counter[str] = Counter()
        self.skipped_valid = 0

    def messages(self, count: int) -> Iterator[tuple[str, bytes]]:
        made = 0
        while made < count:
            name, payload = self._candidate(made)
            if name is None:
                continue
            made += 1
            yield name, payload

    def _candidate(self, index: int) -> tuple[str | None, bytes]:
        rng = self.rng
        roll = rng.random()
        name = self._name()
        transaction = f"fz-{index}"
        if roll < 0.05:
            self.kinds["invalid_utf8"] += 1
            return name, b'{"transaction": "' + rng.randbytes(8) + b'"}'
        if roll < 0.10:
            self.kinds["oversize"] += 1
            return name, json.dumps({"transaction": transaction,
                                     "line": "G1 X1 " * 1000}).encode()  # fmt: skip
        if roll < 0.15:
            self.kinds["deep"] += 1
            return name, ("[" * 200 + "]" * 200).encode()
        if roll < 0.25:
            self.kinds["not_an_object"] += 1
            return name, json.dumps(self._value(3)).encode()
        document: dict[str, Any] = {"transaction": transaction}
        document.update(self._fields(name))
        if not self._harmless(name, document):
            self.skipped_valid += 1
            return None, b""
        payload = json.dumps(document).encode()
        self.kinds["object"] += 1
        if REQUEST_NAME.fullmatch(name) and len(payload) <= MAX_PAYLOAD:
            self.expected[transaction] = name
        return name, payload

    def _name(self) -> str:
        rng = self.rng
        roll = rng.random()
        if roll < 0.8:
            return rng.choice(self.NAMES)
        if roll < 0.9:
            return "".join(rng.choice("abcdefghijklmnopqrstuvwxyz_-0123456789")
                           for _ in range(rng.randint(1, 80)))  # fmt: skip
        return rng.choice(("a b", "ü", "x" * 65, "status/extra", "..", "$x"))

    def _fields(self, name: str) -> dict[str, Any]:
        rng = self.rng
        keys = (
            "line",
            "volts",
            "on",
            "mm",
            "reset",
            "mode",
            "percent",
            "number",
            "name",
            "xy_speed_mm_s",
            "line_number",
            "x",
            "y",
            "deadline_ms",
            "dialect",
            "cut_height",
        )
        out: dict[str, Any] = {}
        if name == "gcode" and rng.random() < 0.7:
            out["line"] = self._gcode()
        for _ in range(rng.randint(0, 3)):
            out[rng.choice(keys)] = self._value(2)
        return out

    def _gcode(self) -> str:
        rng = self.rng
        words = [f"{rng.choice('GMXYZFSPQIJKTHDACVOBE#%')}{rng.choice(('', '-'))}"
                 f"{rng.choice(('1', '0.5', '200', '667', '1e9', 'nan', '', '3', '5'))}"
                 for _ in range(rng.randint(0, 6))]  # fmt: skip
        return " ".join(words) + rng.choice(("", " (x", " ;y", "\x00", "\n"))

    def _value(self, depth: int) -> Any:
        rng = self.rng
        kinds = ["int", "float", "str", "bool", "null", "big"] + (["list", "dict"] * (depth > 0))
        kind = rng.choice(kinds)
        if kind == "int":
            return rng.randint(-(2**40), 2**40)
        if kind == "float":
            return rng.uniform(-1e6, 1e6)
        if kind == "str":
            return "".join(chr(rng.randrange(32, 0x2FF)) for _ in range(rng.randint(0, 20)))
        if kind == "bool":
            return rng.random() < 0.5
        if kind == "null":
            return None
        if kind == "big":
            return rng.choice((1e308, -1e308, 2**63, "9" * 400))
        if kind == "list":
            return [self._value(depth - 1) for _ in range(rng.randint(0, 4))]
        return {str(self._value(0)): self._value(depth - 1) for _ in range(rng.randint(0, 3))}

    @staticmethod
    def _harmless(name: str, document: dict[str, Any]) -> bool:
        """False for a payload the daemon would accept as a command that changes the cut."""
        args = {k: v for k, v in document.items() if k != "transaction"}
        if name in SAFE_REQUESTS:
            return True
        if name == GCODE_REQUEST:
            line = args.get("line")
            if not isinstance(line, str):
                return True
            try:
                parsed = parse_line(line)
            except (CommandError, ValueError):
                return True
            return not parsed.commands  # a motion line: its feed noted, answered at once
        spec = REQUESTS.get(name)
        if spec is None:
            return True  # refused: unknown request
        if spec.command is not None:
            try:
                parse_request(name, args)
            except CommandError:
                return True
        return False


# --- the run --------------------------------------------------------------------------------


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


async def _inject(port: int, frames: Iterator[bytes]) -> int:
    """Write the frames through the mock's control port, a chunk at a time."""
    written = 0
    async with mock_control(port) as mock:

        async def send(chunk: bytes) -> int:
            reply = await mock.request("inject", hex=chunk.hex())
            await asyncio.sleep(0.002)  # the daemon reads the pty meanwhile
            return int(reply["bytes"])

        chunk = b""
        for frame in frames:
            if chunk and len(chunk) + len(frame) > CHUNK_BYTES:
                written += await send(chunk)
                chunk = b""
            chunk += frame
        if chunk:
            written += await send(chunk)
    return written


async def _publish(stack: Stack, fuzzer: PayloadFuzzer, count: int) -> Counter[str]:
    """Publish the payloads; count the responses per transaction (listening all along)."""
    answers: Counter[str] = Counter()
    root = stack.root
    broker = stack.broker_settings().model_copy(update={"protocol": "5"})
    async with aiomqtt.Client(**broker.client_options(), identifier="dthc-fuzz") as client:
        await client.subscribe(f"{root}/response/#", qos=1)

        async def listen() -> None:
            async for message in client.messages:
                try:
                    document = json.loads(bytes(message.payload))
                except ValueError:
                    continue
                if isinstance(document, dict) and str(document.get("transaction", "")).startswith(
                    "fz-"
                ):
                    answers[str(document["transaction"])] += 1

        listener = asyncio.create_task(listen())
        for i, (name, payload) in enumerate(fuzzer.messages(count)):
            await client.publish(f"{root}/request/{name}", payload, qos=1)
            if i % 50 == 49:
                await asyncio.sleep(0.02)  # the daemon's max_pending_requests: not a flood
        deadline = time.monotonic() + 10.0
        waiting = True
        while waiting and time.monotonic() < deadline:  # what the listener has counted
            await asyncio.sleep(0.1)
            waiting = any(answers[t] == 0 for t in fuzzer.expected)
        await asyncio.sleep(0.5)  # a duplicate would show up by now
        listener.cancel()
    return answers


async def _fuzz(args: argparse.Namespace, workdir: Path, seed: int) -> dict[str, object]:
    options = StackOptions(workdir, broker="mosquitto", telemetry_hz=10.0)
    frames = FrameFuzzer(random.Random(seed))
    payloads = PayloadFuzzer(random.Random(seed + 1))
    async with Stack(options) as stack:
        assert stack.daemon is not None
        pid = stack.daemon.pid
        await asyncio.sleep(0.5)
        rss_before = _rss_kb(pid)
        sending = asyncio.create_task(stack.send(program(args.frames)))
        while not any(t.get("state") == "cutting" for t in stack.telemetry):  # noqa: ASYNC110
            await asyncio.sleep(0.05)
        t0 = time.monotonic()
        injected, answers = await asyncio.gather(
            _inject(stack.gantry_port, frames.frames(args.frames, args.reboots)),
            _publish(stack, payloads, args.payloads),
        )
        fuzz_s = time.monotonic() - t0
        report = await sending
        await asyncio.sleep(1.0)
        rss_after = _rss_kb(pid)
        alive = stack.daemon.poll() is None
        offline = [e for e in stack.events if e.get("topic") == "availability"
                   and e.get("state") == "offline"]  # fmt: skip
        result = await stack.finish(report)
    missing = sorted(t for t in payloads.expected if answers[t] == 0)
    doubled = sorted(t for t, n in answers.items() if n > 1)
    torch_on = int(result.mock_exit.get("torch_on_commands", -1))
    allowed = 3 * report.cuts_started  # arc_start_attempts per cut
    unsafe_ms = float(result.mock_exit.get("unsafe_torch_ms", float("nan")))
    goals = [
        Goal("daemon_exits", float(not alive) + len(offline), 0, at_most=True),
        Goal("requests_unanswered", float(len(missing)), 0, at_most=True),
        Goal("requests_answered_twice", float(len(doubled)), 0, at_most=True),
        Goal("torch_on_not_asked", float(max(0, torch_on - allowed)), 0, at_most=True),
        Goal("unsafe_torch_ms", unsafe_ms, 0, at_most=True, unit=" ms"),
    ]
    return {
        "seed": seed,
        "frames": sum(frames.kinds.values()),
        "frame_kinds": dict(sorted(frames.kinds.items())),
        "frames_valid_by_chance_redrawn": frames.redrawn,
        "bytes_injected": injected,
        "payloads": sum(payloads.kinds.values()),
        "payload_kinds": dict(sorted(payloads.kinds.items())),
        "valid_commands_not_sent": payloads.skipped_valid,
        "well_formed_requests": len(payloads.expected),
        "responses": sum(answers.values()),
        "unanswered": missing[:20],
        "answered_twice": doubled[:20],
        "fuzz_s": round(fuzz_s, 2),
        "daemon_alive": alive,
        "daemon_rss_kb": {"before": rss_before, "after": rss_after},
        "program": {"ok": report.ok, "error": report.error, "cuts": report.cuts_started},
        "torch_on_commands": torch_on,
        "unsafe_torch_ms": unsafe_ms,
        "violations": result.mock_exit.get("violations", {}),
        "board_executed": result.mock_exit.get("executed", {}),
        "goals": goals_block(goals),
    }


def run(args: argparse.Namespace) -> dict[str, object]:
    seed = args.seed if args.seed is not None else random.randrange(2**32)
    print(f"bench fuzz: seed {seed} (reproduce with --seed {seed})", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory(prefix="dthc-fuzz-") as tmp:
        return asyncio.run(_fuzz(args, Path(tmp), seed))
