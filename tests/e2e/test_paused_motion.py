"""PlasmaC's paused motion and cut recovery end to end: the daemon, the mock board,
mosquitto (and the emulated grbl) as processes, the sender with its operator console in
this process.

The mock's truth (where the arc really burned) is the judge: after an arc lost mid-part,
reverse 20 mm and resume, the part is finished and the second burn overlaps the first;
forward through a cut to the next one, the skipped cut is never burned; a cut recovery
offset pierces beside the path and the torch travels back onto it."""

from __future__ import annotations

import asyncio
import io
import json
import math
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize
from dthc_tools.sender import Sender
from dthc_tools.sender.backend import BackendError
from dthc_tools.sender.console import OperatorConsole
from dthc_tools.sender.grbl_backend import GrblBackend
from dthc_tools.sender.sender import SendReport
from mock_device.plant.arc import ArcState

pytestmark = [pytest.mark.slow, pytest.mark.timeout(150)]

HEAD = ["G21 G90", "T112 M6", "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S0"]
PART = [  # one cut at y=100 (the arc is lost in it), then a second one at y=200
    "G0 X50 Y100", "M3", "M667 F600", "G1 X300 Y100 F3000", "M666", "M5",
    "G0 X300 Y200", "M3", "G1 X250 Y200 F3000", "M5", "G0 X0 Y0", "M30",
]  # fmt: skip
THREE_CUTS = [
    "G0 X50 Y100", "M3", "G1 X200 Y100 F3000", "M5",
    "G0 X50 Y150", "M3", "G1 X200 Y150 F3000", "M5",
    "G0 X50 Y200", "M3", "G1 X200 Y200 F3000", "M5", "G0 X0 Y0", "M30",
]  # fmt: skip

Operator = Callable[[OperatorConsole], Awaitable[None]]


async def run_with_operator(
    stack: Stack, lines: list[str], operator: Operator
) -> tuple[SendReport, list[str]]:
    """The program under an operator console that waits after an error; ``operator`` acts
    once the program is paused."""
    daemon = stack.daemon_client()
    backend = stack.motion_backend()
    if isinstance(backend, GrblBackend):
        await backend.connect()
    async with daemon.connected():
        sender = Sender(daemon, backend, auto_cycle_start=True)
        console = OperatorConsole(sender, out=io.StringIO(), interactive=False,
                                  wait_operator=True)  # fmt: skip
        job = asyncio.create_task(console.run_job(lines))
        try:
            await operator(console)
            report = await asyncio.wait_for(job, 90.0)
        finally:
            job.cancel()
            await backend.close()
    return report, console.messages


async def until_paused(console: OperatorConsole, timeout_s: float = 40.0) -> dict[str, Any]:
    for _ in range(int(timeout_s / 0.05)):
        if console.paused is not None and console.sender.progress.paused_at:
            return console.sender.progress.paused_at
        await asyncio.sleep(0.05)
    raise AssertionError(f"the program never paused: {console.messages}")


def burns(truth: Path, y: float) -> list[tuple[float, float]]:
    """Each span of transferred arc along the line y, as (x start, x end)."""
    spans: list[tuple[float, float]] = []
    burning = False
    for line in truth.read_text().splitlines():
        row = json.loads(line)
        on = row["arc_state"] == ArcState.TRANSFERRED and abs(row["y_mm"] - y) < 0.5
        if on and not burning:
            spans.append((row["x_mm"], row["x_mm"]))
        elif on:
            spans[-1] = (spans[-1][0], row["x_mm"])
        burning = on
    return spans


