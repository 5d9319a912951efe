"""``bench panel``: the operator panel while N slow clients hold connections to it.

The panel runs as its own process (``dthc-bridge panel`` on 127.0.0.1, beside a local
broker), from this tree or from ``--tree`` (another checkout, to compare), with the usual
1024 file descriptors (``--panel-fd-limit``). The bench then opens N connections that each
send a request line and one header byte per ``--trickle-s``, never the blank line that ends
the head, and holds them for ``--hold-s``; meanwhile it asks ``GET /api/view`` on a new
connection every ``--probe-interval-s``, as a page reloading would.

Figures: the panel's RSS (before, and the most while held), the probe's response time (p50,
p99, max; a probe unanswered in ``--probe-timeout-s`` counts as failed), how many slow
connections the panel closed and how long after they opened, how many were still open at
the end, and what the panel wrote to stderr (lines, tracebacks). Loopback only; the run
stops by itself (about ``--hold-s`` plus 20 s); the bench raises its own descriptor limit
up to the hard limit for the N connections.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from ..demo import Stack, StackOptions
from ..procs import die_with_parent
from .report import Goal, goals_block, percentiles

__all__ = ["add_arguments", "run"]

STARTUP_S = 20.0
OPEN_TIMEOUT_S = 3.0  # a slow connection the kernel does not complete in this is "not open"
HEAD_DEADLINE_GOAL_S = 12.0  # the panel's HEADER_TIMEOUT_S (10 s) and a margin
PROBE_P99_GOAL_MS = 100.0
SLOW_HEAD = b"GET /api/view HTTP/1.1\r\nHost: 127.0.0.1\r\nUser-Agent: slow\r\nX-Slow: "
PROBE = b"GET /api/view HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--connections", type=int, default=1000, help="N slow connections")
    parser.add_argument("--hold-s", type=float, default=15.0, help="how long they are held")
    parser.add_argument("--trickle-s", type=float, default=1.0, help="one header byte this often")
    parser.add_argument("--probe-interval-s", type=float, default=0.1)
    parser.add_argument("--probe-timeout-s", type=float, default=2.0)
    parser.add_argument(
        "--panel-fd-limit", type=int, default=1024,
        help="the panel process's soft limit of file descriptors (1024: the usual default)",
    )  # fmt: skip
    parser.add_argument(
        "--tree", type=Path, default=None,
        help="run the panel from this source tree (a checkout of another commit)",
    )  # fmt: skip


def run(args: argparse.Namespace) -> dict[str, object]:
    if not 1 <= args.connections <= 20_000 or not 1.0 <= args.hold_s <= 300.0:
        raise SystemExit("--connections 1..20000, --hold-s 1..300")
    _raise_own_fd_limit(args.connections + 200)
    with tempfile.TemporaryDirectory(prefix="bench-panel-") as tmp:
        return asyncio.run(asyncio.wait_for(_bench(args, Path(tmp)), args.hold_s + 120.0))


def _raise_own_fd_limit(wanted: int) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < wanted:
        ceiling = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
        resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, ceiling), hard))


def _panel_preexec(fd_limit: int) -> Callable[[], None]:
    parent_death = die_with_parent()

    def preexec() -> None:
        if parent_death is not None:
            parent_death()
        hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
        resource.setrlimit(resource.RLIMIT_NOFILE, (fd_limit, hard))

    return preexec


def _rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        return None
    return None


class SlowClients:
    """N connections that never finish their request's head; when each was closed."""

    def __init__(self, port: int, trickle_s: float) -> None:
        self.port = port
        self.trickle_s = trickle_s
        self.opened = 0
        self.open_failed = 0
        self.closed_after_s: list[float] = []  # by the panel, from each connection's opening
        self._writers: list[asyncio.StreamWriter] = []

    async def hold(self, index: int) -> None:
        try:
            reader, writer = await asyncio.wait_for(
                asyncio.open_connection("127.0.0.1", self.port), OPEN_TIMEOUT_S
            )
        except (OSError, TimeoutError):
            self.open_failed += 1
            return
        self.opened += 1
        self._writers.append(writer)
        opened_at = time.monotonic()
        writer.write(SLOW_HEAD)
        dripping = asyncio.create_task(self._drip(writer, index))
        try:
            with contextlib.suppress(OSError):
                while await reader.read(4096):
                    pass  # a refusal's text: the connection's end is what counts
            self.closed_after_s.append(time.monotonic() - opened_at)
        finally:
            dripping.cancel()

    async def _drip(self, writer: asyncio.StreamWriter, index: int) -> None:
        with contextlib.suppress(OSError):
            while not writer.is_closing():
                await asyncio.sleep(self.trickle_s)
                writer.write(b"abcdefghijklmnopqrstuvwxyz"[index % 26 : index % 26 + 1])

    def close(self) -> None:
        for writer in self._writers:
            writer.close()


async def _probe(port: int, timeout_s: float) -> tuple[float, int | None]:
    """Seconds and HTTP status of one GET /api/view on a new connection (None: failed)."""
    start = time.monotonic()
    writer: asyncio.StreamWriter | None = None
    try:
        async with asyncio.timeout(timeout_s):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(PROBE)
            answer = await reader.read()
        status = int(answer.split(b" ", 2)[1])
    except (OSError, TimeoutError, ValueError, IndexError):
        return time.monotonic() - start, None
    finally:
        if writer is not None:
            writer.close()
    return time.monotonic() - start, status


