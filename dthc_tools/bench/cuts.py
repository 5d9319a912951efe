"""What every controller of ``bench control`` shares: the cut plans and the per-run figures.

A plan is one cut per ``G0`` of a scenario's program, with a slow-down appended to the last
one (see :func:`plan_cuts`). A :class:`ControllerResult` holds the plant's ground truth per
cut and the time spent per THC phase, whichever controller ran: the daemon's
(:mod:`.control`) or LinuxCNC's plasmac (:mod:`.plasmac`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from dthc_bridge.controller.words import words
from mock_device.plant.truth import CutStats

__all__ = ["ControllerResult", "CutPlan", "VoidLockTally", "merge", "plan_cuts"]


class VoidLockTally:
    """Void-lock episodes against the plant's truth: an episode that starts with nothing
    under the torch (no kerf or void voltage, :attr:`Arc.gap_voltage_v` 0) is a false lock;
    the longest episode shows a lock that stayed locked."""

    __slots__ = ("_episode_s", "_locked", "false_locks", "locked_s", "locks", "longest_s")

    def __init__(self) -> None:
        self._locked = False
        self._episode_s = 0.0
        self.locks = 0
        self.false_locks = 0
        self.locked_s = 0.0
        self.longest_s = 0.0

    def update(self, locked: bool, gap_v: float, dt_s: float) -> None:
        if locked:
            if not self._locked:
                self.locks += 1
                self._episode_s = 0.0
                if gap_v <= 0.0:
                    self.false_locks += 1
            self._episode_s += dt_s
            self.locked_s += dt_s
            self.longest_s = max(self.longest_s, self._episode_s)
        self._locked = locked


@dataclass(frozen=True)
class CutPlan:
    approach: str  # the rapid to the pierce point, before M3
    lines: tuple[str, ...]  # the cut's motion, torch on
    slow: tuple[str, ...] = ()  # the slowed-down tail, sent after ``lines``
    slow_feed_mm_min: float | None = None
    programmed_feed_mm_min: float | None = None


def plan_cuts(
    program: Sequence[str], *, max_path_mm: float | None = None, slow_percent: float = 50.0
) -> tuple[CutPlan, ...]:
    """One cut per ``G0`` of an absolute (G90) program, a slow-down after the last one.

    ``max_path_mm`` shortens the program (straight moves clipped, later ones dropped).
    """
    cuts: list[tuple[str, list[str]]] = []
    x = y = 0.0
    feed: float | None = None
    travelled = 0.0
    points: list[tuple[float, float]] = []
    end = (x, y)  # where the last cut line ended
    for raw in program:
        w = dict(words(raw))  # the last word of a letter counts
        g = w.get("G")
        if "X" not in w and "Y" not in w:
            continue
        if max_path_mm is not None and travelled >= max_path_mm:
            break
        nx, ny = w.get("X", x), w.get("Y", y)
        if g == 0:
            cuts.append((f"G0 X{nx:g} Y{ny:g}", []))
        else:
            if not cuts:
                raise ValueError(f"cut motion before the first G0: {raw!r}")
            feed = w.get("F", feed)
            length = math.dist((x, y), (nx, ny))
            if max_path_mm is not None and g == 1 and travelled + length > max_path_mm:
                keep = (max_path_mm - travelled) / length
                nx, ny = x + (nx - x) * keep, y + (ny - y) * keep
                line = f"G1 X{nx:.3f} Y{ny:.3f}" + (f" F{feed:g}" if "F" in w else "")
                length = max_path_mm - travelled
            else:
                line = raw.strip()
            travelled += length
            cuts[-1][1].append(line)
            end = (nx, ny)
        points.append((nx, ny))
        x, y = nx, ny
    cuts = [(a, lines) for a, lines in cuts if lines]
    if not cuts or feed is None:
        raise ValueError("the program has no cut")
    plans = [CutPlan(approach, tuple(lines)) for approach, lines in cuts]
    # The slow-down: from the end of the last cut towards the middle of the part.
    cx = (min(p[0] for p in points) + max(p[0] for p in points)) / 2
    cy = (min(p[1] for p in points) + max(p[1] for p in points)) / 2
    x, y = end
    dist = math.dist((x, y), (cx, cy))
    if slow_percent < 100.0 and dist > 1.0:
        length = min(100.0, dist) if max_path_mm is None else min(50.0, dist)
        sx, sy = x + (cx - x) * length / dist, y + (cy - y) * length / dist
        slow_feed = feed * slow_percent / 100.0
        last = plans[-1]
        plans[-1] = CutPlan(
            last.approach,
            last.lines,
            (f"G1 X{sx:.3f} Y{sy:.3f} F{slow_feed:g}",),
            slow_feed,
            feed,
        )
    return tuple(plans)


@dataclass
class ControllerResult:
    cuts: list[CutStats] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    cutting_s: float = 0.0
    locked_s: float = 0.0
    lock_s: dict[str, float] = field(default_factory=dict)
    # Per phase: [seconds, seconds x squared height error], while the gantry moves.
    phase_err: dict[str, list[float]] = field(default_factory=dict)
    completed_cuts: int = 0
    planned_cuts: int = 0
    pauses: list[str] = field(default_factory=list)  # the controller paused the program
    void: VoidLockTally = field(default_factory=VoidLockTally)
    # Per cut that measured one: the controller's voltage at cut height (ours: measured on
    # every cut; plasmac: its auto volts target) less the plant's true one, in volts.
    target_errors_v: list[float] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        n = sum(c.measured_samples for c in self.cuts)
        sum2 = sum(
            c.measured_samples * c.height_rms_error_mm**2 for c in self.cuts if c.measured_samples
        )
        rms = math.sqrt(sum2 / n) if n else None
        worst = max((c.height_max_error_mm for c in self.cuts if c.measured_samples), default=None)
        lowest = min((c.min_height_mm for c in self.cuts), default=None)
        total2 = sum(err2 for _, err2 in self.phase_err.values())
        return {
            "rms_mm": None if rms is None else round(rms, 4),
            "max_mm": None if worst is None else round(worst, 3),
            "min_height_mm": None if lowest is None else round(lowest, 3),
            "dives": sum(c.dives for c in self.cuts),
            "touches": sum(c.touches for c in self.cuts),
            "cutting_s": round(self.cutting_s, 3),
            "locked_s": round(self.locked_s, 3),
            "locks_s": {k: round(v, 3) for k, v in sorted(self.lock_s.items())},
            "measured_s": round(n / 1000.0, 3),
            "rms_by_phase": {
                phase: {
                    "s": round(count, 3),
                    "rms_mm": round(math.sqrt(err2 / count), 4),
                    "share_of_sq_error": round(err2 / total2, 3) if total2 else None,
                }
                for phase, (count, err2) in sorted(self.phase_err.items())
                if count
            },
            "cuts_completed": f"{self.completed_cuts}/{self.planned_cuts}",
            "errors": self.errors,
            "pauses": len(self.pauses),
            "void_locks": self.void.locks,
            "false_locks": self.void.false_locks,
            "void_locked_s": round(self.void.locked_s, 3),
            "longest_void_lock_s": round(self.void.longest_s, 3),
            "target_error_v": _error_figures(self.target_errors_v),
        }


def _error_figures(errors_v: Sequence[float]) -> dict[str, object] | None:
    """Mean (signed), mean and max absolute error of the cut-height voltages, in volts."""
    if not errors_v:
        return None
    return {
        "cuts": len(errors_v),
        "mean_v": round(sum(errors_v) / len(errors_v), 3),
        "mean_abs_v": round(sum(abs(e) for e in errors_v) / len(errors_v), 3),
        "max_abs_v": round(max(abs(e) for e in errors_v), 3),
    }


def merge(results: Sequence[ControllerResult]) -> ControllerResult:
    merged = ControllerResult()
    for r in results:
        merged.cuts += r.cuts
        merged.errors += r.errors
        merged.cutting_s += r.cutting_s
        merged.locked_s += r.locked_s
        for lock, seconds in r.lock_s.items():
            merged.lock_s[lock] = merged.lock_s.get(lock, 0.0) + seconds
        for phase, (count, err2) in r.phase_err.items():
            acc = merged.phase_err.setdefault(phase, [0.0, 0.0])
            acc[0] += count
            acc[1] += err2
        merged.pauses += r.pauses
        merged.void.locks += r.void.locks
        merged.void.false_locks += r.void.false_locks
        merged.void.locked_s += r.void.locked_s
        merged.void.longest_s = max(merged.void.longest_s, r.void.longest_s)
        merged.target_errors_v += r.target_errors_v
        merged.completed_cuts += r.completed_cuts
        merged.planned_cuts += r.planned_cuts
    return merged
