"""The program's XY path, as geometry: where the torch is on it, moves along it, the rest of
a segment from a point (PlasmaC's paused motion and cut recovery).

Sans-io. :func:`build_path` reads the plan's motion lines (units, G90/G91, G0-G3 with I J,
feed) and the daemon's lines (a cut runs from its M3 to its M5) into :class:`Segment` s in
millimetres, each knowing its program line, the plan step that moves it and the cut it
belongs to. Arcs stay arcs: a move along one, or the rest of one, is written as ``G2``/``G3``
with its centre, so a split arc is cut as the program drew it."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from dthc_bridge.controller.commands import (
    Command,
    CommandError,
    ProbeAndStart,
    TorchStart,
    TorchStop,
)
from dthc_bridge.controller.gcode import parse_line
from dthc_bridge.controller.words import tokenize
from dthc_bridge.program.plan import DaemonStep, MotionStep, ProgramPlan, Step

from .backend import BackendError

__all__ = ["PathPoint", "ProgramPath", "Segment", "build_path", "starts_cut"]

ON_PATH_MM = 1.0  # a torch farther than this from every segment is not on the path
_NOT_TARGETS = frozenset({10.0, 28.0, 28.1, 30.0, 30.1, 53.0, 92.0, 92.1})
TAU = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class Segment:
    index: int
    kind: int  # 0 rapid, 1 line, 2 clockwise arc, 3 counter-clockwise arc
    x0: float
    y0: float
    x1: float
    y1: float
    feed: float | None  # as programmed: program units per minute
    source_line: int
    step_index: int  # the plan step (0-based, in the order ProgramPlan.steps gives)
    cut: int | None  # 0-based index of the cut it belongs to; None: the torch is off
    cx: float = 0.0  # arcs: the centre
    cy: float = 0.0
    sweep: float = 0.0  # arcs: signed angle, radians (clockwise negative)

    @property
    def radius(self) -> float:
        return math.hypot(self.x0 - self.cx, self.y0 - self.cy)

    @property
    def length(self) -> float:
        if self.kind in (2, 3):
            return abs(self.sweep) * self.radius
        return math.hypot(self.x1 - self.x0, self.y1 - self.y0)

    def point_at(self, s: float) -> tuple[float, float]:
        """The point ``s`` mm from the segment's start (clamped to it)."""
        length = self.length
        f = 0.0 if length <= 0.0 else min(max(s / length, 0.0), 1.0)
        if self.kind in (2, 3):
            a = math.atan2(self.y0 - self.cy, self.x0 - self.cx) + self.sweep * f
            return self.cx + self.radius * math.cos(a), self.cy + self.radius * math.sin(a)
        return self.x0 + (self.x1 - self.x0) * f, self.y0 + (self.y1 - self.y0) * f

    def project(self, x: float, y: float) -> tuple[float, float]:
        """(s, distance): the nearest point of the segment to (x, y)."""
        length = self.length
        if length <= 0.0:
            return 0.0, math.hypot(x - self.x0, y - self.y0)
        if self.kind in (2, 3):
            a0 = math.atan2(self.y0 - self.cy, self.x0 - self.cx)
            ap = math.atan2(y - self.cy, x - self.cx)
            along = (ap - a0) % TAU if self.sweep > 0 else (a0 - ap) % TAU
            if along <= abs(self.sweep):
                s = along * self.radius
            else:  # beyond an end: the nearer end
                s = min((0.0, length), key=lambda e: math.dist(self.point_at(e), (x, y)))
        else:
            ux, uy = (self.x1 - self.x0) / length, (self.y1 - self.y0) / length
            s = min(max((x - self.x0) * ux + (y - self.y0) * uy, 0.0), length)
        return s, math.dist(self.point_at(s), (x, y))

    def move(self, s_from: float, s_to: float, feed: float, scale: float) -> str:
        """The line that runs the segment from ``s_from`` to ``s_to`` (backwards when
        ``s_to`` is smaller), at ``feed`` (program units/min), in program units."""
        x, y = self.point_at(s_to)
        target = f"X{x / scale:.4f} Y{y / scale:.4f}"
        if self.kind in (2, 3):
            px, py = self.point_at(s_from)
            forward = s_to >= s_from
            clockwise = (self.kind == 2) == forward
            centre = f"I{(self.cx - px) / scale:.4f} J{(self.cy - py) / scale:.4f}"
            return f"G{2 if clockwise else 3} {target} {centre} F{feed:g}"
        return f"G1 {target} F{feed:g}"


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


