"""Void (kerf-crossing) lock detection, robust to measurement noise.

Crossing an old kerf or a void raises the arc voltage by about 20 V at several hundred
V/s; a THC that follows the spike dives. Measurement noise has other shapes: single spikes
of ±20-100 V over one or two samples, and bursts of 1.5-2 V white noise lasting 0.5-2 s.
A test on sample-to-sample slopes (or a slope over a few samples of a lightly filtered
signal) fires on both. This detector runs on its own path from the raw samples:

- a median of five (removes spikes up to two samples long; the control path's median of
  three lets two-sample spikes through) and a mean of the last four medians;
- **lock** on a *rise* (only up: a kerf or void only ever raises the voltage; a fast fall is
  the plate coming close, which the THC must answer) of at least ``step_v`` within
  ``step_v / slope_v_s`` seconds, i.e. at least that large a step at a mean slope of at
  least ``slope_v_s``, seen on ``on_samples`` consecutive samples. A burst moves the
  smoothed signal by about 1 V, a spike not at all; a kerf at 800 V/s gives 4 V within
  about 8 ms of its start (about 10 ms with the filters);
- **unlock** as soon as the smoothed voltage has been back within ``back_v`` of its level
  before the rise for ``back_samples`` samples, or else once no step of ``step_v`` (either
  way) has been seen for ``hold_s`` (the plate moved while locked: the voltage never comes
  back to the old level).

Samples are counted, not timed: batches read together do not look steep.
"""

from __future__ import annotations

from collections import deque

__all__ = ["VoidLockDetector"]

_MEDIAN = 5
_MEAN = 4
_BASE = 8  # samples averaged for the level before the rise


class VoidLockDetector:
    """Fed one raw sample at a time (``sample``); ``locked`` is the state after the last."""

    def __init__(
        self,
        *,
        slope_v_s: float,
        step_v: float,
        on_samples: int,
        hold_s: float,
        back_v: float,
        back_samples: int,
        period_s: float = 0.001,
    ) -> None:
        self.slope_v_s = slope_v_s
        self.step_v = step_v
        self.on_samples = max(1, on_samples)
        self.hold_s = hold_s
        self.back_v = back_v
        self.back_samples = back_samples
        self.locked = False
        self.rise_v = 0.0  # the rise over the window at the last sample
        self._raw: deque[float] = deque(maxlen=_MEDIAN)
        self._medians: deque[float] = deque(maxlen=_MEAN)
        self._period_s = 0.0
        self._window = 0  # samples over which the rise is measured
        self._smoothed: deque[float] = deque()
        self._steep = 0
        self._base_v = 0.0
        self._back = 0
        self._last_step_t = 0.0
        self._set_period(period_s)

    def _set_period(self, period_s: float) -> None:
        self._period_s = period_s
        window_s = self.step_v / self.slope_v_s if self.slope_v_s > 0.0 else 0.0
        self._window = int(window_s / period_s + 1e-9) if period_s > 0.0 else 0
        self._smoothed = deque(self._smoothed, maxlen=self._window + _BASE + 1)

    @property
    def level_before_v(self) -> float | None:
        """While locked: the smoothed voltage before the rise that locked."""
        return self._base_v if self.locked else None

    def sample(self, v: float, t_s: float, period_s: float) -> None:
        if period_s != self._period_s:
            self._set_period(period_s)
        raw = self._raw
        raw.append(v)
        if len(raw) < _MEDIAN:
            return
        self._medians.append(sorted(raw)[_MEDIAN // 2])
        if len(self._medians) < _MEAN:
            return
        d = sum(self._medians) / _MEAN
        smoothed = self._smoothed
        smoothed.append(d)
        w = self._window
        if w < 1 or len(smoothed) <= w:
            return
        rise = d - smoothed[-1 - w]
        self.rise_v = rise
        if self.locked:
            if abs(rise) >= self.step_v:
                self._last_step_t = t_s
            self._back = self._back + 1 if d <= self._base_v + self.back_v else 0
            if self._back >= self.back_samples or t_s - self._last_step_t >= self.hold_s:
                self.locked = False
                self._steep = 0
            return
        self._steep = self._steep + 1 if rise >= self.step_v else 0
        if self._steep >= self.on_samples:
            self.locked = True
            self._last_step_t = t_s
            self._back = 0
            before = list(smoothed)[: len(smoothed) - w][-_BASE:]
            self._base_v = sum(before) / len(before)
