"""Measurement noise and determinism: same seed, same run; noise features as configured."""

import random
import statistics

import pytest

from mock_device.plant import ArcState, NoiseGenerator, Plant, load_scenario
from mock_device.plant.scenario import NoiseSpec

from .plant_helpers import DT_S, fire, goto_xy


def _five_second_run(seed: int) -> list[float]:
    """Noisy scenario: fire, cut the default program with a crude Z follower, 5 s of samples."""
    plant = Plant(load_scenario("noisy_hf_start"), seed=seed)
    goto_xy(plant, 50.0, 50.0)
    plant.zaxis.move_to(plant.surface_z_mm + 3.8, 60.0)
    plant.set_torch(True)
    plant.load_default_program()
    out = []
    for _ in range(5000):
        v = plant.measured_voltage_v()
        if plant.arc_state is ArcState.TRANSFERRED:
            plant.zaxis.jog(max(-10.0, min(10.0, 0.5 * (128.0 - v))))
        plant.step(DT_S)
        out.append(plant.measured_voltage_v())
    return out


def test_same_seed_gives_bit_identical_measured_voltages_and_different_seeds_differ() -> None:
    """Two runs with seed 42 agree sample for sample over 5 s; seed 43 does not."""
    first = _five_second_run(42)
    assert first == _five_second_run(42)
    assert first != _five_second_run(43)
    assert max(first) > 100.0, "the arc was on"


def test_steady_noise_has_the_configured_sigma() -> None:
    """With only the gaussian floor, the sample standard deviation matches sigma_v."""
    gen = NoiseGenerator(NoiseSpec(sigma_v=0.4), random.Random(1))
    samples = [gen.sample(i * DT_S) for i in range(20000)]
    assert statistics.pstdev(samples) == pytest.approx(0.4, rel=0.05)
    assert abs(statistics.fmean(samples)) < 0.02


def test_spikes_are_large_and_short_and_hf_start_adds_spikes_early() -> None:
    """Spikes of 20-100 V last 1-2 samples; the 0.5 s after torch on are much spikier."""
    spec = NoiseSpec(
        sigma_v=0.0,
        spike_rate_per_s=2.0,
        hf_start_spike_rate_per_s=200.0,
        hf_start_window_s=0.5,
    )
    gen = NoiseGenerator(spec, random.Random(7))
    gen.start_hf(0.0)
    samples = [gen.sample((i + 1) * DT_S) for i in range(20000)]
    nonzero = [abs(s) for s in samples if s != 0.0]
    assert nonzero
    assert all(20.0 <= a <= 100.0 for a in nonzero)
    runs, length = [], 0
    for s in samples[1000:]:
        if s != 0.0:
            length += 1
        elif length:
            runs.append(length)
            length = 0
    assert len(runs) >= 20
    assert set(runs) == {1, 2}, "after the HF window: isolated spikes of 1-2 samples"
    early = sum(1 for s in samples[:500] if s != 0.0)
    late = sum(1 for s in samples[500:1000] if s != 0.0)
    assert early >= 50
    assert late <= 10


def test_bursts_raise_the_noise_for_their_duration() -> None:
    """During a burst the noise spread grows by about burst_amplitude_v."""
    spec = NoiseSpec(sigma_v=0.3, burst_rate_per_s=0.5, burst_amplitude_v=2.0)
    gen = NoiseGenerator(spec, random.Random(3))
    quiet: list[float] = []
    loud: list[float] = []
    for i in range(60000):
        t = i * DT_S
        s = gen.sample(t)
        (loud if gen.in_burst(t) else quiet).append(s)
    assert loud, "bursts happened"
    assert statistics.pstdev(quiet) == pytest.approx(0.3, rel=0.1)
    assert statistics.pstdev(loud) == pytest.approx((0.3**2 + 2.0**2) ** 0.5, rel=0.1)


def test_noise_is_off_while_the_torch_is_off() -> None:
    """No arc, no voltage: the sample is exactly 0 V with the torch off, whatever the noise."""
    plant = Plant(load_scenario("noisy_hf_start"), seed=1)
    plant.advance(0.5)
    assert plant.measured_voltage_v() == 0.0
    fire(plant)
    plant.set_torch(False)
    plant.advance(0.5)
    assert plant.measured_voltage_v() == 0.0
