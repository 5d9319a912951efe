"""``bench faults``: every fault at every phase of a cut, with the real processes.

Each cell is one fresh stack (mosquitto, the daemon under an emulated supervisor, the mock
board on a pty, the sender as its own process running a two-cut program): the bench waits
for the phase, strikes the fault, and measures

- ``unsafe_torch_ms``: torch-on time the board's lease should have prevented (the mock's
  ground truth: torch on past the lease plus one sample period);
- ``requests_lost``: a sender request that never got an answer (its report says so);
- ``requests_duplicated``: torch-on commands the board executed beyond the cuts the sender
  started (arc retries included): a command run twice;
- ``recovery_s``: from the fault's end until the daemon is online with the board online
  again (0 when neither went away);
- the outcome: the program completed, or stopped with a clear error (and where to restart).

Faults: the daemon killed (restarted by its supervisor after ``RestartSec``, as the
shipped unit's ``Restart=on-failure`` does) or stopped 0.5 s and 2 s, the board unplugged
1 s or rebooted, the broker restarted or unreachable for 10 s, the sender killed, both
cores pinned by other processes, a burst of corrupt bytes on the link, 1 % frame loss for
10 s. Phases: idle, probing, arc wait, pierce delay, cutting (THC active), THC locked (the
operator's THC switch off mid-cut), between cuts.

``--board atmega2560`` runs the same matrix with the reference firmware's ELF on the
emulated Mega (``dthc-emulated-board``, simavr) in place of the mock, X and Y on the
emulated grbl (the emulated board has no XY). The board's faults become the emulator's own
(its control channel): unplugged = the pty's master closed and the port's path gone for
1 s, then a new pty behind it; rebooted = SIGUSR2, the MCU's reset pin; corrupt bytes = the
same 1800 bytes put into the board's stream to the host; frame loss = each board frame lost
whole with 1 % probability for 10 s. The rest strike the daemon, broker and sender as on
the mock. The ground truth is the emulator's record of the relay pin against the host
frames reaching the MCU's UART (simulated time): torch on past the lease plus one sample
period (and the decode tolerance of the conformance suite); a torch-on done twice is a
relay rising edge beyond the daemon's torch-on attempts. Each cell also reports how the
emulator kept up (simulated against wall seconds, its worst lag).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dthc_bridge.config import BoardSettings
from dthc_bridge.conformance.options import LEASE_TOLERANCE_US

from ..demo import Stack, StackOptions
from ..emulated_board.build import checkout_root, ensure_built
from ..emulated_board.harness import (
    EmulatedBoard,
    read_record,
    torch_on_edges,
    unsafe_torch_us,
)
from ..procs import die_with_parent
from .mock_control import mock_control
from .report import Goal, goals_block

__all__ = [
    "BOARDS", "FAULTS", "PHASES", "add_arguments", "board_serials", "board_truth", "cell_holds",
    "recovery_s", "run", "silent_resumes",
]  # fmt: skip

RESTART_SEC = 2.0  # systemd/dthc-bridge.service: Restart=on-failure, RestartSec=2s
RECOVERY_GOAL_S = 2.0
PROGRAM = [  # two short cuts: every phase happens, "between cuts" too
    "G21 G90", "T112 M6", "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S0",
    "G0 X50 Y100", "M3", "M667 F600", "G1 X200 Y100 F3000", "M666", "M5",
    "G0 X50 Y150", "M3", "M667 F600", "G1 X200 Y150 F3000", "M666", "M5",
    "G0 X0 Y0", "M30",
]  # fmt: skip
PHASES = ("idle", "probing", "arc_wait", "pierce_delay", "cutting", "thc_locked", "between_cuts")
BOARDS = ("mock", "atmega2560")  # the emulated Nano is not on the matrix (yet)
SAMPLE_PERIOD_US = 1000  # the firmware's sample period (the mock's grace: lease + one)
CORRUPT_BYTES = 1800


@dataclass
class Cell:
    """One run: its stack, its sender process, and when the fault ended."""

    stack: Stack
    sender: subprocess.Popen[str] | None = None
    fault_end: float = 0.0


Strike = Callable[[Cell], Awaitable[None]]


async def _daemon_kill(cell: Cell) -> None:
    stack = cell.stack
    assert stack.daemon is not None
    stack.daemon.kill()
    await asyncio.to_thread(stack.daemon.wait, 5)
    await asyncio.sleep(RESTART_SEC)
    stack._start_daemon()  # the supervisor's restart


def _daemon_stop(seconds: float) -> Strike:
    async def strike(cell: Cell) -> None:
        assert cell.stack.daemon is not None
        pid = cell.stack.daemon.pid
        os.kill(pid, signal.SIGSTOP)
        await asyncio.sleep(seconds)
        os.kill(pid, signal.SIGCONT)

    return strike


def _mock_signal(sig: int, lasts_s: float) -> Strike:
    async def strike(cell: Cell) -> None:
        if cell.stack.emulated_board is not None:
            await _emulated_board_fault(cell.stack.emulated_board, sig, lasts_s)
            return
        assert cell.stack.mock is not None
        os.kill(cell.stack.mock.pid, sig)
        await asyncio.sleep(lasts_s)

    return strike


async def _emulated_board_fault(board: EmulatedBoard, sig: int, lasts_s: float) -> None:
    """The mock's SIGUSR1 (unplug) and SIGUSR2 (reboot) on the emulated board."""
    if sig == signal.SIGUSR2:
        board.reboot()  # SIGUSR2 to the emulator: the MCU's reset pin
        await asyncio.sleep(lasts_s)
        return
    await asyncio.to_thread(board.unplug)
    await asyncio.sleep(lasts_s)
    await asyncio.to_thread(board.replug)


