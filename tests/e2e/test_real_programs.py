"""Programs in the forms real posts write, end to end: one per dialect through the stack.

mosquitto, the daemon and the mock as their own processes, the reference sender; the
programs are in tests/programs (written for these tests in the forms of
../shared/reference/real-programs.md).
"""

from __future__ import annotations

import asyncio
import shutil
from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_tools.demo import Stack, StackOptions, program_lines
from dthc_tools.demo.summary import summarize

from .test_end_to_end import assert_clean

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

PROGRAMS = Path(__file__).parents[1] / "programs"


async def test_plasmac_program_with_a_material_change_and_a_hole_over_cut(
    tmp_path: Path,
) -> None:
    """M190 from the daemon's library, its feed through F#<_hal[...]>, then a magic-comment
    material; the hole ends with the torch disabled (M62 P3) while motion goes on."""
    materials = tmp_path / "materials.cfg"
    shutil.copyfile(PROGRAMS / "shop_material.cfg", materials)
    options = StackOptions(tmp_path, broker="mosquitto", materials_file=materials)
    async with Stack(options) as stack:
        lines = program_lines(str(PROGRAMS / "plasmac_material_overcut.ngc"))
        report = await stack.send(lines)
        result = await stack.finish(report)
    summary = summarize(result, options.telemetry_hz)
    assert report.dialect == "plasmac"
    assert_clean(summary, 2, 0.2)
    cuts = summary["cuts"]
    assert isinstance(cuts, list)
    # The first cut ran at the library material's feed (3000 mm/min): 600 mm in ~12 s.
    assert 11.5 < cuts[0]["arc_on_s"] < 14.0
    # The hole's over-cut ran with the torch off: the arc went out before the path ended.
    assert cuts[1]["arc_on_s"] < 4.0


async def test_sheetcam_inch_program_with_an_inch_material_library(tmp_path: Path) -> None:
    """G20 in a preamble beside G92.1, an inch library (M190 P2), the feed read from it: the
    machine runs inches at the material's feed, so the THC takes its target and works."""
    materials = tmp_path / "materials.cfg"
    shutil.copyfile(PROGRAMS / "shop_material_inch.cfg", materials)
    options = StackOptions(
        tmp_path, broker="mosquitto", materials_file=materials,
        controller={"materials_in_inches": True},
    )  # fmt: skip
    async with Stack(options) as stack:
        report = await stack.send(program_lines(str(PROGRAMS / "sheetcam_plasmac_inch.ngc")))
        result = await stack.finish(report)
    summary = summarize(result, options.telemetry_hz)
    assert report.dialect == "plasmac"
    assert summary["errors"] == [], summary["errors"]
    assert summary["safety_violations"] == 0
    assert summary["completed_cuts"] == 2
    cuts = summary["cuts"]
    assert isinstance(cuts, list)
    # 4 + 3 + 4 + 3 inches at 80 in/min: 10.5 s with the pierce; run in mm it would crawl.
    assert 10.0 < cuts[0]["arc_on_s"] < 14.0
    assert cuts[0]["target_v"] == 128.0  # CUT_VOLTS of material 2
    assert cuts[0]["thc_active_s"] > 5.0  # at speed, so not held by anti-dive


async def test_relay_program_probes_and_moves_z_itself(tmp_path: Path) -> None:
    """grbl-style: G38.2 by the board, G92 Z, its own Z moves and dwell, M3 a bare relay,
    FireControl's H1/H0 switching the THC."""
    options = StackOptions(tmp_path, broker="mosquitto")
    async with Stack(options) as stack:
        report = await stack.send(program_lines(str(PROGRAMS / "relay_self_probe.nc")))
        result = await stack.finish(report)
    summary = summarize(result, options.telemetry_hz)
    assert report.dialect == "relay"
    assert_clean(summary, 1, 0.1)
    cuts = summary["cuts"]
    assert isinstance(cuts, list)
    assert cuts[0]["thc_active_s"] > 1.0  # H1 switched the THC on


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
