"""The reference controller: the open controllers' law, and that it really differs from ours."""

from __future__ import annotations

import pytest

from dthc_bridge.controller.thc import Lock
from dthc_tools.bench.control import plan_cuts, run_controller
from dthc_tools.bench.reference import ReferenceConfig, ReferenceThc
from mock_device.plant import load_scenario

PERIOD = 0.001


def running(target: float = 120.0, **ref: float) -> ReferenceThc:
    thc = ReferenceThc(ReferenceConfig(**ref))  # type: ignore[arg-type]  # keyword test data
    thc.target_v = target
    thc.frozen = False
    thc.observe_speed(100.0, 100.0, 0.0)
    return thc


def step(thc: ReferenceThc, volts: list[float], t: float, speed: float = 100.0) -> float:
    thc.observe_speed(speed, 100.0, t)
    return thc.update(volts, PERIOD, t, PERIOD * len(volts)).velocity_mm_s


def test_hard_dead_band_then_one_mm_s_per_volt_of_the_batch_mean() -> None:
    """Inside 1 V nothing moves; outside, the whole error counts, 1 mm/s per volt, no ramp."""
    thc = running()
    assert step(thc, [120.9] * 5, 0.005) == 0.0
    assert step(thc, [117.0] * 5, 0.010) == pytest.approx(3.0)  # low voltage: up, at once
    assert step(thc, [124.0, 124.0, 124.0, 124.0, 126.0], 0.015) == pytest.approx(-4.4)


def test_speed_is_clamped_to_the_thc_limit() -> None:
    """M667 F600: 10 mm/s at most, whatever the error."""
    thc = running()
    thc.set_speed_limit(600.0)
    assert step(thc, [60.0] * 5, 0.005) == pytest.approx(10.0)


def test_void_lock_after_three_steep_samples_and_unlock_after_ten_quiet() -> None:
    """|dV| above 500 V/s x 2 x 1 ms on 3 consecutive samples locks; 10 quiet ones unlock."""
    thc = running()
    step(thc, [120.0] * 5, 0.005)
    step(thc, [121.5, 123.0], 0.007)  # two steep samples: not yet
    assert Lock.VOID not in thc.locks(0.007)
    step(thc, [124.5], 0.008)  # the third
    assert Lock.VOID in thc.locks(0.008)
    assert step(thc, [124.5] * 9, 0.017) == 0.0
    assert Lock.VOID in thc.locks(0.017)
    step(thc, [124.5], 0.018)  # the tenth quiet sample
    assert Lock.VOID not in thc.locks(0.018)


def test_the_literal_threshold_is_half_a_volt_per_sample() -> None:
    """``void_threshold_cycles=1``: 500 V/s x 1 ms, as docs/plasma-facts.md words it."""
    thc = running(void_threshold_cycles=1.0)
    step(thc, [120.0, 120.7, 121.4, 122.1], 0.004)
    assert Lock.VOID in thc.locks(0.004)


def test_velocity_anti_dive_and_unknown_speed_lock_as_ours_does() -> None:
    """90 % locks, 99 % unlocks; no XY speed locks."""
    thc = running()
    assert step(thc, [110.0] * 5, 0.005, speed=89.0) == 0.0
    assert Lock.VELOCITY in thc.locks(0.005)
    assert step(thc, [110.0] * 5, 0.010, speed=95.0) == 0.0
    assert step(thc, [110.0] * 5, 0.015, speed=99.5) == pytest.approx(10.0)
    thc.observe_speed(None, 100.0, 0.02)
    assert thc.locks(0.02) & {Lock.VELOCITY, Lock.NO_SPEED}


def test_reset_forgets_the_void_lock() -> None:
    thc = running()
    step(thc, [120.0, 125.0, 130.0, 135.0], 0.004)
    assert thc.void_locked
    thc.reset()
    assert not thc.void_locked
    assert thc.filtered_v is None


def test_on_a_warped_sheet_the_reference_law_holds_height_worse_than_ours() -> None:
    """Same plant, seed, path and sequence: the 1 V / 1 mm/s/V law has a larger RMS error."""
    plans = plan_cuts(load_scenario("warped_sheet").default_program, max_path_mm=600)
    ours = run_controller("warped_sheet", 1, "ours", plans).as_dict()
    reference = run_controller("warped_sheet", 1, "reference", plans).as_dict()
    no_thc = run_controller("warped_sheet", 1, "no_thc", plans).as_dict()
    assert isinstance(ours["rms_mm"], float)
    assert isinstance(reference["rms_mm"], float)
    assert isinstance(no_thc["rms_mm"], float)
    assert ours["dives"] == 0
    assert reference["rms_mm"] > 1.3 * ours["rms_mm"]
    assert no_thc["rms_mm"] > reference["rms_mm"]


def test_kerf_spikes_below_the_void_threshold_drag_the_reference_down() -> None:
    """800 V/s kerf edges stay under 1 V per sample: the reference follows them, ours not."""
    plans = plan_cuts(load_scenario("kerf_crossing").default_program, max_path_mm=300)
    ours = run_controller("kerf_crossing", 1, "ours", plans).as_dict()
    reference = run_controller("kerf_crossing", 1, "reference", plans).as_dict()
    assert isinstance(ours["max_mm"], float)
    assert isinstance(reference["max_mm"], float)
    assert reference["max_mm"] > 0.25
    assert reference["max_mm"] > 5 * ours["max_mm"]


def test_on_nested_kerfs_ours_neither_dives_nor_stays_void_locked() -> None:
    """nested_kerfs, the first 330 mm (four kerfs and the shallow one): no dive, and no
    void lock lasts longer than the kerf under the torch (0.1 s at 92 mm/s)."""
    plans = plan_cuts(load_scenario("nested_kerfs").default_program, max_path_mm=330)
    ours = run_controller("nested_kerfs", 1, "ours", plans)
    assert ours.as_dict()["dives"] == 0
    assert ours.void.locks >= 4
    assert ours.void.longest_s < 0.15
    assert ours.void.false_locks == 0