async def _probes(
    port: int, args: argparse.Namespace, until: float, results: list[tuple[float, int | None]]
) -> None:
    while time.monotonic() < until:
        results.append(await _probe(port, args.probe_timeout_s))
        await asyncio.sleep(args.probe_interval_s)


async def _rss_samples(pid: int, until: float, samples: list[float]) -> None:
    while time.monotonic() < until:
        rss = _rss_mb(pid)
        if rss is not None:
            samples.append(rss)
        await asyncio.sleep(0.5)


async def _bench(args: argparse.Namespace, workdir: Path) -> dict[str, object]:
    broker = Stack(StackOptions(workdir)).broker
    await broker.start()
    tree = (args.tree or Path(__file__).parents[2]).resolve()
    stderr_path = workdir / "panel.stderr"
    try:
        with stderr_path.open("w") as stderr:
            panel = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "dthc_bridge", "panel",
                "--broker", f"mqtt://127.0.0.1:{broker.port}", "--listen", "127.0.0.1:0",
                cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                stdout=subprocess.PIPE, stderr=stderr,
                preexec_fn=_panel_preexec(args.panel_fd_limit),
            )  # fmt: skip
        try:
            figures = await _measure(args, panel)
        finally:
            if panel.returncode is None:
                panel.terminate()
                try:
                    await asyncio.wait_for(panel.wait(), 10.0)
                except TimeoutError:
                    panel.kill()
                    await panel.wait()
    finally:
        await broker.stop()
    log = stderr_path.read_text(errors="replace").splitlines()
    figures["panel_stderr"] = {
        "lines": len(log),
        "tracebacks": sum("Traceback" in line for line in log),
        "out_of_fd_warnings": sum("panel_out_of_file_descriptors" in line for line in log),
        "accept_errors": sum("accept" in line and "resource" in line for line in log),
    }
    figures["tree"] = str(tree)
    return {**figures, "goals": _goals(figures)}


async def _measure(
    args: argparse.Namespace, panel: asyncio.subprocess.Process
) -> dict[str, object]:
    assert panel.stdout is not None
    line = (await asyncio.wait_for(panel.stdout.readline(), STARTUP_S)).decode()
    if not line.startswith("PANEL "):
        raise RuntimeError(f"the panel did not start: {line!r}")
    port = int(line.split()[1].rstrip("/").rsplit(":", 1)[1])

    baseline: list[tuple[float, int | None]] = []
    await _probes(port, args, time.monotonic() + 2.0, baseline)
    rss_before = _rss_mb(panel.pid)

    slow = SlowClients(port, args.trickle_s)
    held: list[tuple[float, int | None]] = []
    rss: list[float] = []
    started = time.monotonic()
    until = started + args.hold_s
    async with asyncio.TaskGroup() as group:
        group.create_task(_probes(port, args, until, held))
        group.create_task(_rss_samples(panel.pid, until, rss))
        holders = [group.create_task(slow.hold(i)) for i in range(args.connections)]
        await asyncio.sleep(max(0.0, until - time.monotonic()))
        still_open = sum(not task.done() for task in holders)
        for task in holders:
            task.cancel()
    slow.close()
    held_ok = [s for s, status in held if status == 200]
    return {
        "connections": args.connections,
        "hold_s": args.hold_s,
        "panel_fd_limit": args.panel_fd_limit,
        "rss_mb": {"before": rss_before, "max_while_held": max(rss, default=None)},
        "probe_before_ms": percentiles([s for s, st in baseline if st == 200], 1000.0),
        "probe_while_held_ms": percentiles(held_ok, 1000.0),
        "probes_while_held": {
            "sent": len(held),
            "answered_200": len(held_ok),
            "answered_other": sum(st not in (None, 200) for _, st in held),
            "failed": sum(st is None for _, st in held),
        },
        "slow": {
            "opened": slow.opened,
            "not_opened": slow.open_failed,
            "closed_by_panel": len(slow.closed_after_s),
            "closed_after_s": percentiles(slow.closed_after_s, 1.0, 2),
            "still_open_at_end": still_open,
        },
    }


def _goals(figures: dict[str, object]) -> dict[str, object]:
    probe = figures["probe_while_held_ms"]
    probes = figures["probes_while_held"]
    slow = figures["slow"]
    assert isinstance(probe, dict)
    assert isinstance(probes, dict)
    assert isinstance(slow, dict)
    sent = max(1, int(probes["sent"]))
    closed = slow["closed_after_s"]
    assert isinstance(closed, dict)
    stderr = figures["panel_stderr"]
    assert isinstance(stderr, dict)
    return goals_block([
        Goal("probe_p99_ms", probe["p99"], PROBE_P99_GOAL_MS, at_most=True, unit=" ms"),
        Goal("probes_answered_200_percent", round(100.0 * int(probes["answered_200"]) / sent, 1),
             99.0, at_most=False, unit=" %"),
        Goal("slow_closed_within_s", closed["max"], HEAD_DEADLINE_GOAL_S, at_most=True,
             unit=" s"),
        Goal("slow_still_open_at_end", float(slow["still_open_at_end"]), 0.0, at_most=True),
        Goal("panel_tracebacks", float(stderr["tracebacks"]), 0.0, at_most=True),
    ])  # fmt: skip
