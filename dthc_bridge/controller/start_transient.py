"""The arc's start transient, measured during the pierce: what is left of it later.

After transfer the arc voltage overshoots and decays (0.2 s on a fast machine, 0.5-1.5 s
on others; docs/plasma-facts.md). Auto voltage used to start measuring a fixed 0.5 s after
arc OK; on a cutter that settles in 0.8 s about 2.5 V of overshoot was still there (a
third of a millimetre on the target). During the pierce delay neither the torch nor the
gantry moves, so the voltage's change there is the transient alone: a decay
``V = A + C·exp(-(t - t0)/tau)`` is fitted to the pierce's batches (one median of each
batch, which drops the high-frequency start's one- and two-sample spikes), by least
squares for ``A`` and ``C`` over a grid of ``tau``. Auto voltage then waits until the
predicted remnant ``C·exp(-(t - t0)/tau)`` is small and subtracts what is left.

No model (a remnant of 0) when the pierce was too short to see a decay, the fit does not
find one (no overshoot, or a fit no better than a constant), so the fixed delay alone
applies as before.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

__all__ = ["StartTransient", "TransientFit", "fit_through_transient", "refit_decay"]

_MIN_POINTS = 12  # batches: 60 ms at 5 ms per batch
# Time constants tried: 0.055 s .. about 1.9 s. The fastest cutters settle in 0.2 s (5 %
# left: tau 0.067 s); a faster "decay" is spikes at transfer: on noisy_hf_start seed 18
# two spiked batches there fitted a 0.02 s one that hid the real 0.27 s decay, and auto
# voltage measured 1.4 V of it. Without it those batches are left out as outliers.
_TAUS_S = tuple(0.02 * 1.12**k for k in range(9, 41))
_MIN_IMPROVEMENT = 0.5  # the decay must explain at least half the variance
_OUTLIER_SPREADS = 4.0  # a batch this many median residuals off the first fit is left out


class StartTransient:
    """Fed the pierce's batches (``add``); ``fit`` once the pierce ends; then
    ``remnant_v(t)``."""

    def __init__(self) -> None:
        self.t0_s: float | None = None
        self.times_s: list[float] = []
        self.volts: list[float] = []
        self.overshoot_v = 0.0  # C: the decay's size at t0; 0: no model
        self.tau_s = 0.0

    def add(self, now_s: float, volts: Sequence[float]) -> None:
        if not volts:
            return
        if self.t0_s is None:
            self.t0_s = now_s
        ordered = sorted(volts)
        self.times_s.append(now_s)
        self.volts.append(ordered[len(ordered) // 2])

    def fit(self) -> None:
        """The decay that best fits the pierce's voltages, kept only when it explains them."""
        n = len(self.volts)
        if self.t0_s is None or n < _MIN_POINTS:
            return
        # A spike denser than the batch median removes (the start's interference comes
        # at up to 200 per second) is one batch out of line: a median of three batches,
        # then the batches still far off the first fit are left out of a second.
        v_in = self.volts
        volts = [v_in[0], *(sorted(v_in[i - 1 : i + 2])[1] for i in range(1, n - 1)), v_in[-1]]
        times = list(self.times_s)
        first = _best_decay(self.t0_s, times, volts)
        if first is None:
            return
        residuals = [abs(v - first.at(self.t0_s, t)) for t, v in zip(times, volts, strict=True)]
        spread = sorted(residuals)[n // 2]
        keep = [r <= _OUTLIER_SPREADS * spread + 0.5 for r in residuals]
        times = [t for t, k in zip(times, keep, strict=True) if k]
        volts = [v for v, k in zip(volts, keep, strict=True) if k]
        fit = _best_decay(self.t0_s, times, volts)
        if fit is None or fit.overshoot_v <= 0.0 or fit.explained < _MIN_IMPROVEMENT:
            return  # no overshoot decaying: nothing to wait for
        self.overshoot_v, self.tau_s = fit.overshoot_v, fit.tau_s

    def remnant_v(self, now_s: float, tau_margin: float = 1.0) -> float:
        """What is left of the transient at ``now_s`` (0 without a model); with the time
        constant ``tau_margin`` times the fitted one, a bound for deciding when to measure
        (the pierce's 0.3 s pin the time constant down to about a quarter)."""
        if self.t0_s is None or self.overshoot_v <= 0.0:
            return 0.0
        return self.overshoot_v * math.exp(-(now_s - self.t0_s) / (self.tau_s * tau_margin))


@dataclass(frozen=True)
class _Decay:
    level_v: float
    overshoot_v: float
    tau_s: float
    explained: float  # the share of the voltages' variance the decay explains

    def at(self, t0_s: float, t_s: float) -> float:
        return self.level_v + self.overshoot_v * math.exp(-(t_s - t0_s) / self.tau_s)


def _best_decay(t0_s: float, times_s: Sequence[float], volts: Sequence[float]) -> _Decay | None:
    """``V = A + C·exp(-(t - t0)/tau)`` by least squares, the best ``tau`` of the grid."""
    n = len(volts)
    if n < _MIN_POINTS:
        return None
    mean_v = sum(volts) / n
    total = sum((v - mean_v) ** 2 for v in volts)
    if total <= 0.0:
        return None
    best: _Decay | None = None
    best_sse = math.inf
    for tau in _TAUS_S:
        xs = [math.exp(-(t - t0_s) / tau) for t in times_s]
        mean_x = sum(xs) / n
        sxx = sum((x - mean_x) ** 2 for x in xs)
        if sxx <= 0.0:
            continue
        c = sum((x - mean_x) * (v - mean_v) for x, v in zip(xs, volts, strict=True)) / sxx
        a = mean_v - c * mean_x
        sse = sum((v - a - c * x) ** 2 for x, v in zip(xs, volts, strict=True))
        if sse < best_sse:
            best_sse = sse
            best = _Decay(a, c, tau, 1.0 - sse / total)
    return best


def _joint_fit(
    transient: StartTransient,
    times_s: Sequence[float],
    distances_mm: Sequence[float],
    volts: Sequence[float],
    *,
    with_slope: bool,
    taus_s: Sequence[float] = _TAUS_S,
) -> tuple[float, list[float], float] | None:
    """The pierce's voltages (median of three) and the cut's, one decay shared by both:
    ``V = A_pierce | A_cut [+ b·d] + C·exp(-(t - t0)/tau)``, best ``tau`` of ``taus_s``.
    Returns ``(tau, coefficients, rms residual of the cut's samples)``, or None without a
    pierce model or enough samples."""
    t0 = transient.t0_s
    n_p = len(transient.volts)
    n_c = len(volts)
    if t0 is None or n_p < _MIN_POINTS or n_c < _MIN_POINTS:
        return None
    p_in = transient.volts
    pierce = [p_in[0], *(sorted(p_in[i - 1 : i + 2])[1] for i in range(1, n_p - 1)), p_in[-1]]
    rows_t = [*transient.times_s, *times_s]
    ys = [*pierce, *volts]
    best: tuple[float, float, list[float]] | None = None  # (sse, tau, coefficients)
    for tau in taus_s:
        rows = _design(rows_t, n_p, distances_mm, t0, tau, with_slope=with_slope)
        coef = _least_squares(rows, ys)
        if coef is None:
            continue
        sse = sum((y - _dot(coef, row)) ** 2 for row, y in zip(rows, ys, strict=True))
        if best is None or sse < best[0]:
            best = (sse, tau, coef)
    if best is None:
        return None
    _, tau, coef = best
    rows = _design(rows_t, n_p, distances_mm, t0, tau, with_slope=with_slope)[n_p:]
    residual = math.sqrt(
        sum((y - _dot(coef, row)) ** 2 for row, y in zip(rows, volts, strict=True)) / n_c
    )
    return tau, coef, residual


class TransientFit(NamedTuple):
    level_v: float  # A_cut: the cut's voltage at distance 0, the transient gone
    slope_v_per_mm: float  # b (0 for a flat fit)
    residual_v: float  # rms residual of the cut's samples
    tau_s: float  # the decay's time constant


def fit_through_transient(
    transient: StartTransient,
    times_s: Sequence[float],
    distances_mm: Sequence[float],
    volts: Sequence[float],
    *,
    with_slope: bool,
    tau_s: float | None = None,
) -> TransientFit | None:
    """The cut's voltage at distance 0 with the transient gone, from the pierce's voltages
    and the cut's (``volts``, a held torch's, at ``times_s`` and ``distances_mm``) together:
    ``V = A_pierce | A_cut + b·d + C·exp(-(t - t0)/tau)``, one decay shared by both, best
    ``tau`` on the grid. The pierce sees the decay's start, the cut its tail, so ``tau`` is
    far better pinned down than by the pierce alone. None without a pierce model or enough
    samples. ``tau_s``: that time constant alone, not the grid (a fit made again over more
    of the cut: one solve, not 32, about 30 ms less of the event loop at 400 batches)."""
    taus = _TAUS_S if tau_s is None else (tau_s,)
    fit = _joint_fit(transient, times_s, distances_mm, volts, with_slope=with_slope, taus_s=taus)
    if fit is None:
        return None
    tau, coef, residual = fit
    return TransientFit(coef[1], coef[2] if with_slope else 0.0, residual, tau)


def refit_decay(
    transient: StartTransient, times_s: Sequence[float], volts: Sequence[float]
) -> tuple[float, float, float] | None:
    """The decay seen by the pierce and by the cut's first voltages together (a held torch's,
    ``volts`` at ``times_s``; a flat plate): ``V = A_pierce | A_cut + C·exp(-(t - t0)/tau)``,
    best ``tau`` on the grid. Returns ``(C, tau, rms residual of the cut's samples)``, or
    None without a pierce model with an overshoot or enough samples. The pierce alone sees
    the decay's first 0.3 s and leaves ``tau`` uncertain by a factor of two; its tail pins
    it down."""
    if transient.overshoot_v <= 0.0:
        return None
    fit = _joint_fit(transient, times_s, [0.0] * len(volts), volts, with_slope=False)
    if fit is None:
        return None
    tau, coef, residual = fit
    return coef[2], tau, residual


def _design(
    times_s: Sequence[float],
    n_pierce: int,
    distances_mm: Sequence[float],
    t0: float,
    tau: float,
    *,
    with_slope: bool,
) -> list[list[float]]:
    """Columns: pierce level, cut level, [cut slope by distance], decay."""
    rows = []
    for i, t in enumerate(times_s):
        x = math.exp(-(t - t0) / tau)
        if i < n_pierce:
            rows.append([1.0, 0.0, 0.0, x] if with_slope else [1.0, 0.0, x])
        else:
            d = distances_mm[i - n_pierce]
            rows.append([0.0, 1.0, d, x] if with_slope else [0.0, 1.0, x])
    return rows


def _dot(coef: Sequence[float], row: Sequence[float]) -> float:
    return sum(c * r for c, r in zip(coef, row, strict=True))


def _least_squares(rows: Sequence[Sequence[float]], ys: Sequence[float]) -> list[float] | None:
    """Normal equations solved by Gaussian elimination (3 or 4 unknowns); None if singular."""
    k = len(rows[0])
    m = [[0.0] * (k + 1) for _ in range(k)]
    for row, y in zip(rows, ys, strict=True):
        for i in range(k):
            ri = row[i]
            if ri == 0.0:
                continue
            mi = m[i]
            for j in range(k):
                mi[j] += ri * row[j]
            mi[k] += ri * y
    for col in range(k):
        pivot = max(range(col, k), key=lambda r: abs(m[r][col]))
        if abs(m[pivot][col]) < 1e-12:
            return None
        m[col], m[pivot] = m[pivot], m[col]
        for r in range(k):
            if r != col:
                f = m[r][col] / m[col][col]
                for j in range(col, k + 1):
                    m[r][j] -= f * m[col][j]
    return [m[i][k] / m[i][i] for i in range(k)]
