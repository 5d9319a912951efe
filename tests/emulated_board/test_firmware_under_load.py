"""The reference firmware on the emulated Mega and Nano while the machine is loaded: the
conformance check ``telemetry_gaps`` (no SAMPLES batch lost under 200 STATUS queries) passes
beside a CPU hog, as on a CI machine or a shop PC that shares its cores.

The emulated board falls behind the wall clock under load and catches up flat out; host
bytes then arrive bunched, and the board must still answer every query without losing a
batch. The round-trip and host-clock rate checks measured in the same window judge the
host's scheduling as much as the board, so only ``telemetry_gaps`` is asserted here.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from dthc_tools.emulated_board import EmulatedBoard, HarnessOptions, ensure_built

from .conformance_run import run_conformance

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

HOG = "while True: pass"


@pytest.fixture
def cpu_hog() -> Iterator[None]:
    """A process that keeps one core busy for the test's length."""
    hog = subprocess.Popen([sys.executable, "-c", HOG])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()


@pytest.mark.parametrize("mcu", ["atmega2560", "atmega328p"])
def test_telemetry_gaps_passes_beside_a_cpu_hog(
    built: Path, tmp_path: Path, mcu: str, cpu_hog: None
) -> None:
    """No SAMPLES batch lost (no stream_seq gap, no SAMPLE_OVERFLOW) in the conformance
    suite's telemetry window while another process keeps a core busy."""
    ensure_built(built, firmware=True)
    options = HarnessOptions(
        mcu=mcu, record=tmp_path / "record.csv", build=False, stderr=tmp_path / "host.log"
    )
    with EmulatedBoard(tmp_path / "board.pty", options) as board:
        report = run_conformance(board, only=("telemetry_gaps",))
    gaps = next(c for c in report["checks"] if c["name"] == "telemetry_gaps")
    print(gaps["figure"])
    assert gaps["passed"] is True
