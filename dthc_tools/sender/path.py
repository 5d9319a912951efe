"""The program's XY path, as geometry: where the torch is on it, moves along it, the rest of
a segment from a point (PlasmaC's paused motion and cut recovery).

Sans-io. :func:`build_path` traces the plan with :class:`~dthc_bridge.program.xypath.
PathTracer` (the daemon package's, shared with ``check-program --json``): :class:`Segment` s
in millimetres, each knowing its program line, the plan step that moves it and the cut it
belongs to. Arcs stay arcs: a move along one, or the rest of one, is written as ``G2``/``G3``
with its centre, so a split arc is cut as the program drew it."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from dthc_bridge.program.plan import ProgramPlan, Step
from dthc_bridge.program.xypath import PathTracer, Segment, starts_cut

from .backend import BackendError

__all__ = ["PathPoint", "ProgramPath", "Segment", "build_path", "starts_cut"]

ON_PATH_MM = 1.0  # a torch farther than this from every segment is not on the path


@dataclass(frozen=True, slots=True)
class PathPoint:
    segment: int
    s: float  # mm from the segment's start

    def before(self, other: PathPoint) -> bool:
        return (self.segment, self.s) < (other.segment, other.s)


class ProgramPath:
    def __init__(
        self,
        segments: Sequence[Segment],
        *,
        inch: bool,
        arc_absolute: bool,
        cut_steps: Sequence[int] = (),
    ) -> None:
        self.segments = list(segments)
        self.cut_steps = list(cut_steps)  # the plan step that starts each cut (its M3)
        self.scale = 25.4 if inch else 1.0  # mm per program unit
        self.arc_absolute = arc_absolute  # G90.1 somewhere: a split arc cannot be written

    def xy(self, point: PathPoint) -> tuple[float, float]:
        return self.segments[point.segment].point_at(point.s)

    def locate(self, x: float, y: float, *, up_to_step: int | None = None) -> PathPoint:
        """The point of the path nearest (x, y) among the segments queued so far (a later one
        wins a tie: the path may cross itself). BackendError when none is within
        ON_PATH_MM."""
        best: tuple[float, PathPoint] | None = None
        for segment in self.segments:
            if up_to_step is not None and segment.step_index > up_to_step:
                break
            if segment.length <= 0.0:
                continue
            s, distance = segment.project(x, y)
            if best is None or distance <= best[0] + 1e-6:
                best = (distance, PathPoint(segment.index, s))
        if best is None or best[0] > ON_PATH_MM:
            raise BackendError(f"the torch (X{x:.3f} Y{y:.3f}) is not on the program's path")
        return best[1]

    def follow(
        self, x: float, y: float, start: int, *, up_to_step: int, within_mm: float = ON_PATH_MM
    ) -> Segment | None:
        """The segment the torch is on, searched forward from ``start`` (the one it was on)
        among those sent so far: the first within ``within_mm``. None when off the path (a
        restart's move, a recovery offset): the caller keeps what it had."""
        for segment in self.segments[start:]:
            if segment.step_index > up_to_step:
                break
            if segment.project(x, y)[1] <= within_mm:
                return segment
        return None

    def document(self, program: str, *, arc_step_mm: float = 2.0) -> dict[str, Any]:
        """The path as the panel draws it (the retained ``sender/path``): one move per
        segment, in mm, arcs as points ``arc_step_mm`` apart; ``cut`` None for a rapid or a
        move with the torch off."""
        moves: list[dict[str, Any]] = []
        xs: list[float] = []
        ys: list[float] = []
        for segment in self.segments:
            if segment.kind in (2, 3):
                count = max(2, math.ceil(segment.length / arc_step_mm) + 1)
                points = [segment.point_at(segment.length * i / (count - 1)) for i in range(count)]
            else:
                points = [(segment.x0, segment.y0), (segment.x1, segment.y1)]
            rounded = [[round(px, 3), round(py, 3)] for px, py in points]
            xs += [p[0] for p in rounded]
            ys += [p[1] for p in rounded]
            moves.append({"cut": segment.cut, "line": segment.source_line, "points": rounded})
        bounds = [min(xs), min(ys), max(xs), max(ys)] if xs else [0.0, 0.0, 0.0, 0.0]
        return {"program": program, "bounds": bounds, "moves": moves}

    def cut_start(self, point: PathPoint) -> PathPoint:
        """How far back paused motion may go: the start of the cut the point is in (the
        start of its own segment when it is on a rapid)."""
        cut = self.segments[point.segment].cut
        if cut is None:
            return PathPoint(point.segment, 0.0)
        first = next(s for s in self.segments if s.cut == cut)
        return PathPoint(first.index, 0.0)

    def end(self) -> PathPoint:
        last = self.segments[-1]
        return PathPoint(last.index, last.length)

    def walk(self, start: PathPoint, mm: float) -> tuple[PathPoint, float]:
        """The point ``mm`` along the path from ``start`` (negative: backwards) and the
        distance actually available that way (less when the path ends first)."""
        segment, s, left = start.segment, start.s, abs(mm)
        forward = mm >= 0.0
        while True:
            room = self.segments[segment].length - s if forward else s
            if left <= room + 1e-9:
                s = s + left if forward else s - left
                return PathPoint(segment, s), abs(mm)
            left -= room
            if forward and segment + 1 < len(self.segments):
                segment, s = segment + 1, 0.0
            elif not forward and segment > 0:
                segment -= 1
                s = self.segments[segment].length
            else:
                end = PathPoint(segment, self.segments[segment].length if forward else 0.0)
                return end, abs(mm) - left

    def distance(self, a: PathPoint, b: PathPoint) -> float:
        """Path length from ``a`` forward to ``b`` (negative when ``b`` is behind)."""
        if b.before(a):
            return -self.distance(b, a)
        if a.segment == b.segment:
            return b.s - a.s
        total = self.segments[a.segment].length - a.s + b.s
        total += sum(self.segments[i].length for i in range(a.segment + 1, b.segment))
        return total

    def moves(self, start: PathPoint, end: PathPoint, feed_mm_min: float) -> Iterator[str]:
        """The lines that take the torch along the path from ``start`` to ``end``."""
        feed = feed_mm_min / self.scale
        forward = not end.before(start)
        segment, s = start.segment, start.s
        while True:
            seg = self.segments[segment]
            last = segment == end.segment
            to = end.s if last else (seg.length if forward else 0.0)
            if abs(to - s) > 1e-6:
                yield seg.move(s, to, feed, self.scale)
            if last:
                return
            segment += 1 if forward else -1
            s = 0.0 if forward else self.segments[segment].length

    def rest_of(self, point: PathPoint) -> str | None:
        """The rest of the point's segment as the program runs it (its own motion and
        feed), or None when the point is at its end. BackendError for an arc in G90.1."""
        seg = self.segments[point.segment]
        if point.s >= seg.length - 1e-6:
            return None
        if seg.kind in (2, 3) and self.arc_absolute:
            raise BackendError(f"line {seg.source_line}: an arc in G90.1 cannot be split here")
        if seg.kind == 0:
            x, y = seg.x1 / self.scale, seg.y1 / self.scale
            return f"G0 X{x:.4f} Y{y:.4f}"
        assert seg.feed is not None
        return seg.move(point.s, seg.length, seg.feed, self.scale)


def build_path(plan: ProgramPlan, steps: Sequence[Step] | None = None) -> ProgramPath:
    """The path of ``plan`` (a fresh plan: its steps are read here)."""
    tracker = PathTracer(plan)
    for index, step in enumerate(plan.steps() if steps is None else steps):
        tracker.step(index, step)
    return ProgramPath(
        tracker.segments, inch=tracker.inch, arc_absolute=tracker.arc_absolute,
        cut_steps=tracker.cut_steps,
    )  # fmt: skip
