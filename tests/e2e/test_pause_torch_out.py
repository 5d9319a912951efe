"""docs/DESIGN.md invariant 7 end to end: a pause from the panel's route (a request on
``sender/request/pause``, as the panel's Pause button sends it) puts the torch out, and
cycle start resumes the cut where the torch stands, which finishes the program.

Measured: from the pause request to the relay off. On the mock, as the board reports its
relay (the TORCH_ON status bit in its batches, through the daemon's telemetry at 50 Hz:
an upper bound by one telemetry period and the broker hop); on the emulated Mega, at the
relay pin itself (the harness's record, on the host's monotonic clock)."""

from __future__ import annotations

import asyncio
import io
import itertools
import json
import time
from pathlib import Path
from typing import Any

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize
from dthc_tools.emulated_board import read_record
from dthc_tools.sender import Sender
from dthc_tools.sender.console import OperatorConsole
from dthc_tools.sender.grbl_backend import GrblBackend
from dthc_tools.sender.remote import OperatorRemote
from dthc_tools.sender.sender import SendReport
from tests.e2e.test_emulated_board import emulated_stack, relay_intervals

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

PROGRAM = [
    "G21 G90", "T112 M6", "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S0",
    "G0 X20 Y40", "M3", "G1 X220 Y40 F1500", "M5", "G0 X0 Y0", "M30",
]  # fmt: skip
PAUSE_AFTER_CUTTING_S = 2.0


async def pause_mid_cut_and_resume(stack: Stack) -> tuple[SendReport, float, list[str]]:
    """The program under a sender with its console and its panel route; once the daemon
    has cut for PAUSE_AFTER_CUTTING_S, a panel client asks the sender to pause; once the
    program is paused, to cycle start. The report, the pause's monotonic time, messages."""
    daemon, panel = stack.daemon_client(), stack.daemon_client(role="panel")
    panel.on_topic("sender/response/+", panel.answer)
    backend = stack.motion_backend()
    if isinstance(backend, GrblBackend):
        await backend.connect()
    sender = Sender(daemon, backend)
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False, wait_operator=True)
    OperatorRemote(sender, daemon, program="part.nc", console=console)  # subscribes first
    async with daemon.connected(), panel.connected():
        job = asyncio.create_task(console.run_job(PROGRAM))
        try:
            while sequence_state(stack) != "cutting":  # noqa: ASYNC110 - polls its events
                await asyncio.sleep(0.02)
            await asyncio.sleep(PAUSE_AFTER_CUTTING_S)
            paused_at = time.monotonic()
            await panel.request_to("sender", "pause")
            while console.paused is None:  # noqa: ASYNC110 - polls the console
                await asyncio.sleep(0.05)
            await panel.request_to("sender", "cycle_start")  # resume here
            report = await asyncio.wait_for(job, 90.0)
        finally:
            job.cancel()
            await backend.close()
    return report, paused_at, console.messages


def sequence_state(stack: Stack) -> str:
    states = [e["state"] for e in stack.events if e.get("type") == "sequence"]
    return states[-1] if states else "idle"


def first_off_after(telemetry: list[dict[str, Any]], t: float) -> float:
    """When the daemon's telemetry first showed the board's relay off after ``t``."""
    return float(
        next(d["received_s"] for d in telemetry if d["received_s"] > t and not d["torch_on"])
    )


async def test_a_pause_from_the_panel_puts_the_torch_out_on_the_mock(tmp_path: Path) -> None:
    options = StackOptions(tmp_path, broker="mosquitto", telemetry_hz=50.0)
    async with Stack(options) as stack:
        report, paused_at, messages = await pause_mid_cut_and_resume(stack)
        off_at = first_off_after(list(stack.telemetry), paused_at)
        result = await stack.finish(report)
    assert report.ok, (report.error, messages)
    assert report.cuts_started == 1  # one cut, resumed where it stopped
    off_ms = (off_at - paused_at) * 1000
    assert off_ms < 500, off_ms  # a feed hold takes longer than this to stop the gantry
    rows = [json.loads(line) for line in result.truth_path.read_text().splitlines()]
    # The torch was lit twice (the cut, then its resume) and was never lit standing still
    # for long: the pause is not a lit dwell.
    burns = sum(1 for a, b in itertools.pairwise(rows) if b["torch_on"] and not a["torch_on"])
    assert burns == 2, burns
    assert max(r["x_mm"] for r in rows if r["torch_on"]) == pytest.approx(220.0, abs=1.0)
    assert summarize(result, options.telemetry_hz)["safety_violations"] == 0
    print(json.dumps({"pause_to_relay_off_ms": {"mock_via_telemetry": round(off_ms, 1)}}))


async def test_a_pause_from_the_panel_puts_the_relay_off_on_the_emulated_mega(
    tmp_path: Path,
) -> None:
    async with Stack(emulated_stack(tmp_path)) as stack:
        report, paused_at, messages = await pause_mid_cut_and_resume(stack)
        result = await stack.finish(report)
    assert report.ok, (report.error, messages)
    assert result.daemon_exit_code == 0
    relay = relay_intervals(read_record(stack.board_record))
    assert len(relay) == 2, relay  # the cut up to the pause, then from the resume
    first_off = relay[0][1]
    assert first_off is not None
    assert first_off > paused_at
    off_ms = (first_off - paused_at) * 1000
    assert off_ms < 500, off_ms
    print(json.dumps({"pause_to_relay_off_ms": {"emulated_mega_pin": round(off_ms, 1)}}))


async def test_a_new_run_drops_the_hold_and_queue_a_killed_sender_left(tmp_path: Path) -> None:
    """A sender killed mid-program leaves the gantry held with its lines queued; the next
    sender's run does not sit waiting for a cycle start: it drops both and runs."""
    async with Stack(StackOptions(tmp_path, broker="mosquitto")) as stack:
        dead = stack.motion_backend()
        await dead.queue("G1 X300 Y300 F600")  # the dead sender's line, never to run
        await dead.hold()
        await dead.close()
        report = await asyncio.wait_for(stack.send(PROGRAM), 60.0)
        result = await stack.finish(report)
    assert report.ok, report.error
    rows = [json.loads(line) for line in result.truth_path.read_text().splitlines()]
    assert max(r["y_mm"] for r in rows) < 41.0  # the dead sender's line never ran
