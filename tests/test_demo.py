"""The README's main command: the demo runs everything end to end and reports honestly."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dthc_tools.procs import die_with_parent

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


def test_demo_json_runs_the_masso_sample_safely(tmp_path: Path) -> None:
    """`dthc-bridge demo --json`: both MASSO cuts complete, no violation, a plot is written."""
    plot = tmp_path / "demo.png"
    proc = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "demo", "--json", "--plot", str(plot)],
        capture_output=True, text=True, timeout=120, check=False, preexec_fn=die_with_parent(),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads(proc.stdout)
    for key in ("cuts", "completed_cuts", "safety_violations", "height_rms_mm",
                "height_max_err_mm", "errors"):  # fmt: skip
        assert key in summary
    assert len(summary["cuts"]) == 2  # the sample program has two M3
    assert summary["completed_cuts"] == 2
    assert summary["safety_violations"] == 0
    assert summary["errors"] == []
    assert summary["height_rms_mm"] < 0.15
    assert summary["height_max_err_mm"] < 0.5
    assert summary["torch_on_at_exit"] is False
    assert plot.stat().st_size > 10_000


def test_demo_runs_a_g200_s1_program_to_its_end_pressing_cycle_start(tmp_path: Path) -> None:
    """MASSO's stop after pierce: the demo has no operator, so it presses cycle start at each
    stop (``--yes-cycle-start``) and says where; without it the program would wait forever."""
    proc = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "demo", "--json", "--program", "masso_s1",
         "--plot", str(tmp_path / "demo.png")],
        capture_output=True, text=True, timeout=120, check=False, preexec_fn=die_with_parent(),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["cycle_starts"] == [8, 17]  # the two M03 lines of masso_s1.ngc
    assert summary["sender"]["cuts_started"] == 2
    assert summary["sender"]["ok"]
    assert summary["safety_violations"] == 0
    assert summary["torch_on_at_exit"] is False
