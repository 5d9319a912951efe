"""Auto voltage's guards against the start transient and a flat plate's noise (issue 35):
the transient measured over the pierce, the wait for it, the fit through it."""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Any

import pytest

from dthc_bridge.controller.auto_voltage import AutoVoltage, FitLimits, line_fit
from dthc_bridge.controller.sequence import SequenceConfig
from dthc_bridge.controller.start_transient import StartTransient
from tests.controller.test_sequence import ready

LIMITS = FitLimits(
    max_plate_slope_v_per_mm=0.02 * 7.5,
    min_span_mm=1.0,
    max_residual_v=1.0,
    max_slope_change_v_per_mm=0.05,
    min_slope_t=2.0,
    min_slope_v_per_mm=0.01,
)
OVERSHOOT_V = 20.0
TAU_S = 0.8 / 3.0  # noisy_hf_start: 5 % left at 0.8 s


def _arc_v(t: float, level_v: float) -> float:
    return level_v + OVERSHOOT_V * math.exp(-t / TAU_S)


def _pierce(rng: random.Random, *, spikes_per_s: float) -> StartTransient:
    """0.3 s of pierce at 1 kHz in 5-sample batches: the decay, 0.5 V noise and a
    high-frequency start's spikes of 20-100 V lasting one or two samples."""
    transient = StartTransient()
    spike_left = 0
    for batch in range(60):
        volts = []
        for i in range(5):
            t = (batch * 5 + i) * 0.001
            v = _arc_v(t, 160.0) + rng.gauss(0.0, 0.5)
            if spike_left == 0 and rng.random() < spikes_per_s * 0.001:
                spike_left = rng.choice((1, 2))
            if spike_left:
                spike_left -= 1
                v += rng.choice((-1.0, 1.0)) * rng.uniform(20.0, 100.0)
            volts.append(v)
        transient.add(batch * 0.005 + 0.004, volts)
    transient.fit()
    return transient


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_pierce_measures_the_decay_through_a_high_frequency_start(seed: int) -> None:
    """200 spikes a second: the decay's size and time constant within a quarter, so that
    what is left at 0.75 s is known within 0.75 V (without the median of three batches and
    the second fit without the batches far off the first, spike batches take the decay's
    place: no model, or tau off by half)."""
    transient = _pierce(random.Random(seed), spikes_per_s=200.0)
    assert transient.tau_s == pytest.approx(TAU_S, rel=0.25)
    assert transient.overshoot_v == pytest.approx(OVERSHOOT_V, rel=0.25)
    true_left = OVERSHOOT_V * math.exp(-0.75 / TAU_S)
    assert transient.remnant_v(0.75) == pytest.approx(true_left, abs=0.75)


def test_spiked_batches_at_transfer_do_not_choose_the_time_constant() -> None:
    """noisy_hf_start seed 18: the first two batches' medians spiked (200 and 225 V over
    a 172 V start), and the best fit was a 31 V "decay" of 0.02 s that explained those two
    and left nothing of the real one (0.27 s) by 0.7 s: auto voltage measured 1.4 V of it.
    No arc settles that fast: with time constants from 0.055 s the two are outliers."""
    transient = StartTransient()
    rng = random.Random(18)
    for batch in range(60):
        volts = [_arc_v((batch * 5 + i) * 0.001, 152.0) + rng.gauss(0.0, 0.5) for i in range(5)]
        if batch < 2:  # three of the five samples spiked: the batch's median too
            spike = 28.0 if batch == 0 else 53.0
            volts = [v + spike if i < 3 else v for i, v in enumerate(volts)]
        transient.add(batch * 0.005 + 0.004, volts)
    transient.fit()
    assert transient.tau_s == pytest.approx(TAU_S, rel=0.3)
    true_left = OVERSHOOT_V * math.exp(-0.7 / TAU_S)
    assert transient.remnant_v(0.7) == pytest.approx(true_left, abs=0.6)


def test_a_steady_pierce_has_no_transient_to_wait_for() -> None:
    """No decay in the pierce's voltages: no model, nothing left at any time."""
    transient = StartTransient()
    rng = random.Random(4)
    for batch in range(60):
        transient.add(batch * 0.005, [160.0 + rng.gauss(0.0, 0.5) for _ in range(5)])
    transient.fit()
    assert transient.overshoot_v == 0.0
    assert transient.remnant_v(0.1) == 0.0


def test_a_short_pierce_gives_no_model() -> None:
    transient = StartTransient()
    for batch in range(5):
        transient.add(batch * 0.005, [_arc_v(batch * 0.005, 160.0)] * 5)
    transient.fit()
    assert transient.remnant_v(0.5) == 0.0


