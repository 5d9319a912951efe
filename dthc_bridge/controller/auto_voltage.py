"""Auto voltage (G200 V0, G100 P5 A1), pure: the arc voltage a cut should hold, measured at
its start.

Z holds the cut height set over the probed point from the start of the cut, so the voltage
to hold is the one of the first centimetres: a warped plate drifts away under the held
torch, and sampling after the THC delay (as PlasmaC does) put that drift into the target.
So first the mean over a short window (``AutoVoltage.sample``), taken as soon as the
machine is at speed; then, ``fit_window_s`` from the window's start, one correction
(``AutoVoltage.refine``): the voltages since the window began, less what the THC moved Z
(what a held torch would read), fitted against the distance cut (V = a + b * d); ``a`` is
the voltage where XY started, over the probed point. :func:`fitted_voltage` says when the
line is not to be trusted (the mean is kept).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

__all__ = ["AutoVoltage", "FitLimits", "fitted_voltage"]


@dataclass(frozen=True)
class FitLimits:
    """When the fitted line is implausible and the mean is kept (see SequenceConfig)."""

    max_plate_slope_v_per_mm: float  # the plate's slope (mm per mm) through the THC slope
    min_span_mm: float
    max_residual_v: float
    max_slope_change_v_per_mm: float  # first half's slope less the second half's


@dataclass
class AutoVoltage:
    """One cut's estimate: the mean over the first window, then one refinement by the fit."""

    window_s: float
    fit_window_s: float
    limits: FitLimits | None  # None: no fit, the mean stays
    volts: list[float] = field(default_factory=list)
    distances_mm: list[float] = field(default_factory=list)  # distance cut at each sample
    since: float | None = None  # the window's start
    mean_v: float | None = None  # the estimate before the fit refined it
    refined: bool = False

    def sample(
        self, now: float, filtered_v: float | None, distance_mm: float, void: bool
    ) -> float | None:
        """One batch while no target is known: the mean once the window is full, else
        None. A void lock (a kerf, a spike) starts the window again."""
        if void:
            self.volts.clear()
            self.distances_mm.clear()
            self.since = None
            return None
        if self.since is None:
            self.since = now
        if filtered_v is not None:
            self.volts.append(filtered_v)
            self.distances_mm.append(distance_mm)
        if now - self.since >= self.window_s and self.volts:
            self.mean_v = sum(self.volts) / len(self.volts)
            return self.mean_v
        return None

    @property
    def wants_refining(self) -> bool:
        return self.mean_v is not None and not self.refined

    def refine(
        self, now: float, held_v: float | None, distance_mm: float, void: bool
    ) -> float | None:
        """One batch after the mean was taken, ``held_v`` the voltage a held torch would
        read: the refined voltage once, when the fit window is over and the fit is
        plausible; else None (and the mean stays)."""
        if self.limits is None or self.since is None or self.mean_v is None:
            self.refined = True
            return None
        if held_v is not None and not void:
            self.volts.append(held_v)
            self.distances_mm.append(distance_mm)
        if now - self.since < self.fit_window_s:
            return None
        self.refined = True
        return fitted_voltage(self.distances_mm, self.volts, self.limits)


def fitted_voltage(
    distances_mm: Sequence[float], volts: Sequence[float], limits: FitLimits
) -> float | None:
    """The voltage at distance 0 by a least-squares line through (distance, volts), or None
    where the line is implausible: fewer than 3 samples, too short a span, too steep a
    plate, halves that disagree (a start transient still decaying, a bend in the plate),
    too much scatter."""
    n = len(volts)
    if n < 3:
        return None
    mean_v = sum(volts) / n
    mean_d = sum(distances_mm) / n
    sdd = sum((d - mean_d) ** 2 for d in distances_mm)
    if max(distances_mm) - min(distances_mm) < limits.min_span_mm or sdd <= 0.0:
        return None
    pairs = list(zip(distances_mm, volts, strict=True))
    b = sum((d - mean_d) * (v - mean_v) for d, v in pairs) / sdd
    if abs(b) > limits.max_plate_slope_v_per_mm:
        return None
    half = n // 2
    b1 = _slope(distances_mm[:half], volts[:half])
    b2 = _slope(distances_mm[half:], volts[half:])
    if b1 is None or b2 is None or abs(b1 - b2) > limits.max_slope_change_v_per_mm:
        return None
    a = mean_v - b * mean_d
    residual = math.sqrt(sum((v - a - b * d) ** 2 for d, v in pairs) / n)
    if residual > limits.max_residual_v:
        return None
    return a


def _slope(distances_mm: Sequence[float], volts: Sequence[float]) -> float | None:
    """The least-squares slope of volts against distances, None without a spread."""
    n = len(volts)
    if n < 3:
        return None
    mean_d = sum(distances_mm) / n
    mean_v = sum(volts) / n
    sdd = sum((d - mean_d) ** 2 for d in distances_mm)
    if sdd <= 0.0:
        return None
    return sum((d - mean_d) * (v - mean_v) for d, v in zip(distances_mm, volts, strict=True)) / sdd