def _broker_down(seconds: float) -> Strike:
    async def strike(cell: Cell) -> None:
        await cell.stack.broker.stop()
        await asyncio.sleep(seconds)
        await cell.stack.broker.start()

    return strike


async def _sender_kill(cell: Cell) -> None:
    if cell.sender is not None:
        cell.sender.kill()


async def _starve(cell: Cell) -> None:
    hogs = [
        subprocess.Popen(  # noqa: ASYNC220 - started and killed here, never waited on long
            [sys.executable, "-c", "while True: pass"], preexec_fn=die_with_parent()
        )
        for _ in range(4)  # two per core
    ]
    try:
        await asyncio.sleep(3.0)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


async def _corrupt_burst(cell: Cell) -> None:
    garbage = random.Random(3).randbytes(CORRUPT_BYTES)
    if cell.stack.emulated_board is not None:
        await asyncio.to_thread(cell.stack.emulated_board.inject, garbage)
        return
    async with mock_control(cell.stack.gantry_port) as mock:
        await mock.request("inject", hex=garbage.hex())


async def _frame_loss(cell: Cell) -> None:
    if cell.stack.emulated_board is not None:
        await asyncio.to_thread(cell.stack.emulated_board.drop_frames, 0.01, 10.0)
    else:
        async with mock_control(cell.stack.gantry_port) as mock:
            await mock.request("drop_frames", rate=0.01, for_s=10.0)
    await asyncio.sleep(10.0)