def test_a_flat_plates_slope_in_the_noise_gives_the_mean() -> None:
    """A slope of 0.005 V/mm over 30 mm is noise on a flat plate: the mean of the window,
    not the line's value 15 mm before it (0.1 V further off)."""
    distances = [15.0 + 0.5 * i for i in range(60)]
    volts = [125.0 + 0.005 * (d - 30.0) + 0.01 * (-1) ** i for i, d in enumerate(distances)]
    fit = line_fit(distances, volts, LIMITS)
    assert fit is not None
    assert fit[1] == 0.0
    assert fit[0] == pytest.approx(sum(volts) / len(volts))
    steep = [125.0 + 0.05 * (d - 30.0) for d in distances]
    sloped = line_fit(distances, steep, LIMITS)
    assert sloped is not None
    assert sloped[0] == pytest.approx(125.0 - 1.5)


def test_the_fit_through_the_transient_removes_its_tail() -> None:
    """A flat plate, the mean taken while 1.5 V of overshoot is left: the pierce's and the
    cut's voltages fitted together give the level without it."""
    rng = random.Random(5)
    transient = _pierce(rng, spikes_per_s=0.0)
    auto = AutoVoltage(window_s=0.05, fit_window_s=0.3, limits=LIMITS, transient=transient)
    t = 0.7
    d = 30.0
    estimate = None
    while estimate is None:
        estimate = auto.sample(t, _arc_v(t, 128.0) + rng.gauss(0.0, 0.1), d, void=False)
        t, d = t + 0.005, d + 0.2
    refined = None
    while auto.wants_refining:
        refined = auto.refine(t, _arc_v(t, 128.0) + rng.gauss(0.0, 0.1), d, void=False)
        t, d = t + 0.005, d + 0.2
    assert refined is not None
    assert refined == pytest.approx(128.0, abs=0.3)