async def test_arc_lost_mid_part_reverse_20_mm_and_resume_overlaps_the_lost_section(
    tmp_path: Path,
) -> None:
    """Through the grbl backend: X and Y on the emulated grbl (its own process on a pty),
    mirrored into the mock's plant."""
    options = StackOptions(tmp_path, scenario="arc_lost_midcut", broker="mosquitto",
                           telemetry_hz=10.0, motion="grbl")  # fmt: skip
    seen: dict[str, Any] = {}

    async def operator(console: OperatorConsole) -> None:
        seen["stopped"] = await until_paused(console)
        seen["moved"] = await console.act("path_move", mm=-20.0, feed_mm_min=1200)
        await console.act("resume")

    async with Stack(options) as stack:
        report, messages = await run_with_operator(stack, HEAD + PART, operator)
        result = await stack.finish(report)
    assert report.ok, (report.error, messages)
    stopped, moved = seen["stopped"], seen["moved"]
    assert stopped["line"] == 7  # the long cut's G1
    assert moved["x_mm"] == pytest.approx(stopped["x_mm"] - 20.0, abs=0.05)
    first, second = burns(result.truth_path, 100.0)
    # The arc went out at first[1]; the second burn starts 20 mm behind where the torch
    # stopped, so the cut overlaps the section lost, and goes on to the end of the part.
    assert second[0] < first[1] - 5.0
    assert second[1] == pytest.approx(300.0, abs=1.0)
    assert burns(result.truth_path, 200.0)  # the second cut ran too
    assert summarize(result, options.telemetry_hz)["safety_violations"] == 0
    print(json.dumps({"paused_motion": {"arc_lost_at_x": round(first[1], 2),
                      "stopped_at_x": stopped["x_mm"], "resumed_at_x": moved["x_mm"],
                      "overlap_mm": round(first[1] - second[0], 2)}}))  # fmt: skip


async def test_forward_through_a_cut_to_the_next_then_recover_beside_the_path(
    tmp_path: Path,
) -> None:
    """Paused by the operator in cut 1 (feed hold): the daemon ends the cut where the
    torch stands (torch out, raised: invariant 7), then the torch goes forward past the
    whole of cut 2 into cut 3, then a cut recovery offset; the resume pierces beside the
    path, travels back onto it and finishes cut 3; cut 2 is never burned. A reverse past
    cut 3's start, an offset beyond the bound and a path move while off the path are
    refused with the reason."""
    options = StackOptions(tmp_path, broker="mosquitto", telemetry_hz=10.0)
    seen: dict[str, Any] = {}

    async def operator(console: OperatorConsole) -> None:
        while console.telemetry.get("state") != "cutting":  # noqa: ASYNC110 - polls telemetry
            await asyncio.sleep(0.05)
        await asyncio.sleep(1.5)
        await console.sender.pause()  # mid-cut: the daemon puts the torch out and raises it
        stopped = await console.act("path_move", mm=1.0)  # once the program has stopped
        # The rest of cut 1, the rapid to cut 2, cut 2, the rapid to cut 3, 50 mm into it.
        rapid = math.hypot(150.0, 50.0)
        ahead = (200.0 - stopped["x_mm"]) + rapid + 150.0 + rapid + 50.0
        seen["moved"] = await console.act("path_move", mm=ahead, feed_mm_min=6000)
        with pytest.raises(BackendError, match=r"only 50.0 mm of this cut lie behind"):
            await console.act("path_move", mm=-60.0)
        with pytest.raises(BackendError, match="beyond the 10 mm cut recovery allows"):
            await console.act("recovery_offset", x_mm=0.0, y_mm=12.0)
        seen["offset"] = await console.act("recovery_offset", x_mm=-3.0, y_mm=4.0)
        with pytest.raises(BackendError, match="set the offset back to 0 first"):
            await console.act("path_move", mm=-5.0)
        await console.act("resume")

    async with Stack(options) as stack:
        report, messages = await run_with_operator(stack, HEAD + THREE_CUTS, operator)
        result = await stack.finish(report)
    assert report.ok, (report.error, messages)
    assert seen["moved"]["cut"] == 3
    assert seen["moved"]["x_mm"] == pytest.approx(100.0, abs=0.05)
    assert seen["offset"]["offset_mm"] == [-3.0, 4.0]
    assert burns(result.truth_path, 150.0) == []  # cut 2 skipped: never burned
    rows = [json.loads(line) for line in result.truth_path.read_text().splitlines()]
    third = [r for r in rows if r["arc_state"] == ArcState.TRANSFERRED and r["y_mm"] > 190.0]
    # Pierced at the offset point (3 mm back, 4 mm up), then back onto the path at y=200.
    assert third[0]["x_mm"] == pytest.approx(97.0, abs=0.2)
    assert third[0]["y_mm"] == pytest.approx(204.0, abs=0.2)
    on_path = [r for r in third if abs(r["y_mm"] - 200.0) < 0.05]
    assert on_path[0]["x_mm"] == pytest.approx(100.0, abs=0.5)
    assert max(r["x_mm"] for r in on_path) == pytest.approx(200.0, abs=1.0)
    assert summarize(result, options.telemetry_hz)["safety_violations"] == 0