def starts_cut(command: Command) -> bool:
    """M3, or RosettaCNC G100 P6 in a mode that starts the torch (I0/I1; I2/I3 set values)."""
    return isinstance(command, TorchStart) or (
        isinstance(command, ProbeAndStart) and command.mode in (0, 1)
    )


def build_path(plan: ProgramPlan, steps: Sequence[Step] | None = None) -> ProgramPath:
    """The path of ``plan`` (a fresh plan: its steps are read here)."""
    tracker = _Tracker(plan)
    for index, step in enumerate(plan.steps() if steps is None else steps):
        tracker.step(index, step)
    return ProgramPath(
        tracker.segments, inch=tracker.inch, arc_absolute=tracker.arc_absolute,
        cut_steps=tracker.cut_steps,
    )  # fmt: skip


class _Tracker:
    def __init__(self, plan: ProgramPlan) -> None:
        self.plan = plan
        self.segments: list[Segment] = []
        self.scale = 1.0
        self.absolute = True
        self.arc_abs = False
        self.arc_absolute = False
        self.motion = 0
        self.feed: float | None = None
        self.x = self.y = 0.0
        self.cut: int | None = None
        self.cut_steps: list[int] = []

    @property
    def inch(self) -> bool:
        return self.scale != 1.0

    def step(self, index: int, step: Step) -> None:
        if isinstance(step, DaemonStep) and not step.feed_note:
            self._daemon(index, step)
        elif isinstance(step, MotionStep):
            self._motion(index, step)

    def _daemon(self, index: int, step: DaemonStep) -> None:
        try:
            parsed = parse_line(step.line, line_number=step.source_line, dialect=self.plan.dialect)
        except CommandError:
            return
        for command in parsed.commands:
            if starts_cut(command):
                self.cut = len(self.cut_steps)
                self.cut_steps.append(index)
            elif isinstance(command, TorchStop):
                self.cut = None

    def _motion(self, index: int, step: MotionStep) -> None:
        coords: dict[str, float] = {}
        codes: set[float] = set()
        for word in tokenize(step.line).words:
            if word.letter == "G":
                codes.add(word.value)
            elif word.letter in "XYIJ":
                coords[word.letter] = word.value
            elif word.letter == "F":
                self.feed = word.value
        for code in codes:
            if code in (20.0, 21.0):
                self.scale = 25.4 if code == 20.0 else 1.0
            elif code in (90.0, 91.0):
                self.absolute = code == 90.0
            elif code in (90.1, 91.1):
                self.arc_abs = code == 90.1
                self.arc_absolute |= self.arc_abs
            elif code in (0.0, 1.0, 2.0, 3.0):
                self.motion = int(code)
        if codes & _NOT_TARGETS or not ("X" in coords or "Y" in coords):
            return
        k = self.scale
        x0, y0 = self.x, self.y
        x1 = (coords["X"] * k if self.absolute else x0 + coords["X"] * k) if "X" in coords else x0
        y1 = (coords["Y"] * k if self.absolute else y0 + coords["Y"] * k) if "Y" in coords else y0
        self.x, self.y = x1, y1
        cx = cy = sweep = 0.0
        if self.motion in (2, 3):
            if self.arc_abs:
                cx, cy = coords.get("I", x0 / k) * k, coords.get("J", y0 / k) * k
            else:
                cx, cy = x0 + coords.get("I", 0.0) * k, y0 + coords.get("J", 0.0) * k
            sweep = math.atan2(y1 - cy, x1 - cx) - math.atan2(y0 - cy, x0 - cx)
            if self.motion == 2 and sweep >= -1e-12:
                sweep -= TAU
            elif self.motion == 3 and sweep <= 1e-12:
                sweep += TAU
        self.segments.append(
            Segment(
                index=len(self.segments), kind=self.motion, x0=x0, y0=y0, x1=x1, y1=y1,
                feed=self.feed, source_line=step.source_line, step_index=index, cut=self.cut,
                cx=cx, cy=cy, sweep=sweep,
            )
        )  # fmt: skip