FAULTS: dict[str, Strike] = {
    "daemon_kill_restart": _daemon_kill,
    "daemon_stop_0.5s": _daemon_stop(0.5),
    "daemon_stop_2s": _daemon_stop(2.0),
    "board_unplug_1s": _mock_signal(signal.SIGUSR1, 1.0),
    "board_reboot": _mock_signal(signal.SIGUSR2, 0.0),
    "broker_restart": _broker_down(0.2),
    "broker_down_10s": _broker_down(10.0),
    "sender_kill": _sender_kill,
    "cpu_starvation": _starve,
    "corrupt_burst": _corrupt_burst,
    "frame_loss_1pct_10s": _frame_loss,
}
QUICK_PHASE = {  # --quick: one phase per fault, each phase used
    "daemon_kill_restart": "cutting", "daemon_stop_0.5s": "pierce_delay",
    "daemon_stop_2s": "cutting", "board_unplug_1s": "probing", "board_reboot": "arc_wait",
    "broker_restart": "cutting", "broker_down_10s": "between_cuts", "sender_kill": "cutting",
    "cpu_starvation": "thc_locked", "corrupt_burst": "cutting", "frame_loss_1pct_10s": "idle",
}  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="one phase per fault (~3 min)")
    parser.add_argument("--faults", help="comma-separated subset of: " + ", ".join(FAULTS))
    parser.add_argument("--phases", help="comma-separated subset of: " + ", ".join(PHASES))
    parser.add_argument(
        "--keep-dir", type=Path,
        help="run the cells in this directory and keep it (each cell's logs and, on the "
        "emulated board, its record): default a temporary one, removed",
    )  # fmt: skip
    parser.add_argument(
        "--board", choices=BOARDS, default="mock",
        help="mock: the mock board (default); atmega2560: the reference firmware on the "
        "emulated Mega (simavr), X and Y on the emulated grbl",
    )  # fmt: skip


async def _phase(cell: Cell, phase: str, timeout_s: float = 60.0) -> None:
    """Until the program is in ``phase`` (the daemon's sequence events, exact)."""
    stack = cell.stack
    deadline = time.monotonic() + timeout_s
    settle = {"cutting": 1.2, "thc_locked": 1.2}.get(phase, 0.0)  # THC delay: target taken
    target = {"between_cuts": "idle", "thc_locked": "cutting"}.get(phase, phase)
    while time.monotonic() < deadline:
        seen = _events(stack.events)
        cut_done = any(e["previous"] == "to_safe_height" for e in seen)
        if seen and seen[-1]["state"] == target and (phase != "between_cuts" or cut_done):
            await asyncio.sleep(settle)
            if phase == "thc_locked":
                # The THC locked, the arc on: the operator's THC switch off (as M666). Not
                # thc_hold: the operator's hold is a pause now, ending the cut (invariant 7),
                # and the sender waits on it for the operator.
                await stack.request("thc", on=False)
            return
        await asyncio.sleep(0.005)
    raise RuntimeError(f"the program never reached {phase}")


def _start_sender(stack: Stack, program: Path, log: Any) -> subprocess.Popen[str]:
    motion = (
        ["--backend", "grbl", "--port", str(stack.grbl_pty)]
        if stack.options.motion == "grbl"
        else ["--gantry", f"socket://127.0.0.1:{stack.gantry_port}"]
    )
    return subprocess.Popen(  # noqa: S603 - our own command, fixed arguments
        [sys.executable, "-m", "dthc_bridge", "send", str(program), "--json",
         "--broker", f"mqtt://127.0.0.1:{stack.broker.port}", "--base-topic", stack.base,
         *motion],
        stdout=subprocess.PIPE, stderr=log, text=True, preexec_fn=die_with_parent(),
    )  # fmt: skip


