"""The THC controller: unit behaviour, and holding the true height against the plant."""

from __future__ import annotations

import itertools
from dataclasses import replace
from typing import Any

import pytest

from dthc_bridge.bench.closed_loop import ClosedLoop
from dthc_bridge.controller.thc import Lock, ThcConfig, ThcController

from .test_sequence import ready

PERIOD = 0.001


def running(target: float = 120.0, **cfg: Any) -> ThcController:
    thc = ThcController(ThcConfig(**cfg))
    thc.target_v = target
    thc.frozen = False
    thc.observe_speed(100.0, 100.0, 0.0)
    return thc


def step(thc: ThcController, volts: float, t: float, speed: float = 100.0) -> float:
    thc.observe_speed(speed, 100.0, t)
    return thc.update([volts] * 5, PERIOD, t, 0.005).velocity_mm_s


def test_inside_the_dead_band_z_holds() -> None:
    """Errors within 0.3 V give no Z motion at all."""
    thc = running()
    assert all(step(thc, 120.2, 0.005 * i) == 0.0 for i in range(1, 50))


def test_low_voltage_moves_up_and_high_voltage_moves_down() -> None:
    """Voltage below target means too close: Z goes up; above target: Z goes down."""
    up = running()
    down = running()
    v_up = v_down = 0.0
    for i in range(1, 40):
        v_up = step(up, 117.0, 0.005 * i)
        v_down = step(down, 123.0, 0.005 * i)
    assert v_up > 0.5
    assert v_down < -0.5


def test_speed_and_acceleration_are_limited() -> None:
    """A huge error ramps at the acceleration limit and stops at the M667 F speed."""
    thc = running(max_accel_mm_s2=400.0)
    thc.set_speed_limit(600.0)  # M667 F600 -> 10 mm/s
    speeds = [step(thc, 60.0, 0.005 * i) for i in range(1, 40)]
    steps = [b - a for a, b in itertools.pairwise(speeds)]
    assert max(steps) <= 400.0 * 0.005 + 1e-9
    assert max(speeds) == pytest.approx(10.0)


def test_velocity_anti_dive_locks_below_90_and_unlocks_above_99_percent() -> None:
    """Hysteresis: 95 % stays locked, 99.5 % unlocks after 0.1 s at speed, 89 % locks."""
    thc = running()
    step(thc, 125.0, 0.005, speed=89.0)
    assert Lock.VELOCITY in thc.locks(0.005)
    step(thc, 125.0, 0.010, speed=95.0)
    assert Lock.VELOCITY in thc.locks(0.010)
    step(thc, 125.0, 0.015, speed=99.5)
    assert Lock.VELOCITY in thc.locks(0.015)  # back at speed: held a little longer
    step(thc, 125.0, 0.120, speed=99.5)
    assert Lock.VELOCITY not in thc.locks(0.120)
    step(thc, 125.0, 0.125, speed=95.0)
    assert Lock.VELOCITY not in thc.locks(0.125)
    step(thc, 125.0, 0.130, speed=89.0)
    assert Lock.VELOCITY in thc.locks(0.130)


def test_missing_or_stale_speed_counts_as_locked() -> None:
    """No XY speed for longer than the stale time locks THC; None locks at once."""
    thc = running()
    thc.observe_speed(100.0, 100.0, 0.0)
    assert Lock.NO_SPEED in thc.locks(0.2)
    thc.observe_speed(None, 100.0, 0.3)
    assert Lock.VELOCITY in thc.locks(0.3) or Lock.NO_SPEED in thc.locks(0.3)
    assert thc.update([110.0] * 5, PERIOD, 0.3, 0.005).velocity_mm_s == 0.0


def test_void_lock_on_a_steep_slope_and_release_after_quiet() -> None:
    """A 800 V/s ramp locks THC; quiet samples release it after the hold time."""
    thc = running()
    t = 0.0
    v = 120.0
    for _ in range(10):
        t += 0.005
        step(thc, v, t)
    for _ in range(4):
        t += 0.005
        v += 4.0  # 4 V per 5 ms = 800 V/s
        step(thc, v, t)
    assert Lock.VOID in thc.locks(t)
    for _ in range(30):
        t += 0.005
        step(thc, v, t)
    assert Lock.VOID not in thc.locks(t)


def test_single_sample_spikes_do_not_move_z() -> None:
    """A 60 V one-sample spike inside a batch is removed by the median before the loop."""
    thc = running()
    for i in range(1, 20):
        thc.observe_speed(100.0, 100.0, 0.005 * i)
        out = thc.update([120.0, 120.0, 180.0, 120.0, 120.0], PERIOD, 0.005 * i, 0.005)
        assert out.velocity_mm_s == 0.0


