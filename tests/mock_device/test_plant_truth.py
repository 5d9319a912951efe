"""Ground truth: bounded recording, CSV/JSONL output, per-cut stats, violation counting."""

import csv
import json
from pathlib import Path

import pytest

from mock_device.plant import (
    TRUTH_FIELDS,
    VIOLATION_LEASE,
    VIOLATION_TOUCH,
    ArcState,
    Plant,
    TruthRecorder,
)

from .plant_helpers import DT_S, fire, goto_xy, quiet, set_height


def _record(rec: TruthRecorder, t_s: float, height_mm: float, arc_state: int, speed: float) -> None:
    rec.record(t_s, 1.0, 2.0, speed, height_mm, 21.5, 20.0, True, arc_state, 125.0, 125.5)


def test_csv_and_jsonl_hold_every_stored_sample_with_named_fields(tmp_path: Path) -> None:
    """write_csv and write_jsonl write the same rows, header/keys are TRUTH_FIELDS."""
    plant = Plant(quiet(), seed=1)
    fire(plant)
    plant.advance(0.2)
    n = len(plant.truth)
    assert n == round(plant.t_s / DT_S)
    csv_path = tmp_path / "truth.csv"
    jsonl_path = tmp_path / "truth.jsonl"
    assert plant.truth.write_csv(csv_path) == n
    assert plant.truth.write_jsonl(jsonl_path) == n
    with csv_path.open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    lines = [json.loads(line) for line in jsonl_path.read_text(encoding="utf-8").splitlines()]
    assert len(rows) == len(lines) == n
    assert tuple(rows[0]) == TRUTH_FIELDS
    assert tuple(lines[0]) == TRUTH_FIELDS
    last_csv, last_json = rows[-1], lines[-1]
    assert float(last_csv["t_s"]) == pytest.approx(plant.t_s)
    assert last_json["arc_state"] == int(ArcState.TRANSFERRED)
    assert last_json["torch_on"] is True
    assert last_csv["torch_on"] == "1"
    assert float(last_csv["measured_v"]) == pytest.approx(plant.measured_voltage_v())
    assert last_json["true_height_mm"] == pytest.approx(1.5)


def test_recording_is_bounded_and_decimated() -> None:
    """The ring keeps the newest `capacity` samples, oldest first; decimation thins them."""
    rec = TruthRecorder(capacity=100, decimation=2)
    for i in range(500):
        _record(rec, i * DT_S, 1.5, 0, 0.0)
    assert len(rec) == 100
    times = rec.column("t_s")
    assert times[0] == pytest.approx(300 * DT_S)
    assert times[-1] == pytest.approx(498 * DT_S)
    assert [r.t_s for r in rec.rows()] == times
    summary = rec.summary()
    assert (summary.samples_seen, summary.samples_stored, summary.samples_dropped) == (
        500,
        250,
        150,
    )


def test_touching_the_plate_while_cutting_counts_once_per_episode() -> None:
    """Two separate dives onto the plate with the arc on: two violations, not hundreds."""
    plant = Plant(quiet(), seed=2)
    goto_xy(plant, 100.0, 100.0)
    fire(plant)
    for _ in range(2):
        set_height(plant, -0.5, feed_mm_s=10.0)
        plant.advance(0.05)
        set_height(plant, 1.5, feed_mm_s=10.0)
    assert plant.arc_state is ArcState.TRANSFERRED
    assert plant.truth.violations == {VIOLATION_TOUCH: 2}
    plant.set_torch(False)
    set_height(plant, -0.5)
    plant.advance(0.1)
    assert plant.truth.violations[VIOLATION_TOUCH] == 2, "no arc, no violation"


def test_board_reported_violations_are_counted_by_kind() -> None:
    """count_violation (the firmware's lease-expiry report) adds up per kind."""
    plant = Plant(quiet(), seed=3)
    for _ in range(3):
        plant.count_violation(VIOLATION_LEASE)
    plant.count_violation("other")
    assert plant.truth.violations == {VIOLATION_LEASE: 3, "other": 1}
    assert plant.truth.summary().violations[VIOLATION_LEASE] == 3


def test_cut_stats_measure_height_error_after_the_thc_delay_and_count_dives() -> None:
    """Error stats skip the first thc_delay_s of a cut and standstill; dives are episodes."""
    rec = TruthRecorder(cut_height_mm=1.5, thc_delay_s=0.5)
    t = 0.0
    heights = [3.8] * 500 + [1.5] * 300 + [0.5] * 10 + [1.5] * 50 + [0.6] * 5 + [2.0] * 100
    for h in heights:
        t += DT_S
        _record(rec, t, h, int(ArcState.TRANSFERRED), 50.0)
    _record(rec, t + 0.2, 1.5, int(ArcState.TRANSFERRED), 0.0)  # standstill: not measured
    _record(rec, t + 0.3, 9.0, int(ArcState.LOST), 50.0)
    (cut,) = rec.summary().cuts
    # From 0.5 s after the first transferred sample (±1 sample of float rounding).
    assert len(heights) - 501 <= cut.measured_samples <= len(heights) - 499
    assert cut.dives == 2
    assert cut.height_max_error_mm == pytest.approx(1.0)
    assert cut.min_height_mm == pytest.approx(0.5)
    expected_rms = ((10 * 1.0 + 5 * 0.81 + 100 * 0.25 + 0.0) / cut.measured_samples) ** 0.5
    assert cut.height_rms_error_mm == pytest.approx(expected_rms, rel=1e-3)
    assert cut.duration_s == pytest.approx(t + 0.2 - DT_S)


def test_a_clean_plant_cut_has_zero_height_error() -> None:
    """A cut at exactly the cut height on a flat plate: RMS error 0, no dives, no touches."""
    plant = Plant(quiet(), seed=4)
    goto_xy(plant, 50.0, 100.0)
    fire(plant)
    plant.gantry.feed_line("G1 X250 Y100 F5500")
    plant.advance(3.0)
    plant.set_torch(False)
    plant.step(DT_S)
    (cut,) = plant.truth.summary().cuts
    assert cut.measured_samples > 1000
    assert cut.height_rms_error_mm == pytest.approx(0.0, abs=1e-9)
    assert (cut.dives, cut.touches) == (0, 0)
