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
line is not to be trusted (the mean is kept). Where that fit found a flat plate (no slope
told from noise, or a flat fit through the start transient's tail), the window goes on to
``flat_window_s`` and, if the plate is still flat over all of it, the target becomes the
same fit over all of it: on a flat plate the 0.3 s window's noise (about ±0.06 V, 0.008
mm) was most of the target's error, and a held torch reads the same voltage for as long
as the plate stays flat.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from .start_transient import StartTransient, TransientFit, fit_through_transient

__all__ = ["AutoVoltage", "FitLimits", "fitted_voltage"]


@dataclass(frozen=True)
class FitLimits:
    """When the fitted line is implausible and the mean is kept (see SequenceConfig)."""

    max_plate_slope_v_per_mm: float  # the plate's slope (mm per mm) through the THC slope
    min_span_mm: float
    max_residual_v: float
    max_slope_change_v_per_mm: float  # first half's slope less the second half's
    min_slope_t: float = 0.0  # a slope within this many standard errors of 0: the mean
    min_slope_v_per_mm: float = 0.0  # ...or below this (a flat plate's noise): the mean
    max_transient_correction_v: float = 2.5  # the pierce-and-cut fit, against the mean
    min_transient_left_v: float = 0.1  # at the window's start, by the pierce's model


@dataclass
class AutoVoltage:
    """One cut's estimate: the mean over the first window, then one refinement by the fit."""

    window_s: float
    fit_window_s: float
    limits: FitLimits | None  # None: no fit, the mean stays
    # The start transient as the pierce measured it: subtracted from every sample, and
    # fitted again with the cut's samples when the fit window ends.
    transient: StartTransient = field(default_factory=StartTransient)
    volts: list[float] = field(default_factory=list)  # the held voltage less the remnant
    distances_mm: list[float] = field(default_factory=list)  # distance cut at each sample
    times_s: list[float] = field(default_factory=list)
    held_v: list[float] = field(default_factory=list)  # the held voltage as it came
    since: float | None = None  # the window's start
    # Time since the window's start without a voltage (a noise burst left out): the windows
    # count the time with voltages, so a burst does not fill them with nothing.
    gap_s: float = 0.0
    last_s: float | None = None  # the previous batch's time
    mean_v: float | None = None  # the estimate before the fit refined it
    refined: bool = False
    # A flat plate: the window goes on to this length (from its start) and the same fit
    # over all of it (the mean, or the flat fit through the transient) replaces the target,
    # once, if the plate is still flat. At most fit_window_s: no longer window.
    flat_window_s: float = 0.0
    extending: bool = False  # the fit found a flat plate; the longer window is running
    through_transient: bool = False  # ...by the fit through the start transient
    tau_s: float | None = None  # ...whose time constant the longer window keeps

    def sample(
        self, now: float, filtered_v: float | None, distance_mm: float, void: bool
    ) -> float | None:
        """One batch while no target is known: the mean once the window is full, else
        None. A void lock (a kerf, a spike) starts the window again."""
        if void:
            for samples in (self.volts, self.distances_mm, self.times_s, self.held_v):
                samples.clear()
            self.since = None
            self.gap_s = 0.0
            self.last_s = now
            return None
        if self.since is None:
            self.since = now
        self._count(now, filtered_v)
        if filtered_v is not None:
            self._keep(now, filtered_v, distance_mm)
        if self._covered_s(now) >= self.window_s and self.volts:
            self.mean_v = sum(self.volts) / len(self.volts)
            return self.mean_v
        return None

    @property
    def wants_refining(self) -> bool:
        return self.mean_v is not None and (not self.refined or self.extending)

    def refine(
        self, now: float, held_v: float | None, distance_mm: float, void: bool
    ) -> float | None:
        """One batch after the mean was taken, ``held_v`` the voltage a held torch would
        read: the refined voltage when the fit window is over and the fit is plausible,
        and on a flat plate once more when the longer window is; else None (the estimate
        stays)."""
        if self.limits is None or self.since is None or self.mean_v is None:
            self.refined = True
            return None
        self._count(now, held_v)  # a void lock's batches count (a kerf, not a gap)
        if held_v is not None and not void:
            self._keep(now, held_v, distance_mm)
        if self.extending:
            return self._flat_mean(now, self.limits)
        if self._covered_s(now) < self.fit_window_s:
            return None
        self.refined = True
        line = line_fit(self.distances_mm, self.volts, self.limits)
        longer = self.flat_window_s > self.fit_window_s
        through = self._through_transient(self.limits, line)
        if through is not None:
            level_v, flat = through
            self.extending = self.through_transient = flat and longer
            return level_v
        if line is None:
            return None
        # A flat plate (line_fit gives slope 0 where no slope is told from noise).
        self.extending = line[1] == 0.0 and longer
        return line[0]

    def _flat_mean(self, now: float, limits: FitLimits) -> float | None:
        """The longer window on a flat plate: at its end, the mean of all of it (or the flat
        fit through the start transient over all of it) where the plate is still flat over
        all of it; else the fit window's target stays."""
        if self._covered_s(now) < self.flat_window_s:
            return None
        self.extending = False
        if self.through_transient:
            # The time constant the fit window found: the longer window refits the levels
            # and the slope only (a solve per fit, not the grid's 32, in the event loop).
            args = (self.transient, self.times_s, self.distances_mm, self.held_v)
            sloped = fit_through_transient(*args, with_slope=True, tau_s=self.tau_s)
            if sloped is None or abs(sloped.slope_v_per_mm) > limits.min_slope_v_per_mm:
                return None  # the plate bent or tilted later
            flat = fit_through_transient(*args, with_slope=False, tau_s=self.tau_s)
            return flat.level_v if flat is not None and _plausible(flat, limits) else None
        line = line_fit(self.distances_mm, self.volts, limits)
        if line is None or line[1] != 0.0:
            return None  # the plate bent or tilted later: what was fitted near 0 is better
        return line[0]

    def _count(self, now: float, held_v: float | None) -> None:
        """The time since the previous batch is a gap when this batch has no voltage."""
        if held_v is None and self.last_s is not None and self.since is not None:
            self.gap_s += now - max(self.last_s, self.since)
        self.last_s = now

    def _covered_s(self, now: float) -> float:
        """Time since the window's start with voltages."""
        assert self.since is not None
        return now - self.since - self.gap_s

    def _keep(self, now: float, held_v: float, distance_mm: float) -> None:
        self.times_s.append(now)
        self.held_v.append(held_v)
        self.volts.append(held_v - self.transient.remnant_v(now))
        self.distances_mm.append(distance_mm)

    def _through_transient(
        self, limits: FitLimits, line: tuple[float, float] | None
    ) -> tuple[float, bool] | None:
        """The pierce's and the cut's voltages fitted together (start_transient): with a
        plate slope where the line fit found one, else flat (a line through a decay's tail
        and noise over 30 mm is mostly noise: measured, docs/benchmarks.md); None where
        there is no pierce model or it does not fit (the line fit alone then decides).
        ``(voltage, flat)``: flat where the fit had no slope."""
        args = (self.transient, self.times_s, self.distances_mm, self.held_v)
        # Only where a decay may still be going on (the pierce's model leaves some of it at
        # the window's start, or found none in the noise): otherwise the line fit is the
        # better judge, and a decay term would take up the plate's drift.
        transient = self.transient
        decaying = transient.overshoot_v <= 0.0 or (
            bool(self.times_s)
            and transient.remnant_v(self.times_s[0]) >= limits.min_transient_left_v
        )
        flat_plate = line is not None and line[1] == 0.0
        if not decaying:
            return None
        if line is not None and not flat_plate:
            sloped = fit_through_transient(*args, with_slope=True)
            if sloped is not None and _plausible(sloped, limits):
                return sloped.level_v, False
        flat = fit_through_transient(*args, with_slope=False)
        if flat is None or not _plausible(flat, limits) or self.mean_v is None:
            return None
        # A flat fit far from the first mean took a plate's drift for the decay's tail.
        if abs(flat.level_v - self.mean_v) > limits.max_transient_correction_v:
            return None
        self.tau_s = flat.tau_s
        return flat.level_v, True


