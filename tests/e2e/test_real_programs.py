"""Programs in the forms real posts write, end to end, beyond what test_check_agrees runs
for every program in tests/programs: an operator's cycle start at an S1 stop.

mosquitto, the daemon and the mock as their own processes, the reference sender; the
programs are in tests/programs (written for these tests in the forms of
../shared/reference/real-programs.md).
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_tools.demo import Stack, StackOptions, program_lines
from dthc_tools.demo.summary import summarize

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

PROGRAMS = Path(__file__).parents[1] / "programs"


async def test_masso_program_stops_after_pierce_midway_and_goes_on_at_cycle_start(
    tmp_path: Path,
) -> None:
    """A G200 change to S1 mid-program: the second M3 waits at the pierce, raised, until
    the operator's cycle start; then the cut runs."""
    options = StackOptions(tmp_path, scenario="flat_clean", broker="mosquitto")
    async with Stack(options) as stack:
        lines = program_lines(str(PROGRAMS / "masso_s1_midway.nc"))
        sending = asyncio.create_task(
            stack.send(lines, dialect=Dialect.MASSO, auto_cycle_start=False)
        )
        async with asyncio.timeout(60):
            while not any(e.get("cause") == "stop_after_pierce" for e in stack.events):
                assert not sending.done(), sending.result()
                await asyncio.sleep(0.05)
        await asyncio.sleep(0.5)
        assert not sending.done()  # the sender waits for the operator
        await stack.request("cycle_start")
        report = await sending
        result = await stack.finish(report)
    summary = summarize(result, options.telemetry_hz)
    assert report.ok, report.error
    assert summary["errors"] == [], summary["errors"]
    assert summary["safety_violations"] == 0
    # The S1 cut lit twice (its pierce, then the relight after cycle start): three arc
    # starts, two cuts, one row each, the THC's figures on the cut they belong to.
    assert summary["pierces"] == 3
    assert summary["completed_cuts"] == 2
    cuts = summary["cuts"]
    assert isinstance(cuts, list)
    assert len(cuts) == 2
    assert all(cut["thc_active_s"] > 0.5 for cut in cuts), cuts
    assert summary["torch_on_at_exit"] is False
