"""A broker restart mid-program: the sender and the daemon reconnect, the request in flight
is sent again with its transaction, and every command runs exactly once.

mosquitto (no persistence: its retained documents and sessions are gone after the
restart, the worst case), the daemon and the mock board as their own processes, the
reference sender in this process. Counted on the mock board: pierces, one per M3.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def square_at(x: int) -> list[str]:
    """One cut: start, THC on, two sides of a square, THC off, stop."""
    return [f"G0 X{x} Y20", "M3", "M667 F600", f"G1 X{x + 60} Y20 F3000",
            f"G1 X{x + 60} Y60", "M666", "M5"]  # fmt: skip


PROGRAM = [
    "G21 G90",
    "T112 M6",
    "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S0",
    *square_at(20),
    *square_at(120),
    *square_at(220),
    "G0 X0 Y0",
    "M30",
]
STARTING = {"probing", "to_probe_height", "to_pierce_height", "arc_wait", "pierce_delay"}


async def wait_for_state(stack: Stack, states: set[str], after: int, timeout_s: float) -> int:
    """The index of the first telemetry point from ``after`` on in one of ``states``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for index in range(after, len(stack.telemetry)):
            if stack.telemetry[index].get("state") in states:
                return index
        await asyncio.sleep(0.02)
    raise AssertionError(f"no state in {sorted(states)} within {timeout_s} s")


async def restart_broker(stack: Stack, down_s: float) -> None:
    await stack.broker.stop()
    await asyncio.sleep(down_s)
    await stack.broker.start()


async def test_broker_restarts_with_m3_pending_and_mid_cut_every_command_runs_once(
    tmp_path: Path,
) -> None:
    options = StackOptions(tmp_path, broker="mosquitto")
    async with Stack(options) as stack:
        client = stack.daemon_client(timeout_s=60.0)
        sending = asyncio.create_task(stack.send(PROGRAM, daemon=client))
        # 1: while the first M3 waits for its answer (touch-off, pierce).
        seen = await wait_for_state(stack, STARTING, 0, 30.0)
        await restart_broker(stack, 1.0)
        # 2: while the second cut is cutting (its M3 answered, motion and M666 to come).
        seen = await wait_for_state(stack, {"idle"}, seen, 60.0)
        seen = await wait_for_state(stack, {"cutting"}, seen, 60.0)
        await restart_broker(stack, 0.5)
        report = await asyncio.wait_for(sending, 120.0)
        result = await stack.finish(report)
    summary = summarize(result, options.telemetry_hz)
    assert report.ok, report.error
    assert report.cuts_started == 3
    assert summary["pierces"] == 3  # on the mock board: no M3 lost, none run twice
    assert summary["completed_cuts"] == 3
    assert summary["safety_violations"] == 0
    # Every plasma command of the program executed once: T112 M6, G200, and per cut M3,
    # M667, M666, M5 (the daemon's answers counted by the sender, the pierces by the board).
    assert report.plasma_commands == 2 + 4 * 3
    print(json.dumps({"broker_restart": {
        "program_plasma_commands": 2 + 4 * 3, "executed": report.plasma_commands,
        "pierces_on_board": summary["pierces"], "reconnects": client.reconnects,
        "republished": client.republished, "outages_s": client.outages_s}}))  # fmt: skip
    assert client.reconnects == 2
    assert client.republished >= 1  # at least the pending M3 went again
    assert summary["torch_on_at_exit"] is False