def _plausible(fit: TransientFit, limits: FitLimits) -> bool:
    return (
        abs(fit.slope_v_per_mm) <= limits.max_plate_slope_v_per_mm
        and fit.residual_v <= limits.max_residual_v
    )


def fitted_voltage(
    distances_mm: Sequence[float], volts: Sequence[float], limits: FitLimits
) -> float | None:
    """See :func:`line_fit`: its voltage."""
    fit = line_fit(distances_mm, volts, limits)
    return None if fit is None else fit[0]


def line_fit(
    distances_mm: Sequence[float], volts: Sequence[float], limits: FitLimits
) -> tuple[float, float] | None:
    """The voltage at distance 0 by a least-squares line through (distance, volts), or None
    where the line is implausible: fewer than 3 samples, too short a span, too steep a
    plate, too much scatter, halves that disagree (a start transient still decaying, a bend
    in the plate) about a slope told from noise. ``(voltage, slope)``: a slope of 0 where
    the mean is returned (a slope not told from noise)."""
    n = len(volts)
    if n < 3:
        return None
    mean_v = sum(volts) / n
    mean_d = sum(distances_mm) / n
    sdd = sum((d - mean_d) ** 2 for d in distances_mm)
    if max(distances_mm) - min(distances_mm) < limits.min_span_mm or sdd <= 0.0:
        return None
    pairs = list(zip(distances_mm, volts, strict=True))
    b = _slope(distances_mm, volts)
    if b is None or abs(b) > limits.max_plate_slope_v_per_mm:
        return None
    a = mean_v - b * mean_d
    residual = math.sqrt(sum((v - a - b * d) ** 2 for d, v in pairs) / n)
    if residual > limits.max_residual_v:
        return None
    # No slope to tell from noise (a flat plate): the mean, a few times less noisy than
    # the line's value at distance 0. Judged before the halves: on a flat plate halves
    # that disagree are noise, or what is left of a start transient, and the whole
    # window's mean holds less of either than the first window's.
    slope_error = residual * math.sqrt(n / max(1, n - 2) / sdd)
    if abs(b) < max(limits.min_slope_t * slope_error, limits.min_slope_v_per_mm):
        return mean_v, 0.0
    half = n // 2
    b1 = _slope(distances_mm[:half], volts[:half])
    b2 = _slope(distances_mm[half:], volts[half:])
    if b1 is None or b2 is None or abs(b1 - b2) > limits.max_slope_change_v_per_mm:
        return None
    return a, b


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
