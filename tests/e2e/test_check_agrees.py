"""check-program and the machine agree (issue 31): a program of each form in
tests/programs (ON_THE_STACK; all of them, in every dialect, in
tests/sim/test_every_dialect.py), with the options its shop would give (a material
library, its own codes), is checked, then run through the stack (mosquitto, the daemon and
the mock as processes, the reference sender) with the same options and the dialect
detection an owner gets by default. A program the check calls runnable runs every cut it
listed to completion, one row per cut; a program it refuses stops at the line it refused
first. (Whether a cut is good is the program's and the scenario's: a fixed voltage the
sheet does not give makes the THC follow it.)"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize
from dthc_tools.sim.program import run_program

from ..program_shop import NC_NAMES, assert_agree, shop_run

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

# Every program in every dialect runs in simulated time (tests/sim/test_every_dialect.py,
# the demo's own parts without the broker and the processes); here, on the processes, one
# program of each form and each option a shop gives, and that simulated run is checked
# against them: the .nc ones here, the .ngc ones in test_check_agrees_ngc.py (two files,
# so the two test workers share the runs).
ON_THE_STACK = [
    "firecontrol_relay.nc",  # a shop's own codes (M10/M11), relay by detection
    "masso_s1_midway.nc",  # G200 S1: three arc starts, two cuts
    "relay_self_probe.nc",  # its own touch-off, FireControl's THC switching
    "plasmac_material_overcut.ngc",  # a material library, M190 and F#<_hal[...]>
    "plasmac_refusals.ngc",  # refused where the check refuses it
    "sheetcam_plasmac_inch.ngc",  # an inch library
    "sheetcam_tube_plasmac.ngc",  # a tube's temporary material, the float-travel pin
]


def _material_change(summary: dict[str, Any]) -> None:
    """M190 from the library, its feed through F#<_hal[...]>, then a magic-comment material;
    the hole ends with the torch disabled (M62 P3) while motion goes on."""
    cuts = summary["cuts"]
    assert summary["height_rms_mm"] < 0.2
    assert 11.5 < cuts[0]["arc_on_s"] < 14.0  # the library's 3000 mm/min: 600 mm in ~12 s
    assert cuts[1]["arc_on_s"] < 4.0  # the over-cut ran with the torch off


def _inch_library(summary: dict[str, Any]) -> None:
    """G20 beside G92.1, an inch library (M190 P2), the feed read from it: the machine runs
    inches at the material's feed, so the THC takes its target and works."""
    cut = summary["cuts"][0]
    assert 10.0 < cut["arc_on_s"] < 14.0  # 14 in at 80 in/min; run in mm it would crawl
    assert cut["target_v"] == 128.0  # CUT_VOLTS of material 2
    assert cut["thc_active_s"] > 5.0  # at speed, so not held by anti-dive


def _relay(summary: dict[str, Any]) -> None:
    """grbl-style: G38.2 by the board, G92 Z, its own Z moves and dwell, M3 a bare relay,
    FireControl's H1/H0 switching the THC."""
    assert summary["height_rms_mm"] < 0.1
    assert summary["cuts"][0]["thc_active_s"] > 1.0  # H1 switched the THC on


# What a program's own run shows beyond agreeing (each was its own end-to-end test).
DETAILS = {
    "plasmac_material_overcut.ngc": _material_change,
    "sheetcam_plasmac_inch.ngc": _inch_library,
    "relay_self_probe.nc": _relay,
}


@pytest.mark.parametrize("name", [name for name in NC_NAMES if name in ON_THE_STACK])
async def test_what_check_program_calls_runnable_runs_on_the_machine(
    name: str, tmp_path: Path
) -> None:
    await agrees(name, tmp_path)


async def agrees(name: str, tmp_path: Path) -> None:
    """tests/programs/``name``: checked, then run on the stack with the same options and
    the dialect detection an owner gets by default."""
    run = shop_run(name, tmp_path)
    check = run.check()
    options = StackOptions(tmp_path, broker="mosquitto", materials_file=run.library,
                           controller={"materials_in_inches": run.inch})  # fmt: skip
    async with Stack(options) as stack:
        report = await stack.send(run.lines, codes=run.codes)
        result = await stack.finish(report)
    summary = summarize(result, options.telemetry_hz)
    print(json.dumps({name: {"check": "ok" if check.ok else "refused", "cuts": len(check.cuts),
                             "dialect": check.dialect, "ran": report.ok,
                             "completed": summary["completed_cuts"],
                             "height_rms_mm": summary["height_rms_mm"],
                             "violations": summary["safety_violations"]}}))  # fmt: skip
    assert_agree(check, report, summary)
    # The simulated-time run that holds every dialect to the check (tests/sim/
    # test_every_dialect.py) is checked here against the processes: the same verdict,
    # line and cuts, each burning as long within 5 % or 0.25 s (over the broker, each
    # request the arc waits on, an S1 cut's two burns, takes its round trip).
    simulated = await asyncio.to_thread(
        run_program, run.lines, tmp_path / "sim", settings=run.settings(), codes=run.codes
    )
    assert (simulated.report.ok, simulated.report.error_line) == (report.ok, report.error_line)
    burns = [cut["arc_on_s"] for cut in summary["cuts"]]
    simulated_burns = [cut["arc_on_s"] for cut in summarize(simulated, 50.0)["cuts"]]
    assert simulated_burns == pytest.approx(burns, rel=0.05, abs=0.25)
    if check.ok:
        assert summary["daemon_exit_code"] == 0
        if name in DETAILS:
            DETAILS[name](summary)
