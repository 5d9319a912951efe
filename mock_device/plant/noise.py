"""Arc-voltage measurement noise: gaussian floor, bursts, spikes, HF-start spikes, ripple.

Bursts and spikes are Poisson processes in simulated time: the time of the next event is
drawn when the previous one fires, so a sample costs one gaussian and a few comparisons.
"""

import math
import random

from .scenario import NoiseSpec

__all__ = ["NoiseGenerator"]


class NoiseGenerator:
    """Additive noise for one ADC sample per call of ``sample``."""

    __slots__ = (
        "_burst_amp",
        "_burst_dur",
        "_burst_end_t",
        "_burst_rate",
        "_hf_end_t",
        "_hf_next_t",
        "_hf_rate",
        "_hf_window_s",
        "_next_burst_t",
        "_next_spike_t",
        "_ripple_amp",
        "_ripple_w",
        "_rng",
        "_sigma",
        "_spike_amp",
        "_spike_left",
        "_spike_len",
        "_spike_rate",
        "_spike_v",
    )

    def __init__(self, spec: NoiseSpec, rng: random.Random) -> None:
        self._rng = rng
        self._sigma = spec.sigma_v
        self._burst_rate = spec.burst_rate_per_s
        self._burst_amp = spec.burst_amplitude_v
        self._burst_dur = spec.burst_duration_s
        self._spike_rate = spec.spike_rate_per_s
        self._spike_amp = spec.spike_amplitude_v
        self._spike_len = spec.spike_length_samples
        self._hf_rate = spec.hf_start_spike_rate_per_s
        self._hf_window_s = spec.hf_start_window_s
        self._ripple_amp = spec.ripple_amplitude_v
        self._ripple_w = 2.0 * math.pi * spec.ripple_hz
        self._burst_end_t = -math.inf
        self._next_burst_t = self._after(0.0, self._burst_rate)
        self._next_spike_t = self._after(0.0, self._spike_rate)
        self._hf_end_t = -math.inf
        self._hf_next_t = math.inf
        self._spike_left = 0
        self._spike_v = 0.0

    def _after(self, t_s: float, rate_per_s: float) -> float:
        if rate_per_s <= 0.0:
            return math.inf
        return t_s + self._rng.expovariate(rate_per_s)

    def in_burst(self, t_s: float) -> bool:
        """True when a noise burst covers simulated time ``t_s`` (as of the last sample)."""
        return t_s < self._burst_end_t

    def start_hf(self, t_s: float) -> None:
        """The torch fired at ``t_s``: spikes from the HF start for the next window."""
        self._hf_end_t = t_s + self._hf_window_s
        self._hf_next_t = self._after(t_s, self._hf_rate)

    def _start_spike(self) -> None:
        rng = self._rng
        lo, hi = self._spike_len
        self._spike_left = rng.randint(lo, hi)
        amp = rng.uniform(*self._spike_amp)
        self._spike_v = amp if rng.random() < 0.5 else -amp

    def sample(self, t_s: float) -> float:
        """Noise in volts to add to the sample taken at simulated time ``t_s``."""
        rng = self._rng
        n = rng.gauss(0.0, self._sigma) if self._sigma > 0.0 else 0.0
        if t_s >= self._next_burst_t:
            self._burst_end_t = t_s + rng.uniform(*self._burst_dur)
            self._next_burst_t = self._after(self._burst_end_t, self._burst_rate)
        if t_s < self._burst_end_t:
            n += rng.gauss(0.0, self._burst_amp)
        if t_s >= self._next_spike_t:
            self._next_spike_t = self._after(t_s, self._spike_rate)
            self._start_spike()
        if t_s >= self._hf_next_t:
            if t_s < self._hf_end_t:
                self._hf_next_t = self._after(t_s, self._hf_rate)
                self._start_spike()
            else:
                self._hf_next_t = math.inf
        if self._spike_left:
            self._spike_left -= 1
            n += self._spike_v
        if self._ripple_amp:
            n += self._ripple_amp * math.sin(self._ripple_w * t_s)
        return n
