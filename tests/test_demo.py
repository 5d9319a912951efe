"""The README's main command: the demo runs end to end against the mock board process."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow


def test_demo_json_reports_a_safe_bring_up() -> None:
    """Touch-off finds the plate where the plant has it; an unplug drops the torch by lease."""
    proc = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "demo", "--json"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["passed"] is True
    assert summary["touch_off"]["result"] == "CONTACT"
    assert abs(summary["touch_off"]["contact_z_mm"] - 20.0) < 0.1  # flat_clean plate top
    assert summary["telemetry"]["samples_per_s"] > 900
    assert summary["unplug"]["torch_on_before"] is True
    assert summary["unplug"]["torch_on_after"] is False
    assert summary["link"]["timeouts"] == 0