async def _until_back(stack: Stack, struck_at: float, timeout_s: float = 15.0) -> None:
    """The sender may end before the daemon is back: wait for it (or the timeout)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if recovery_s(stack.events, struck_at, time.monotonic()) is not None:
            return
        await asyncio.sleep(0.05)


def recovery_s(events: list[dict[str, Any]], struck_at: float, fault_end: float) -> float | None:
    """From the fault's end until daemon and board are both online again (0: neither went
    away; None: not back)."""
    down = False
    online = {"availability": True, "board": True}
    back_at: float | None = None
    for event in events:
        topic = event.get("topic")
        if topic not in online or float(event["received_s"]) < struck_at:
            continue
        online[str(topic)] = event.get("state") == "online"
        if not all(online.values()):
            down, back_at = True, None
        elif down and back_at is None:
            back_at = float(event["received_s"])
    if not down:
        return 0.0
    if back_at is None:
        return None
    return round(max(0.0, back_at - fault_end), 3)


def _program_file(workdir: Path) -> Path:
    workdir.mkdir(parents=True)
    program = workdir / "part.nc"
    program.write_text("\n".join(PROGRAM) + "\n")
    return program


def _stack_options(workdir: Path, board: str) -> StackOptions:
    if board == "mock":
        return StackOptions(workdir, broker="mosquitto", telemetry_hz=20.0)
    return StackOptions(  # built once by _matrix
        workdir, broker="mosquitto", telemetry_hz=20.0, board=board, motion="grbl",
        board_build=False,
    )  # fmt: skip


def _emulator_pace(board: EmulatedBoard | None) -> dict[str, Any] | None:
    """How the emulator kept up: simulated seconds against wall seconds since it started,
    its worst lag behind the wall clock; its link counters."""
    if board is None:
        return None
    status = board.status()
    wall_s = float(status.fields["wall_s"])
    return {
        "sim_s": round(status.t_us / 1e6, 3), "wall_s": round(wall_s, 3),
        "speed": round(status.t_us / 1e6 / wall_s, 4) if wall_s > 0 else None,
        "max_lag_ms": float(status.fields["max_lag_ms"]),
        "reboots": int(status.fields["reboots"]),
        "frames_lost": int(status.fields.get("frames_lost", 0)),
        "rx_dropped": int(status.fields["rx_dropped"]),
        "tx_dropped": int(status.fields["tx_dropped"]),
    }  # fmt: skip


def board_truth(record: Path, lease_ms: int) -> dict[str, Any]:
    """The emulated board's ground truth from its record: the mock's exit figures' names
    (``unsafe_torch_ms``, ``torch_on_commands``: relay rising edges, ``violations``) and
    the host frames the MCU received (none: the daemon never talked to this board)."""
    events = read_record(record)
    grace_us = lease_ms * 1000 + SAMPLE_PERIOD_US + LEASE_TOLERANCE_US
    unsafe_us, episodes = unsafe_torch_us(events, grace_us)
    return {
        "unsafe_torch_ms": unsafe_us / 1000,
        "torch_on_commands": torch_on_edges(events),
        "violations": {"torch_on_after_lease_expiry": episodes} if episodes else {},
        "host_frames": sum(1 for e in events if e.event == "host_frame"),
        "relay_on_at_end": next(
            (e.fields[:1] == ("1",) for e in reversed(events) if e.event == "torch"), False
        ),
    }  # fmt: skip


def board_serials(daemon_log: Path) -> list[str]:
    """The serial numbers the boards said in their HELLO, as the daemon logged them."""
    serials = []
    for line in daemon_log.read_text(errors="replace").splitlines():
        if '"board_hello"' in line:
            with contextlib.suppress(ValueError):
                serial = json.loads(line).get("serial")
                if serial and serial not in serials:
                    serials.append(str(serial))
    return serials


async def _cell(fault: str, phase: str, workdir: Path, board: str = "mock") -> dict[str, Any]:
    program = _program_file(workdir)
    report: dict[str, Any] | None = None
    pace: dict[str, Any] | None = None
    missed: str | None = None  # the phase never came: why (the fault was not struck)
    async with Stack(_stack_options(workdir, board)) as stack:
        cell = Cell(stack)
        with (workdir / "sender.log").open("w") as log:
            if phase != "idle":
                cell.sender = _start_sender(stack, program, log)
                try:
                    await _phase(cell, phase)
                except RuntimeError as exc:
                    missed = str(exc)
                    if cell.sender.poll() is None:  # waiting on an operator, say
                        cell.sender.terminate()
            struck_at = time.monotonic()
            if missed is None:
                await FAULTS[fault](cell)
            cell.fault_end = time.monotonic()
            if phase == "idle":
                await asyncio.sleep(RECOVERY_GOAL_S + 1.0)  # then the program, as an operator
                cell.sender = _start_sender(stack, program, log)
            sender = cell.sender
            assert sender is not None
            try:
                out, _ = await asyncio.to_thread(sender.communicate, timeout=120)
            except subprocess.TimeoutExpired:
                sender.kill()
                out, _ = await asyncio.to_thread(sender.communicate)
            if out.strip():
                report = json.loads(out.strip().splitlines()[-1])
        await _until_back(stack, struck_at)
        recovery = recovery_s(stack.events, struck_at, cell.fault_end)
        pace = await asyncio.to_thread(_emulator_pace, stack.emulated_board)
        result = await stack.finish()
        if stack.emulated_board is not None:
            result.mock_exit.update(board_truth(stack.board_record, BoardSettings().lease_ms))
    faults_seen = [
        str(e.get("reason") or e.get("code")) for e in result.events
        if e.get("topic") == "event" and e.get("type") in ("fault", "pause")
    ]  # fmt: skip
    mock = result.mock_exit
    torch_on = int(mock.get("torch_on_commands", 0))
    # Each arc_wait the daemon entered is one torch-on it sent; the board doing more than
    # that ran a command twice.
    attempts = sum(1 for e in _events(result.events) if e.get("state") == "arc_wait")
    error = str(report["error"]) if report else "the sender was killed"
    lost = int(report is not None and "no response" in error)
    outcome = "completed" if report and report["ok"] else f"stopped: {error}"
    cell_result = {
        "fault": fault, "phase": phase, "board": board,
        "board_serials": board_serials(workdir / "daemon.log"),
        "unsafe_torch_ms": float(mock.get("unsafe_torch_ms", float("nan"))),
        "requests_lost": lost,
        "requests_duplicated": max(0, torch_on - attempts),
        "silent_resumes": silent_resumes(result.events),
        "recovery_s": recovery,
        "outcome": outcome,
        "restart_line": report.get("restart_line") if report else None,
        "daemon_faults": faults_seen[:4],
        "violations": mock.get("violations", {}),
    }  # fmt: skip
    if pace is not None:
        cell_result["emulator"] = {**pace, "host_frames": mock["host_frames"],
                                   "relay_on_at_end": mock["relay_on_at_end"]}  # fmt: skip
        if mock["relay_on_at_end"]:
            cell_result["violations"] = {**cell_result["violations"], "relay_on_at_end": 1}
    cell_result["pass"] = cell_holds(cell_result)
    if missed is not None:  # a failed cell, said as such: the fault never struck
        cell_result["outcome"] = f"not struck: {missed} ({outcome})"
        cell_result["pass"] = False
    return cell_result


def silent_resumes(events: list[dict[str, Any]]) -> int:
    """Torch-on attempts (``arc_wait``) after the daemon ended a cut through the fault path
    with no re-arm since (a re-arm is the only way out of ``faulted``): a cut that went on
    by itself after a fault."""
    count = 0
    faulted = False
    for event in _events(events):
        state = event.get("state")
        if state == "faulted":
            faulted = True
        elif state == "idle" and event.get("previous") == "faulted":
            faulted = False  # re-armed
        elif state == "arc_wait" and faulted:
            count += 1
    return count


def _events(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [e for e in events if e.get("topic") == "event" and e.get("type") == "sequence"]


def cell_holds(cell: dict[str, Any]) -> bool:
    clear = cell["outcome"] == "completed" or bool(cell["outcome"].split(": ", 1)[-1])
    return bool(
        cell["unsafe_torch_ms"] == 0.0
        and cell["requests_lost"] == 0
        and cell["requests_duplicated"] == 0
        and cell.get("silent_resumes", 0) == 0
        and cell["recovery_s"] is not None
        and cell["recovery_s"] <= RECOVERY_GOAL_S
        and not cell["violations"]
        and clear
    )


async def _matrix(args: argparse.Namespace, workdir: Path) -> dict[str, object]:
    faults = args.faults.split(",") if args.faults else list(FAULTS)
    phases = args.phases.split(",") if args.phases else list(PHASES)
    for name in faults:
        if name not in FAULTS:
            raise SystemExit(f"--faults: {name!r} is not one of {', '.join(FAULTS)}")
    for name in phases:
        if name not in PHASES:
            raise SystemExit(f"--phases: {name!r} is not one of {', '.join(PHASES)}")
    plan = (
        [(f, QUICK_PHASE[f]) for f in faults]
        if args.quick
        else [(f, p) for f in faults for p in phases]
    )
    if args.board != "mock":  # make what is stale once, not in every cell
        await asyncio.to_thread(ensure_built, checkout_root())
    t0 = time.monotonic()
    cells = []
    for i, (fault, phase) in enumerate(plan):
        if not args.json:
            print(f"... {fault} in {phase}", file=sys.stderr, flush=True)
        try:
            cells.append(await _cell(fault, phase, workdir / f"cell{i}", args.board))
        except (RuntimeError, OSError, subprocess.SubprocessError) as exc:
            # The stack itself failed (a board that never came online...): a failed cell
            # with nothing measured, said as such; the matrix goes on.
            cells.append({"fault": fault, "phase": phase, "board": args.board, "pass": False,
                          "outcome": f"cell error: {exc}", "unsafe_torch_ms": None,
                          "requests_lost": None, "requests_duplicated": None,
                          "silent_resumes": None, "recovery_s": None})  # fmt: skip
    measured = [c for c in cells if c["unsafe_torch_ms"] is not None]
    recoveries = [(c["recovery_s"], f"{c['fault']}/{c['phase']}") for c in cells
                  if c["recovery_s"] is not None]  # fmt: skip
    worst = max(recoveries, default=(0.0, ""))
    totals = {
        "unsafe_torch_ms": sum(c["unsafe_torch_ms"] for c in measured),
        "unsafe_torch_ms_worst": max((c["unsafe_torch_ms"] for c in measured), default=0.0),
        "requests_lost": sum(c["requests_lost"] for c in measured),
        "requests_duplicated": sum(c["requests_duplicated"] for c in measured),
        "silent_resumes": sum(c["silent_resumes"] for c in measured),
        "cells_unmeasured": len(cells) - len(measured),
        "worst_recovery_s": worst[0], "worst_recovery_cell": worst[1],
        "cells": len(cells), "cells_failed": sum(not c["pass"] for c in cells),
        "board": args.board,
    }  # fmt: skip
    paces = [c["emulator"] for c in cells if "emulator" in c]
    if paces:  # how the emulated MCU kept up with the wall clock over the whole matrix
        totals["emulator_speed_min"] = min((p["speed"] for p in paces if p["speed"]), default=None)
        totals["emulator_max_lag_ms"] = max(p["max_lag_ms"] for p in paces)
    goals = [
        Goal("unsafe_torch_ms", float(totals["unsafe_torch_ms"]), 0, at_most=True, unit=" ms"),
        Goal("requests_lost", float(totals["requests_lost"]), 0, at_most=True),
        Goal("requests_duplicated", float(totals["requests_duplicated"]), 0, at_most=True),
        Goal("silent_resumes", float(totals["silent_resumes"]), 0, at_most=True),
        Goal("worst_recovery_s", float(worst[0]), RECOVERY_GOAL_S, at_most=True, unit=" s"),
        Goal("cells_failed", float(totals["cells_failed"]), 0, at_most=True),
    ]
    return {**totals, "run_s": round(time.monotonic() - t0, 1), "matrix": cells,
            "goals": goals_block(goals)}  # fmt: skip


def run(args: argparse.Namespace) -> dict[str, object]:
    keep: Path | None = getattr(args, "keep_dir", None)
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        return asyncio.run(_matrix(args, keep))
    with tempfile.TemporaryDirectory(prefix="dthc-faults-") as tmp:
        return asyncio.run(_matrix(args, Path(tmp)))
