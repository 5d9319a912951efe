"""A program's planned XY path as geometry: the moves of a :class:`~.plan.ProgramPlan`, in
millimetres, in program order.

Sans-io. :class:`PathTracer` reads the plan's steps one at a time (motion lines: units,
G90/G91, G90.1/G91.1, G0-G3 with I J or R, and P turns; daemon lines: a cut runs from its M3
to its M5) and keeps a :class:`Segment` per planned XY move, each knowing its program line,
the plan step that moves it and the cut it belongs to. Arcs stay arcs (centre and signed
sweep). A G28/G30 return (to a position kept in the machine's parameters) is not traced.

``dthc-bridge check-program --json`` reports the segments (:func:`path_entries`); the
reference sender (``dthc_tools.sender.path``) builds its path, where the torch is on it and
how to move along it, on the same segments.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..controller.commands import Command, ProbeAndStart, TorchStart, TorchStop
from .modal import ModalState
from .plan import DaemonStep, MotionStep, ProgramPlan, Step

__all__ = ["KIND_NAMES", "PathTracer", "Segment", "path_entries", "radius_centre", "starts_cut"]

TAU = 2.0 * math.pi
# G codes whose X/Y words are not a move's target (G10 L20 X, G28 X, G92 X, ...).
_NOT_TARGETS = frozenset({10.0, 28.0, 28.1, 30.0, 30.1, 53.0, 92.0, 92.1})
KIND_NAMES = ("rapid", "feed", "arc", "arc")  # by Segment.kind


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

    def entry(self) -> dict[str, Any]:
        """The move as ``check-program --json`` gives it (mm; arcs with centre and sense)."""
        out: dict[str, Any] = {
            "line": self.source_line,
            "kind": KIND_NAMES[self.kind],
            "from": [self.x0, self.y0],
            "to": [self.x1, self.y1],
        }
        if self.kind in (2, 3):
            out["center"] = [self.cx, self.cy]
            out["cw"] = self.kind == 2
            turns = math.ceil(abs(self.sweep) / TAU - 1e-9)
            if turns > 1:  # G2 P<turns>: whole turns beyond the first
                out["turns"] = turns
        return out


def radius_centre(
    x0: float, y0: float, x1: float, y1: float, radius: float, *, clockwise: bool
) -> tuple[float, float]:
    """The centre of an arc given by its radius (``G2 X Y R``), as LinuxCNC's interpreter
    finds it (``arc_data_r``): a positive R is the arc of less than half a turn, a negative
    R the longer one; an R a little short of half the chord is a semicircle."""
    abs_radius = abs(radius)
    mid_x, mid_y = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    half_length = math.hypot(mid_x - x1, mid_y - y1)
    if abs_radius <= 0.0 or half_length / abs_radius > 1.0 - 1e-12:
        half_length = abs_radius
    theta = math.atan2(y1 - y0, x1 - x0)
    theta += -math.pi / 2 if clockwise == (radius > 0) else math.pi / 2
    offset = abs_radius * math.cos(math.asin(half_length / abs_radius)) if abs_radius else 0.0
    return mid_x + offset * math.cos(theta), mid_y + offset * math.sin(theta)


def starts_cut(command: Command) -> bool:
    """M3, or RosettaCNC G100 P6 in a mode that starts the torch (I0/I1; I2/I3 set values)."""
    return isinstance(command, TorchStart) or (
        isinstance(command, ProbeAndStart) and command.mode in (0, 1)
    )


def path_entries(segments: Sequence[Segment]) -> list[dict[str, Any]]:
    return [segment.entry() for segment in segments]


class PathTracer:
    """Feed it every step of a plan, in order (:meth:`step`); ``segments`` is the path so
    far. A line the dialect cannot parse changes no cut."""

    def __init__(self, plan: ProgramPlan) -> None:
        self.plan = plan
        self.segments: list[Segment] = []
        self.modal = ModalState()
        self.arc_absolute = False  # G90.1 somewhere in the program
        self.x = self.y = 0.0
        self.cut: int | None = None
        self.cut_steps: list[int] = []  # the plan step that starts each cut (its M3)

    @property
    def inch(self) -> bool:
        return self.modal.inches

    def step(self, index: int, step: Step) -> None:
        if isinstance(step, DaemonStep) and not step.feed_note:
            self._daemon(index, step)
        elif isinstance(step, MotionStep):
            self._motion(index, step)

    def _daemon(self, index: int, step: DaemonStep) -> None:
        for command in step.parsed.commands:
            if starts_cut(command):
                self.cut = len(self.cut_steps)
                self.cut_steps.append(index)
            elif isinstance(command, TorchStop):
                self.cut = None

    def _motion(self, index: int, step: MotionStep) -> None:
        modal = self.modal
        modal.apply((w.letter, w.value) for w in step.words)
        self.arc_absolute |= modal.arc_absolute
        codes = {w.value for w in step.words if w.letter == "G"}
        coords = {w.letter: w.value for w in step.words if w.letter in "XYIJRP"}
        if codes & _NOT_TARGETS or not ("X" in coords or "Y" in coords):
            return
        x0, y0 = self.x, self.y
        x1, y1 = modal.xy_target(x0, y0, coords)
        self.x, self.y = x1, y1
        cx = cy = sweep = 0.0
        if modal.motion in (2, 3):
            clockwise = modal.motion == 2
            if "R" in coords:
                radius = modal.to_mm(coords["R"])
                cx, cy = radius_centre(x0, y0, x1, y1, radius, clockwise=clockwise)
            else:
                cx, cy = modal.arc_centre(x0, y0, coords)
            sweep = math.atan2(y1 - cy, x1 - cx) - math.atan2(y0 - cy, x0 - cx)
            if clockwise and sweep >= -1e-12:
                sweep -= TAU
            elif not clockwise and sweep <= 1e-12:
                sweep += TAU
            extra_turns = max(round(coords.get("P", 1.0)), 1) - 1  # G2 P3: two more turns
            sweep += (-TAU if clockwise else TAU) * extra_turns
        self.segments.append(
            Segment(
                index=len(self.segments), kind=modal.motion, x0=x0, y0=y0, x1=x1, y1=y1,
                feed=modal.feed_in_units, source_line=step.source_line, step_index=index,
                cut=self.cut, cx=cx, cy=cy, sweep=sweep,
            )
        )  # fmt: skip
