"""The Mega 2560 firmware's voltage-to-frequency build (``make -C firmware`` builds
build/atmega2560-vtof): the arc voltage from a THCAD-type card on T5 (D47), counted by
Timer5, here driven by the emulated board's card model (``--arc-input vtof``: a square wave
whose frequency follows the arc voltage, 121 kHz at 0 V to 925 kHz at 10 V = 500 V of arc
behind the 1:50 divider).

What SAMPLES report against the model: the cut voltage at cut height, and a 1 mm height
change by the model's 7.5 V/mm; then the conformance suite against the vtof ELF. One board
for the module (the card model's own rate and its refusals use the self-test program).
The firmware's resolution is 0.62 V of arc per count at 1 kHz (804 counts from 0 V to full
scale per sample); a median over 200 samples is within a few tenths.
"""

from __future__ import annotations

import statistics
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

import firmware_protocol as fp
from dthc_tools.emulated_board import (
    EmulatedBoard,
    HarnessOptions,
    ensure_built,
    host_binary,
    selftest_elf,
)

from .conformance_run import run_conformance
from .frame_link import FrameLink

pytestmark = pytest.mark.slow

PLATE_MM = 20.0
CUT_HEIGHT_MM = 1.5  # the model's defaults: cut_v at cut height, slope per mm
CUT_V = 116.0
SLOPE_V_MM = 7.5
N_SAMPLES = 200
# SAMPLES' median vs the model's noise-free voltage: the count step (0.62 V) and the noise
# (0.4 V sigma, held 104 us) leave a median within a few tenths; 1.5 V is the budget.
MEDIAN_TOLERANCE_V = 1.5
# A 1 mm step measured as the difference of two medians (each within a count or so).
SLOPE_TOLERANCE_V = 1.0


