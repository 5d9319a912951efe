"""Auto voltage as a pure estimator: the mean over the first window, restarted by a void
lock, then one refinement by a line fit back to distance 0."""

from __future__ import annotations

import math
import random
from collections.abc import Callable

import pytest

from dthc_bridge.controller.auto_voltage import AutoVoltage, FitLimits, fitted_voltage, line_fit
from dthc_bridge.controller.sequence import SequenceConfig

LIMITS = FitLimits(
    max_plate_slope_v_per_mm=0.02 * 7.5,
    min_span_mm=1.0,
    max_residual_v=1.0,
    max_slope_change_v_per_mm=0.05,
)


def test_the_mean_is_taken_once_the_window_is_full() -> None:
    """Batches every 10 ms over a 50 ms window: no estimate before, the mean at 50 ms."""
    auto = AutoVoltage(window_s=0.05, fit_window_s=0.3, limits=LIMITS)
    for i in range(5):
        assert auto.sample(1.0 + 0.01 * i, 120.0 + i, 0.0, void=False) is None
    assert auto.sample(1.05, 125.0, 0.0, void=False) == pytest.approx(122.5)
    assert auto.mean_v == pytest.approx(122.5)
    assert auto.wants_refining


def test_a_void_lock_starts_the_window_again() -> None:
    """A kerf crossed during the window: what was sampled before it is dropped."""
    auto = AutoVoltage(window_s=0.05, fit_window_s=0.3, limits=LIMITS)
    auto.sample(1.00, 150.0, 0.0, void=False)
    assert auto.sample(1.02, 160.0, 0.0, void=True) is None
    for i in range(5):
        assert auto.sample(1.03 + 0.01 * i, 120.0, 0.0, void=False) is None
    assert auto.sample(1.08, 120.0, 0.0, void=False) == pytest.approx(120.0)


def test_the_refinement_replaces_the_mean_by_the_voltage_at_distance_0() -> None:
    """A plate drifting 0.0375 V per mm under the held torch, 100 mm/s: after the fit
    window, the line's value at distance 0 (122 V), once."""
    auto = AutoVoltage(window_s=0.05, fit_window_s=0.3, limits=LIMITS)
    t, d = 1.0, 10.0
    mean = None
    while mean is None:
        mean = auto.sample(t, 122.0 - 0.0375 * d, d, void=False)
        t, d = t + 0.01, d + 1.0
    refined = None
    while auto.wants_refining:
        refined = auto.refine(t, 122.0 - 0.0375 * d, d, void=False)
        t, d = t + 0.01, d + 1.0
    assert refined == pytest.approx(122.0)
    assert mean < 122.0 - 0.3
    assert t - 1.0 == pytest.approx(0.31)


def test_without_the_fit_the_mean_stays() -> None:
    auto = AutoVoltage(window_s=0.0, fit_window_s=0.3, limits=None)
    assert auto.sample(1.0, 120.0, 0.0, void=False) == 120.0
    assert auto.refine(1.01, 121.0, 1.0, void=False) is None
    assert not auto.wants_refining


def test_implausible_lines_give_no_fit() -> None:
    """Too few samples, too short a span, too steep a plate: None (the mean is kept)."""
    distances = [float(d) for d in range(20)]
    assert fitted_voltage(distances[:2], [120.0, 120.1], LIMITS) is None
    assert fitted_voltage([0.0, 0.1, 0.2, 0.3], [120.0] * 4, LIMITS) is None
    assert fitted_voltage(distances, [120.0 - 0.5 * d for d in distances], LIMITS) is None
    assert fitted_voltage(distances, [120.0 - 0.01 * d for d in distances], LIMITS) == (
        pytest.approx(120.0)
    )


def test_a_noise_burst_does_not_fill_the_window() -> None:
    """Batches a noise burst leaves out (no voltage) do not count towards the window: after
    a burst of 0.5 s, the mean waits for 50 ms of voltages, not one batch."""
    auto = AutoVoltage(window_s=0.05, fit_window_s=0.3, limits=LIMITS)
    assert auto.sample(1.0, 121.0, 0.0, void=False) is None
    for i in range(1, 51):
        assert auto.sample(1.0 + 0.01 * i, None, 0.0, void=False) is None
    for i in range(1, 5):
        assert auto.sample(1.5 + 0.01 * i, 120.0, 0.0, void=False) is None
    assert auto.sample(1.55, 120.0, 0.0, void=False) == pytest.approx(120.1667, abs=1e-3)
    # The fit window counts the same way: 0.3 s of voltages from the window's start.
    t = 1.55
    while auto.wants_refining:
        t += 0.01
        auto.refine(t, 120.0, 100.0 * (t - 1.5), void=False)
    assert t == pytest.approx(1.8, abs=0.011)


def test_halves_that_disagree_about_a_slope_not_told_from_noise_give_the_mean() -> None:
    """A flat plate whose first samples still carry 2 V of a decaying start and +-0.4 V of
    noise: the halves' slopes differ by more than max_slope_change, but the whole line's
    slope is not told from noise: the mean of every sample (less of the start's remnant
    than the first window's), not None."""
    limits = FitLimits(
        max_plate_slope_v_per_mm=0.15,
        min_span_mm=1.0,
        max_residual_v=1.0,
        max_slope_change_v_per_mm=0.05,
        min_slope_t=2.0,
        min_slope_v_per_mm=0.025,
    )
    distances = [float(i) for i in range(40)]
    volts = [
        120.0 + (2.0 * (1 - i / 4) if i < 4 else 0.0) + (0.4 if i % 2 else -0.4) for i in range(40)
    ]
    fit = line_fit(distances, volts, limits)
    assert fit is not None
    assert fit[0] == pytest.approx(120.125)
    assert fit[1] == 0.0


