"""End to end: mosquitto, the daemon process, the mock process on a pty and the sender."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dthc_tools.demo import Stack, StackOptions, program_lines
from dthc_tools.demo.summary import summarize
from dthc_tools.procs import die_with_parent
from tests.e2e.test_broker_restart import wait_for_state

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


async def run(program: str, scenario: str, tmp_path: Path, **options: object) -> dict[str, object]:
    stack_options = StackOptions(tmp_path, scenario=scenario, broker="mosquitto", **options)  # type: ignore[arg-type]
    async with Stack(stack_options) as stack:
        report = await stack.send(program_lines(program))
        result = await stack.finish(report)
    return summarize(result, stack_options.telemetry_hz)


def assert_clean(
    summary: dict[str, object], cuts: int, rms_mm: float, max_mm: float | None = None
) -> None:
    """Every cut completed within ``rms_mm`` (and ``max_mm``), no violation, clean exit."""
    assert summary["errors"] == [], summary["errors"]
    assert summary["safety_violations"] == 0
    assert summary["pierces"] == cuts
    assert summary["completed_cuts"] == cuts
    assert isinstance(summary["height_rms_mm"], float)
    assert summary["height_rms_mm"] < rms_mm
    if max_mm is not None:
        assert isinstance(summary["height_max_err_mm"], float)
        assert summary["height_max_err_mm"] < max_mm
    assert summary["daemon_exit_code"] == 0
    assert summary["torch_on_at_exit"] is False


async def test_masso_sample_on_a_warped_sheet(tmp_path: Path) -> None:
    """The seed's MASSO program: two cuts, held within 0.5 mm, no violation, clean exit."""
    assert_clean(await run("masso_sample", "masso_warped", tmp_path), 2, 0.15, 0.5)


async def test_rosetta_g100_program(tmp_path: Path) -> None:
    """G100 P4/P5/P6/P7/P0: two probed-and-started cuts on a warped sheet."""
    summary = await run("rosetta_g100", "warped_sheet", tmp_path)
    assert_clean(summary, 2, 0.2, 0.6)
    sender = summary["sender"]
    assert isinstance(sender, dict)
    assert sender["resume_points"] == [6, 16]


async def test_holes_and_corners_with_velocity_reduction(tmp_path: Path) -> None:
    """Sharp corners and two holes at 60 % feed (M67 E3): no dive, THC locked in the holes."""
    summary = await run("holes_corners", "flat_clean", tmp_path)
    assert_clean(summary, 3, 0.15, 0.5)
    cuts = summary["cuts"]
    assert isinstance(cuts, list)
    assert all(cut["dives"] == 0 for cut in cuts)
    assert cuts[1]["thc_locked_s"] > cuts[1]["thc_active_s"]  # a hole: mostly locked


async def test_arc_lost_pauses_the_program_and_reports_the_resume_point(tmp_path: Path) -> None:
    """An arc lost mid-cut stops the sender with the error and the P0 line to resume from."""
    summary = await run("rosetta_g100", "arc_lost_midcut", tmp_path)
    sender = summary["sender"]
    assert isinstance(sender, dict)
    assert not sender["ok"]
    assert "arc lost" in sender["error"]
    assert sender["resume_from"] == 6
    assert summary["safety_violations"] == 0
    assert summary["torch_on_at_exit"] is False


async def test_a_daemon_killed_mid_cut_stops_the_sender_at_once(tmp_path: Path) -> None:
    """SIGKILL the daemon mid-cut: its will turns availability offline, the sender holds
    motion and stops the program within seconds, naming why (it waited for its request's
    timeout before); the board's lease has turned the torch off."""
    options = StackOptions(tmp_path, scenario="masso_warped", broker="mosquitto")
    async with Stack(options) as stack:
        sending = asyncio.create_task(stack.send(program_lines("masso_sample")))
        for _ in range(600):
            if any(point.get("state") == "cutting" for point in stack.telemetry):
                break
            await asyncio.sleep(0.05)
        assert stack.daemon is not None
        stack.daemon.kill()
        killed_s = time.monotonic()
        report = await asyncio.wait_for(sending, 30)
        stopped_after_s = time.monotonic() - killed_s
        result = await stack.finish(report)
    assert not report.ok
    assert "the daemon went offline" in report.error
    assert stopped_after_s < 5.0, stopped_after_s
    assert result.mock_exit["torch_on"] is False
    assert result.mock_exit["unsafe_torch_ms"] == 0
    assert result.mock_exit["violations"] == {}


async def test_a_sender_killed_mid_cut_ends_the_cut_by_its_will(tmp_path: Path) -> None:
    """SIGKILL the sender (its own process) mid-cut: with the daemon's default
    sender_will_topic the sender's will ends the cut through the fault path; the torch
    does not burn on at a standstill waiting for an M5 that never comes."""
    options = StackOptions(tmp_path, scenario="masso_warped", broker="mosquitto")
    program = tmp_path / "part.nc"
    program.write_text("\n".join(program_lines("masso_sample")) + "\n")
    async with Stack(options) as stack:
        with (tmp_path / "sender.log").open("w") as log:
            sender = subprocess.Popen(  # noqa: ASYNC220 - started once, killed below
                [sys.executable, "-m", "dthc_bridge", "send", str(program),
                 "--broker", f"mqtt://127.0.0.1:{stack.broker.port}", "--base-topic",
                 stack.base, "--gantry", f"socket://127.0.0.1:{stack.gantry_port}"],
                stdout=log, stderr=subprocess.STDOUT, preexec_fn=die_with_parent(),
            )  # fmt: skip
            try:
                await wait_for_state(stack, {"cutting"}, 0, 40.0)
                await asyncio.sleep(0.5)
                sender.kill()
                killed_at = stack.telemetry[-1]["t"]
                ended = await wait_for_state(stack, {"faulted"}, len(stack.telemetry) - 1, 5.0)
            finally:
                sender.kill()
                sender.wait(5)
        ended_after_s = stack.telemetry[ended]["t"] - killed_at
        result = await stack.finish()
    faults = [e for e in result.events if e.get("type") == "fault" or e.get("type") == "pause"]
    assert any("sender lost" in str(e.get("reason")) for e in faults), faults
    print(f'{{"sender_killed_cut_ended_after_s": {ended_after_s:.3f}}}')
    assert ended_after_s < 1.0, ended_after_s  # the will arrives as the connection drops
    assert result.mock_exit["torch_on"] is False
    assert result.mock_exit["unsafe_torch_ms"] == 0