@pytest.fixture(scope="module")
def vtof_board(built: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[EmulatedBoard]:
    """The vtof ELF on the Mega, its T5 pin driven by the card model."""
    ensure_built(built, firmware=True)
    tmp = tmp_path_factory.mktemp("vtof")
    options = HarnessOptions(
        arc_input="vtof", record=tmp / "record.csv", build=False, stderr=tmp / "host.log",
        model={"plate-mm": PLATE_MM},
    )  # fmt: skip
    with EmulatedBoard(tmp / "board.pty", options) as board:
        yield board


def model_v(board: EmulatedBoard) -> float:
    """The model's noise-free arc voltage for the tip's height now."""
    s = board.status()
    height_mm = s.z_um / 1000 - float(s.fields["surface_mm"])
    return CUT_V + SLOPE_V_MM * (height_mm - CUT_HEIGHT_MM)


def arc_samples(link: FrameLink, n: int) -> list[float]:
    """The next ``n`` samples (volts) from batches that report ARC_OK."""
    mark = len(link.received)
    deadline = time.monotonic() + 5.0
    volts: list[float] = []
    while len(volts) < n and time.monotonic() < deadline:
        link.pump(0.02)
        batches = link.reports(fp.Samples, mark)
        mark += len(link.received[mark:])
        volts += [
            cv / 100 for b in batches if b.inputs & (1 << fp.InputBit.ARC_OK)
            for cv in b.samples_cv
        ]  # fmt: skip
    assert len(volts) >= n, f"only {len(volts)} samples with ARC_OK in 5 s"
    return volts[:n]


def test_samples_follow_the_model_at_cut_height_and_a_1mm_step(vtof_board: EmulatedBoard) -> None:
    """The tip at cut height (1.5 mm) over the plate, torch lit, the arc transferred: the
    median of 200 SAMPLES is within 1.5 V of the model's cut voltage; 1 mm higher, the
    median rises by the model's 7.5 V/mm within 1 V. The status line says the host drives
    the card (arc_input=vtof) at the frequency the voltage gives."""
    board = vtof_board
    board.command(f"z {PLATE_MM + CUT_HEIGHT_MM}")  # by hand: the firmware's Z is not used
    link = FrameLink(board.pty)
    try:
        link.hello()
        link.expect(lambda s: fp.SetLease(s, 2000), fp.Ack)
        if faults := link.status().faults:
            link.expect(lambda s: fp.FaultReset(s, faults), fp.Ack)
        link.expect(lambda s: fp.Torch(s, True), fp.Ack)
        link.run_for(0.3)  # pilot, transfer after 100 ms, the filters settle
        status = board.status()
        assert status.arc == "transferred"
        assert status.fields["arc_input"] == "vtof"
        # 116 V / 50 = 2.32 V on the card: 121 kHz + 804 kHz * 0.232 = 307.5 kHz, +- noise.
        assert abs(float(status.fields["vtof_hz"]) - 307_528) < 2_000
        expected_cut = model_v(board)
        at_cut = statistics.median(arc_samples(link, N_SAMPLES))
        board.command(f"z {PLATE_MM + CUT_HEIGHT_MM + 1.0}")
        link.run_for(0.02)
        expected_up = model_v(board)
        up = statistics.median(arc_samples(link, N_SAMPLES))
        link.expect(lambda s: fp.Torch(s, False), fp.Ack)
    finally:
        link.close()
        board.command("z 60")  # back where the firmware thinks Z is
    print(
        {
            "vtof_median_at_cut_v": at_cut,
            "model_at_cut_v": expected_cut,
            "vtof_median_1mm_up_v": up,
            "model_1mm_up_v": expected_up,
        }
    )
    assert expected_cut == pytest.approx(CUT_V, abs=0.01)
    assert abs(at_cut - expected_cut) <= MEDIAN_TOLERANCE_V, (at_cut, expected_cut)
    assert abs(up - expected_up) <= MEDIAN_TOLERANCE_V, (up, expected_up)
    assert abs((up - at_cut) - SLOPE_V_MM) <= SLOPE_TOLERANCE_V, up - at_cut


def test_the_conformance_suite_passes_against_the_vtof_firmware(
    vtof_board: EmulatedBoard,
) -> None:
    """Every conformance check passes against the Mega's vtof ELF (SIGUSR2 for the reset)."""
    board = vtof_board
    started = time.monotonic()
    report = run_conformance(board)
    print({"conformance_checks": len(report["checks"]), "s": time.monotonic() - started})
    # The suite reset the MCU (SIGUSR2): the card's edges kept coming after it.
    before = board.status()
    time.sleep(0.05)
    after = board.status()
    assert int(before.fields["reboots"]) >= 1
    assert int(after.fields["vtof_edges"]) > int(before.fields["vtof_edges"])


def test_the_card_model_runs_at_its_zero_volt_frequency_and_the_nano_refuses_it(
    built: Path, tmp_path: Path
) -> None:
    """The host alone (the self-test program, torch off: 0 V): T5's rising edges come at
    the card's 121 kHz in simulated time; the 328P (T1 is OHMIC) and a card whose full-scale
    frequency is not above its zero are refused with exit status 2."""
    options = HarnessOptions(
        elf=selftest_elf(built, "atmega2560"), arc_input="vtof", build=False,
        stderr=tmp_path / "host.log",
    )  # fmt: skip
    with EmulatedBoard(tmp_path / "board.pty", options) as board:
        first = board.status()
        time.sleep(0.3)
        last = board.status()
    edges = int(last.fields["vtof_edges"]) - int(first.fields["vtof_edges"])
    rate_hz = edges / ((last.t_us - first.t_us) / 1e6)
    assert rate_hz == pytest.approx(121_000, rel=2e-3), rate_hz
    host = str(host_binary(built))
    for extra, reason in (
        (["--mcu", "atmega328p"], "no V-to-F input"),
        (["--vtof-full-hz", "100000"], "--vtof-full-hz"),
    ):
        elf = selftest_elf(built, "atmega328p" if "atmega328p" in extra else "atmega2560")
        done = subprocess.run(
            [host, "--elf", str(elf), "--pty", str(tmp_path / "p"), "--arc-input", "vtof", *extra],
            capture_output=True, text=True, timeout=10, check=False, stdin=subprocess.DEVNULL,
        )  # fmt: skip
        assert done.returncode == 2, done
        assert reason in done.stderr
