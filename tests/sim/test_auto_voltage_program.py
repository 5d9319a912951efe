"""Auto voltage in a program of the form a SheetCAM MASSO post writes (``G200 ... V0``): a
bracket's profile and a 30 mm hole at half its feed, on the noisy cutter, run by the
reference sender against the daemon's controller service in simulated time
(dthc_tools/sim/program.py). The program is not in tests/programs: those run in every
dialect and in real time, and this one is about the THC's target, not the dialects."""

from __future__ import annotations

from pathlib import Path

from dthc_bridge.controller.dialect import Dialect
from dthc_tools.sim.program import run_program

PROGRAM = Path(__file__).with_name("masso_auto_volts_bracket.nc")


def test_a_small_holes_auto_voltage_holds_the_cut_height(tmp_path: Path) -> None:
    """noisy_hf_start seed 10: the hole's 0.3 s fit window covers 6.6 mm of arc, 20 mm in;
    with a slope taken at 2 standard errors its noise passed for a plate slope and the
    target came out 0.6 V low (the hole's RMS 0.070 mm, max 0.105). Both cuts now within
    0.02 mm RMS, no dive, no safety violation, the torch off at the end."""
    lines = PROGRAM.read_text().splitlines()
    result = run_program(lines, tmp_path, dialect=Dialect.MASSO, scenario="noisy_hf_start", seed=10)
    assert result.report.ok, result.report.error
    cuts = result.mock_exit["cuts"]
    assert len(cuts) == 2
    assert all(cut["dives"] == 0 and cut["touches"] == 0 for cut in cuts), cuts
    assert all(cut["height_rms_error_mm"] < 0.02 for cut in cuts), cuts
    assert result.mock_exit["violations"] == {}
    assert result.mock_exit["torch_on"] is False