def test_disabled_or_frozen_thc_holds_z() -> None:
    """M666 (disabled) and the THC delay (frozen) both command zero velocity."""
    thc = running()
    thc.enabled = False
    assert step(thc, 100.0, 0.005) == 0.0
    thc.enabled = True
    thc.frozen = True
    assert step(thc, 100.0, 0.010) == 0.0


# --- against the plant ---------------------------------------------------------------------


def cut_stats(loop: ClosedLoop) -> tuple[float, float, int]:
    cut = loop.plant.truth.summary().cuts[-1]
    return cut.height_rms_error_mm, cut.height_max_error_mm, cut.dives


@pytest.mark.parametrize(
    ("scenario", "path", "rms_mm", "max_mm"),
    [
        ("warped_sheet", ("G0 X100 Y100", "G1 X1100 Y100 F6000", "G1 X1100 Y600"), 0.15, 0.45),
        (
            "flat_clean",
            ("G0 X50 Y50", "G1 X250 Y50 F5500", "G1 X250 Y150", "G1 X50 Y150"),
            0.06,
            0.25,
        ),
        ("kerf_crossing", ("G0 X50 Y100", "G1 X450 Y100 F5500"), 0.06, 0.25),
        ("noisy_hf_start", ("G0 X50 Y50", "G1 X450 Y50 F5000", "G1 X450 Y250"), 0.06, 0.2),
    ],
    ids=["warped", "corners", "kerfs", "noisy"],
)
def test_true_height_stays_within_bounds(
    scenario: str, path: tuple[str, ...], rms_mm: float, max_mm: float
) -> None:
    """THC holds the plant's true height: RMS and max error bounded, and no dive."""
    loop = ready(scenario)
    loop.plant.gantry.feed_line(path[0])
    loop.run_until(lambda: loop.plant.gantry.idle, 10)
    started, ok, ended = loop.cut(*path[1:])
    assert started.ok
    assert ok
    assert ended.ok
    rms, worst, dives = cut_stats(loop)
    assert dives == 0
    assert rms < rms_mm
    assert worst < max_mm


@pytest.mark.parametrize(
    ("scenario", "path", "unlock"),
    [
        # A hole cut at 40 % of the programmed 5500 mm/min (M67 E3 Q40): the arc voltage
        # rises about 6 V while the torch has not moved.
        ("flat_clean", ("G0 X50 Y50", "G1 X250 Y50 F5500", "G1 X350 Y50 F2200"), "velocity"),
        ("kerf_crossing", ("G0 X50 Y100", "G1 X450 Y100 F5500"), "void"),
    ],
    ids=["slow_down_dive", "kerf_dive"],
)
def test_locks_prevent_the_dive_an_unlocked_thc_makes(
    scenario: str, path: tuple[str, ...], unlock: str
) -> None:
    """Without anti-dive (slow-downs) or void lock (kerfs) the same cut dives; with them not."""

    def run(locked: bool) -> tuple[float, float, int]:
        no_anti_dive = not locked and unlock == "velocity"
        loop = ready(scenario, anti_dive_percent=0.0) if no_anti_dive else ready(scenario)
        if unlock == "velocity":
            loop.requested_override_mm_s = 5500 / 60
        if not locked and unlock == "void":
            loop.seq.thc.config = replace(loop.seq.thc.config, void_slope_v_s=1e9)
        loop.plant.gantry.feed_line(path[0])
        loop.run_until(lambda: loop.plant.gantry.idle, 10)
        loop.requested_override_mm_s = 5500 / 60 if unlock == "velocity" else None
        loop.cut(*path[1:])
        return cut_stats(loop)

    _, worst_locked, dives_locked = run(True)
    _, worst_unlocked, dives_unlocked = run(False)
    assert dives_locked == 0
    assert dives_unlocked > 0
    assert worst_unlocked > 2 * worst_locked


def test_batches_read_together_do_not_look_like_a_steep_slope() -> None:
    """Two batches handed over at the same instant (one read) keep their sample spacing:
    a 100 V/s ramp, under the 250 V/s void slope, never locks."""
    thc = running()
    void_locked = 0
    for i in range(40):
        t = 0.005 * (i // 2 + 1)  # pairs of batches arrive with the same time stamp
        thc.observe_speed(100.0, 100.0, t)
        thc.update([120.0 + 0.5 * i] * 5, PERIOD, t, 0.005)
        void_locked += Lock.VOID in thc.locks(t)
    assert void_locked == 0