def _default_limits() -> FitLimits:
    """The limits the sequence builds from its defaults, at 7.5 V/mm."""
    cfg = SequenceConfig()
    return FitLimits(
        max_plate_slope_v_per_mm=cfg.auto_voltage_max_plate_slope * 7.5,
        min_span_mm=cfg.auto_voltage_min_span_mm,
        max_residual_v=cfg.auto_voltage_max_residual_v,
        max_slope_change_v_per_mm=cfg.auto_voltage_max_slope_change,
        min_slope_t=cfg.auto_voltage_min_slope_t,
        min_slope_v_per_mm=cfg.auto_voltage_min_slope_v_per_mm,
    )


def _run_flat_window(volts_at: Callable[[float, float], float]) -> list[tuple[float, float]]:
    """Batches every 5 ms at 100 mm/s from t = 1 s, the voltage ``volts_at(t, d)``: every
    estimate the window gives, with its time since the window began."""
    auto = AutoVoltage(window_s=0.05, fit_window_s=0.3, limits=_default_limits(), flat_window_s=2.0)
    found: list[tuple[float, float]] = []
    i = 0
    while auto.mean_v is None or auto.wants_refining:
        t, d = 1.0 + 0.005 * i, 0.5 * i
        v = volts_at(t - 1.0, d)
        got = (
            auto.sample(t, v, d, void=False)
            if auto.mean_v is None
            else auto.refine(t, v, d, void=False)
        )
        if got is not None:
            found.append((round(t - 1.0, 3), got))
        i += 1
        assert i < 1000
    return found


def _noise(t: float) -> float:
    """+-0.4 V, alternating batch by batch: a flat plate's noise, no slope in it."""
    return 0.4 if round(t / 0.005) % 2 else -0.4


def test_on_a_flat_plate_the_longer_window_s_mean_replaces_the_fit_window_s() -> None:
    """The first 0.3 s read 0.1 V high (their noise), the rest true (120 V): the target
    at 0.3 s carries the 0.1 V; at 2 s the mean of all of it, 0.015 V high."""
    found = _run_flat_window(lambda t, d: 120.0 + (0.1 if t < 0.3 else 0.0) + _noise(t))
    assert [t for t, _ in found] == [0.05, 0.3, 2.0]
    assert found[1][1] == pytest.approx(120.1, abs=0.01)
    assert found[2][1] == pytest.approx(120.0 + 0.1 * 0.3 / 2.0, abs=0.003)


def test_a_plate_that_tilts_after_the_fit_window_keeps_the_fit_window_s_target() -> None:
    """Flat for 0.3 s, then rising 0.1 V per mm: over 2 s the line has a slope, so the mean
    of it would carry the tilt; the target fitted at 0.3 s stays."""

    def volts(t: float, d: float) -> float:
        return 120.0 + _noise(t) + (0.1 * (d - 150.0) if d > 150.0 else 0.0)

    found = _run_flat_window(volts)
    assert [t for t, _ in found] == [0.05, 0.3]
    assert found[1][1] == pytest.approx(120.0, abs=0.01)


def test_a_sloped_plate_is_not_averaged_longer() -> None:
    """The fit at 0.3 s found a slope: no longer window, one refinement as before."""
    found = _run_flat_window(lambda t, d: 122.0 - 0.0375 * d)
    assert [t for t, _ in found] == [0.05, 0.3]
    assert found[1][1] == pytest.approx(122.0)


def _small_hole_window(seed: int, slope_v_per_mm: float) -> tuple[list[float], list[float]]:
    """A small hole's fit window: 60 batches over 6.6 mm, 20 mm into the cut (1300
    mm/min), 0.2 V of noise that neighbouring batches share (correlation 0.3, as the 40 Hz
    filter leaves it), on a plate rising ``slope_v_per_mm``."""
    rng = random.Random(seed)
    noise = 0.0
    distances, volts = [], []
    for i in range(60):
        noise = 0.3 * noise + rng.gauss(0.0, 0.2) * math.sqrt(1.0 - 0.3**2)
        d = 20.0 + 0.11 * i
        distances.append(d)
        volts.append(132.9 + slope_v_per_mm * (d - 20.0) + noise)
    return distances, volts


def test_a_small_holes_flat_window_rarely_passes_for_a_slope() -> None:
    """Over 400 noise draws of a flat plate, the default limits find no slope (at 2
    standard errors: 24, every one extrapolated more than 0.3 V off; at 3: 6); a real
    0.1 V/mm slope is found about as often (197; 204 at 2)."""
    limits = _default_limits()
    false_slopes = 0
    found = 0
    for seed in range(400):
        fit = line_fit(*_small_hole_window(seed, 0.0), limits)
        false_slopes += fit is not None and fit[1] != 0.0
        real = line_fit(*_small_hole_window(seed, 0.1), limits)
        found += real is not None and real[1] != 0.0
    assert false_slopes <= 2
    assert found >= 190