@pytest.mark.parametrize(("tilt_v_per_mm", "estimates"), [(0.0, 3), (0.1, 2)])
def test_the_fit_through_the_transient_goes_on_over_a_flat_plate(
    tilt_v_per_mm: float, estimates: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Over a flat plate the fit through the transient's tail is made again over the
    longer window (a third estimate, nearer the level: 0.4 V of noise, 0.3 s against
    2 s); a plate that tilts after the first 0.3 s keeps the first fit (two estimates).
    The longer window keeps the time constant the 0.3 s fit found: over 400 batches the
    grid's 32 took 55 ms of the event loop in one batch, one takes about 3 ms."""
    from dthc_bridge.controller.start_transient import fit_through_transient as real_fit

    taus: list[float | None] = []

    def recording(*args: Any, tau_s: float | None = None, **kwargs: Any) -> Any:
        taus.append(tau_s)  # None: the grid
        return real_fit(*args, tau_s=tau_s, **kwargs)

    monkeypatch.setattr("dthc_bridge.controller.auto_voltage.fit_through_transient", recording)
    rng = random.Random(5)
    transient = _pierce(rng, spikes_per_s=0.0)
    auto = AutoVoltage(
        window_s=0.05, fit_window_s=0.3, limits=LIMITS, transient=transient, flat_window_s=2.0
    )

    def volts(t: float, d: float) -> float:
        tilt = tilt_v_per_mm * (d - 45.0) if d > 45.0 else 0.0
        return _arc_v(t, 128.0) + rng.gauss(0.0, 0.4) + tilt

    t, d = 0.7, 30.0
    found: list[float] = []
    while auto.mean_v is None or auto.wants_refining:
        v = volts(t, d)
        got = auto.sample(t, v, d, False) if auto.mean_v is None else auto.refine(t, v, d, False)
        if got is not None:
            found.append(got)
        t, d = t + 0.005, d + 0.2
    assert len(found) == estimates
    assert found[1] == pytest.approx(128.0, abs=0.3)
    if estimates == 3:
        assert abs(found[2] - 128.0) < 0.05
    # The 0.3 s fit searches the grid; the longer window's solve at the time constant it
    # found (the sloped check, then the flat fit; the tilted plate stops at the check).
    first = auto.tau_s
    assert first is not None
    assert taus == [None, first, first] if estimates == 3 else taus == [None, first]


@dataclass(frozen=True)
class _NoisyCut:
    target_v: float  # the cut-height voltage measured
    truth_v: float  # the arc's true voltage at cut height
    overshoot_v: float  # the start transient the pierce measured
    refining: bool  # the estimate still wants batches (the longer window runs)


def _noisy_cut(seed: int) -> _NoisyCut:
    """A 300 mm cut with auto voltage on noisy_hf_start."""
    loop = ready("noisy_hf_start", seed=seed, cut_voltage_v=None)
    assert loop.m3().ok
    assert loop.move("G1 X350 Y50 F2550", max_s=20)
    cut = loop.sequence.cut
    assert cut is not None
    assert cut.cut_height_v is not None
    assert cut.auto_voltage is not None
    truth = loop.plant.arc.voltage_at_height_v(1.5)
    refining = cut.auto_voltage.wants_refining
    return _NoisyCut(cut.cut_height_v, truth, cut.transient.overshoot_v, refining)


@pytest.mark.parametrize("seed", [1, 4, 5])
def test_auto_voltage_on_a_noisy_cutter_with_a_slow_transient(seed: int) -> None:
    """noisy_hf_start (20 V of overshoot, 5 % left at 0.8 s; 2 V noise bursts; spikes):
    the target within half a volt of the arc's true voltage at cut height, where it was
    1.4-2.2 V over it (the transient's tail in the mean). Seed 5 needs a noise burst's
    voltages left out of the window (else -0.81 V)."""
    cut = _noisy_cut(seed)
    assert cut.target_v == pytest.approx(cut.truth_v, abs=0.5)
    assert cut.overshoot_v > 10.0


@pytest.mark.parametrize("seed", [15, 18])
def test_auto_voltage_on_a_noisy_cutter_within_a_tenth_of_a_volt(seed: int) -> None:
    """The same plant, seeds held out of the benchmark's goals, once the longer window
    on a flat plate is over: within 0.1 V (0.013 mm). Seed 18's pierce fitted a 0.02 s
    decay to two spiked batches (+1.2 V without the floor on the time constant); seed
    15's flat fit through the transient's tail was 0.21 V low over the first 0.3 s (the
    same fit over 2 s: 0.03 V)."""
    cut = _noisy_cut(seed)
    assert not cut.refining  # the longer window is over
    assert cut.target_v == pytest.approx(cut.truth_v, abs=0.1)


def test_the_wait_for_the_transient_is_bounded() -> None:
    """The configuration's bound on that wait, and its threshold, have owner defaults."""
    config = SequenceConfig()
    assert config.auto_voltage_max_transient_v == 0.3
    assert config.auto_voltage_max_wait_s == 2.0


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_delays_voltages_bound_what_the_thc_is_handed(seed: int) -> None:
    """The pierce's 0.3 s alone leave tau uncertain (a quarter either way); fitted again
    with 0.4 s of a held torch's voltages at 0.6-1 s (another level: the cut's), the
    smaller of the two models' remnants at 1 s (what the sequence hands the THC) is within
    0.6-1.2 of the truth (4.9 % of 20 V = 0.47 V); either model alone is off by up to 2x."""
    from dthc_bridge.controller.start_transient import refit_decay

    rng = random.Random(seed)
    transient = _pierce(rng, spikes_per_s=200.0)
    times = [0.6 + 0.005 * i for i in range(80)]
    volts = [_arc_v(t, 128.0) + rng.gauss(0.0, 0.3) for t in times]
    fit = refit_decay(transient, times, volts)
    assert fit is not None
    overshoot_v, tau_s, residual_v = fit
    truth = OVERSHOOT_V * math.exp(-1.0 / TAU_S)
    handed = min(overshoot_v * math.exp(-1.0 / tau_s), transient.remnant_v(1.0))
    assert 0.6 * truth < handed < 1.2 * truth
    assert residual_v < 0.5


def test_after_the_thc_delay_the_thc_holds_what_is_left_of_the_transient() -> None:
    """noisy_hf_start, seed 5 (20 V of overshoot, 0.44 V left at the THC delay's end): the
    pierce alone puts 2 V there; with the delay's voltages the THC is handed 0.3-1 V (0.85),
    and 2 s later nothing is left. Off (``thc_discounts_transient``): nothing is handed."""
    loop = ready("noisy_hf_start", seed=5)
    sequence = loop.sequence
    assert loop.m3().ok
    loop.plant.gantry.feed_line("G1 X350 Y50 F2550")
    loop.submit("G1 X350 Y50 F2550")  # the sender's feed: the anti-dive reference
    cut = sequence.cut
    assert cut is not None
    assert cut.arc_ok_since is not None
    delay_end = cut.arc_ok_since + sequence.config.thc_delay_s
    assert loop.run_until(lambda: sequence.now >= delay_end + 0.004, 3)
    assert cut.tail_decay is not None
    assert 0.3 < sequence.thc.transient_v < 1.0
    assert loop.run_until(lambda: sequence.now >= delay_end + 2.0, 3)
    assert sequence.thc.transient_v < 0.01

    off = ready("noisy_hf_start", seed=5, config=SequenceConfig(thc_discounts_transient=False))
    assert off.m3().ok
    off.plant.gantry.feed_line("G1 X350 Y50 F2550")
    off.submit("G1 X350 Y50 F2550")
    assert off.run_until(lambda: off.sequence.now >= delay_end + 0.5, 3)
    assert off.sequence.thc.transient_v == 0.0
