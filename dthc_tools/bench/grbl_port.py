"""``dthc-bridge bench port``: what the grbl port (issue 32) adds to a line's answer.

In one run, on the same machine: an emulated grbl on a pty by itself (the bare round trip a
sender has with a grbl), and the port in front of another one with the daemon, the mock
board and the broker beside it (the stack of ``dthc-bridge demo`` on grbl motion). The
same lines go one at a time to each (written, then the answer awaited, as a sender's
``ok`` waits), and their answer times are compared:

- ``modal``: a line only grbl acts on (``G90``): the port's receiving, planning and
  relaying;
- ``feed``: a move with a new feed (``G1 X0 F…``): besides, the feed the daemon's
  anti-dive compares the speed with goes to the daemon and is answered over MQTT first.

And the age of the anti-dive speed: the port polls grbl's status (``--status-hz``, 10 by
default) and reports the XY speed to the daemon (``request/motion``, QoS 0). From a move's
``ok`` (grbl has started it) to the first report of a non-zero speed reaching the broker:
``speed_onset`` (p50/p99), against the poll period it cannot beat.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import select
import subprocess
import sys
import tempfile
import time
import tty
from collections.abc import Callable
from pathlib import Path

import aiomqtt

from ..demo import Stack, StackOptions
from ..grbl_port.process import start_port
from ..procs import die_with_parent
from .report import Goal, goals_block, percentiles

__all__ = ["add_arguments", "run"]

KINDS: dict[str, Callable[[int], str]] = {
    "modal": lambda i: "G90",
    "feed": lambda i: f"G1 X0 F{1000 + 500 * (i % 2)}",
}
ADDED_P99_MS = 25.0  # a modal line: the port's own work, well under a sender's patience
STATUS_HZ = 10.0  # the port's default grbl poll (grbl-port --status-hz)
ONSETS = 12  # moves started, for the speed's onset


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lines", type=int, default=200, help="lines of each kind (>= 20)")


def run(args: argparse.Namespace) -> dict[str, object]:
    if args.lines < 20:
        raise SystemExit("--lines: at least 20")
    return asyncio.run(_measure(args.lines))


async def _measure(lines: int) -> dict[str, object]:
    with tempfile.TemporaryDirectory(prefix="dthc-port-bench-") as tmp:
        work = Path(tmp)
        bare_pty = work / "bare-grbl"
        bare = _start_grbl(bare_pty, work / "bare-grbl.log")
        try:
            bare_us = await asyncio.to_thread(_answer_times, bare_pty, lines)
            (work / "stack").mkdir()
            async with Stack(StackOptions(work / "stack", motion="grbl")) as stack:
                listen = work / "grbl-port"
                with (work / "grbl-port.log").open("w") as log:
                    port = await asyncio.to_thread(
                        start_port, listen, stack.grbl_pty, stack.broker.port, stack.base, log
                    )
                    try:
                        port_us = await asyncio.to_thread(_answer_times, listen, lines)
                        onsets_ms = await _speed_onsets(listen, stack)
                    finally:
                        port.terminate()
                        await asyncio.to_thread(port.wait, 10)
                await stack.finish()
        finally:
            bare.terminate()
            bare.wait(10)
    out: dict[str, object] = {"lines_per_kind": lines}
    added_p99: dict[str, float] = {}
    for kind in KINDS:
        b, p = percentiles(bare_us[kind]), percentiles(port_us[kind])
        b50, b99, p50, p99 = (_us(b, "p50"), _us(b, "p99"), _us(p, "p50"), _us(p, "p99"))
        added_p99[kind] = (p99 - b99) / 1000.0
        out[kind] = {
            "bare_us": b, "port_us": p,
            "ratio_p50": round(p50 / b50, 2), "ratio_p99": round(p99 / b99, 2),
            "added_p50_ms": round((p50 - b50) / 1000.0, 3),
            "added_p99_ms": round(added_p99[kind], 3),
        }  # fmt: skip
    onset = percentiles([ms * 1000 for ms in onsets_ms])
    period_ms = 1000.0 / STATUS_HZ
    out["speed_onset_us"] = onset
    out["status_poll_ms"] = period_ms
    out["goals"] = goals_block(
        [
            Goal(
                "port_added_p99_ms_modal", round(added_p99["modal"], 3), ADDED_P99_MS, True, " ms"
            ),
            # A poll period, plus the report's way to the broker and grbl's acceleration.
            Goal(
                "speed_onset_p99_ms", round(_us(onset, "p99") / 1000, 1), 2 * period_ms, True, " ms"
            ),
        ]
    )
    return out


async def _speed_onsets(listen: Path, stack: Stack) -> list[float]:
    """ms from each move's ``ok`` through the port to the first ``motion`` report of a
    non-zero XY speed at the broker; each move ends (a report of 0) before the next."""
    reports: list[tuple[float, float]] = []  # (monotonic s, xy speed)
    got = asyncio.Event()

    async def listen_reports(client: aiomqtt.Client) -> None:
        async for message in client.messages:
            speed = json.loads(bytes(message.payload)).get("xy_speed_mm_s")
            if isinstance(speed, int | float):
                reports.append((time.monotonic(), float(speed)))
                got.set()

    async def first(after: float, moving: bool) -> float:
        while True:
            for at, speed in reports:
                if at >= after and (speed > 0) == moving:
                    return at
            got.clear()
            await asyncio.wait_for(got.wait(), 10)

    link = _Pty(listen)
    onsets = []
    try:
        async with aiomqtt.Client(
            **stack.broker_settings("dashboard").client_options(), identifier="port-bench"
        ) as client:
            await client.subscribe(f"{stack.root}/request/motion", qos=0)
            reader = asyncio.create_task(listen_reports(client))
            try:
                for i in range(ONSETS):
                    x = 10 if i % 2 == 0 else 0  # short moves: the onset is what counts
                    await asyncio.to_thread(link.write, f"G1 X{x} F3000\n".encode())
                    await asyncio.to_thread(link.line_starting, b"ok")
                    started = time.monotonic()
                    onsets.append((await first(started, moving=True) - started) * 1000)
                    await first(time.monotonic(), moving=False)
            finally:
                reader.cancel()
    finally:
        link.close()
    return onsets


def _us(stats: dict[str, object], key: str) -> float:
    value = stats[key]
    assert isinstance(value, int | float)
    return float(value)


def _start_grbl(pty: Path, log: Path) -> subprocess.Popen[str]:
    with log.open("w") as err:
        proc = subprocess.Popen(  # noqa: S603 - our own module, fixed arguments
            [sys.executable, "-m", "dthc_tools.grbl_emu", "--pty", str(pty)],
            stdout=subprocess.PIPE, stderr=err, text=True, preexec_fn=die_with_parent(),
        )  # fmt: skip
    assert proc.stdout is not None
    if not proc.stdout.readline().startswith("READY"):
        raise RuntimeError(f"the grbl emulator did not start: see {log}")
    return proc


def _answer_times(pty: Path, lines: int) -> dict[str, list[float]]:
    """Per kind, the µs from writing each line to reading its answer (one line at a time,
    after a soft reset and its banner). The pty is opened raw, as a sender's serial port."""
    times: dict[str, list[float]] = {kind: [] for kind in KINDS}
    link = _Pty(pty)
    try:
        link.write(b"\x18")
        link.line_starting(b"Grbl ")
        for i in range(lines):
            for kind, make in KINDS.items():
                start = time.perf_counter()
                link.write(make(i).encode() + b"\n")
                answer = link.line_starting(b"ok", b"error:")
                times[kind].append((time.perf_counter() - start) * 1e6)
                if not answer.startswith(b"ok"):
                    raise RuntimeError(f"{pty}: {make(i)!r} answered {answer!r}")
    finally:
        link.close()
    return times


class _Pty:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.buffer = b""

    def write(self, data: bytes) -> None:
        os.write(self.fd, data)

    def line_starting(self, *starts: bytes) -> bytes:
        """The first line that starts with one of ``starts`` (others, [MSG:...], skipped)."""
        deadline = time.monotonic() + 10.0
        while True:
            while b"\n" in self.buffer:
                line, self.buffer = self.buffer.split(b"\n", 1)
                if line.strip().startswith(starts):
                    return line.strip()
            left = deadline - time.monotonic()
            if left <= 0:
                raise RuntimeError(f"{self.path}: no line starting {starts!r} within 10 s")
            if select.select([self.fd], [], [], left)[0]:
                self.buffer += os.read(self.fd, 4096)

    def close(self) -> None:
        os.close(self.fd)
