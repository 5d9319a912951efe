"""XY gantry: a small G-code motion planner and a per-step executor.

``feed_line`` turns G0/G1/G2/G3 lines into straight segments (arcs as chords no longer than
``arc_chord_mm``). Each segment's entry speed is capped at the junction speed of the grbl
junction-deviation model, ``v² = a·δ·sin(θ/2)/(1 - sin(θ/2))`` with θ the angle between
the reversed incoming and the outgoing direction (180° = straight on), and by the
neighbouring feeds; a backward pass over the queue makes every segment's entry speed
reachable from a stop at the end of the queue. Arc chords are also capped at the
centripetal limit ``sqrt(a·r)``.

The executor integrates the path speed per step: it accelerates at ``accel_mm_s2`` towards
the segment's feed and follows a discrete-time braking curve towards the next segment's
entry speed, so the tangential acceleration never exceeds the limit.
"""

import dataclasses
import math
from collections import deque
from collections.abc import Iterable

from dthc_bridge.controller.words import GcodeSyntaxError, words
from dthc_bridge.program.modal import ModalState

from .scenario import GantrySpec

__all__ = ["Gantry", "GcodeError", "Segment"]


class GcodeError(ValueError):
    """A G-code line the planner cannot run; nothing was queued."""

    def __init__(self, line: str, reason: str) -> None:
        self.line = line
        self.reason = reason
        super().__init__(f"{reason}: {line!r}")


class Segment:
    """One straight move at a constant programmed feed."""

    __slots__ = ("entry_mm_s", "feed_mm_s", "length_mm", "max_entry_mm_s", "ux", "uy", "x0", "y0")

    def __init__(
        self,
        x0: float,
        y0: float,
        x1: float,
        y1: float,
        *,
        feed_mm_s: float,
        max_entry_mm_s: float = 0.0,
    ) -> None:
        self.x0 = x0
        self.y0 = y0
        length = math.hypot(x1 - x0, y1 - y0)
        self.length_mm = length
        self.ux = (x1 - x0) / length
        self.uy = (y1 - y0) / length
        self.feed_mm_s = feed_mm_s
        self.max_entry_mm_s = max_entry_mm_s
        self.entry_mm_s = 0.0

    @property
    def end(self) -> tuple[float, float]:
        """End point of the segment."""
        return self.x0 + self.ux * self.length_mm, self.y0 + self.uy * self.length_mm


class Gantry:
    """XY motion of the table, fed with G-code motion lines, advanced by ``step``."""

    __slots__ = (
        "_accel",
        "_chord_mm",
        "_cur",
        "_delta",
        "_held",
        "_modal",
        "_plan_dt_s",
        "_px",
        "_py",
        "_queue",
        "_rapid_mm_s",
        "_s_rem",
        "_tail",
        "requested_feed_mm_s",
        "speed_mm_s",
        "x_mm",
        "y_mm",
    )

    def __init__(
        self,
        *,
        accel_mm_s2: float = 1500.0,
        rapid_mm_min: float = 10000.0,
        junction_deviation_mm: float = 0.05,
        arc_chord_mm: float = 0.5,
        x_mm: float = 0.0,
        y_mm: float = 0.0,
        plan_dt_s: float = 0.001,
    ) -> None:
        self._plan_dt_s = plan_dt_s
        self._accel = accel_mm_s2
        self._rapid_mm_s = rapid_mm_min / 60.0
        self._delta = junction_deviation_mm
        self._chord_mm = arc_chord_mm
        self.x_mm = x_mm
        self.y_mm = y_mm
        self.speed_mm_s = 0.0
        self.requested_feed_mm_s = 0.0
        self._queue: deque[Segment] = deque()
        self._cur: Segment | None = None
        self._tail: Segment | None = None
        self._s_rem = 0.0
        self._held = False
        # The program's modal state (as every reader of a program keeps it) and the
        # planned end point.
        self._modal = ModalState()
        self._px = x_mm
        self._py = y_mm

    @classmethod
    def from_spec(cls, spec: GantrySpec) -> "Gantry":
        """A gantry with the scenario's limits at its start position."""
        return cls(
            accel_mm_s2=spec.accel_mm_s2,
            rapid_mm_min=spec.rapid_mm_min,
            junction_deviation_mm=spec.junction_deviation_mm,
            arc_chord_mm=spec.arc_chord_mm,
            x_mm=spec.start_x_mm,
            y_mm=spec.start_y_mm,
        )

    # ----------------------------------------------------------------- outputs
    @property
    def position_mm(self) -> tuple[float, float]:
        """Current (x, y)."""
        return self.x_mm, self.y_mm

    @property
    def accel_mm_s2(self) -> float:
        """Path acceleration limit."""
        return self._accel

    @property
    def idle(self) -> bool:
        """True when nothing is queued or running and the gantry stands still."""
        return self._cur is None and not self._queue and self.speed_mm_s == 0.0

    @property
    def queue_len(self) -> int:
        """Segments not finished yet, the running one included."""
        return len(self._queue) + (self._cur is not None)

    @property
    def held(self) -> bool:
        """True while a feed hold is requested."""
        return self._held

    def junction_speed_mm_s(self, ux0: float, uy0: float, ux1: float, uy1: float) -> float:
        """Junction speed limit between two unit directions (inf when straight on)."""
        cos_theta = -(ux0 * ux1 + uy0 * uy1)
        if cos_theta <= -0.999999:
            return math.inf
        sin_half = math.sqrt(max(0.0, 0.5 * (1.0 - cos_theta)))
        if sin_half <= 1e-9:
            return 0.0
        return math.sqrt(self._accel * self._delta * sin_half / (1.0 - sin_half))

    # ------------------------------------------------------------------ control
    def hold(self) -> None:
        """Feed hold: decelerate along the path to a stop and wait for ``resume``."""
        self._held = True

    def resume(self) -> None:
        """Release a feed hold."""
        self._held = False

    def clear(self) -> None:
        """Abort: drop every queued and running segment and stand still where it is."""
        self._queue.clear()
        self._cur = None
        self._tail = None
        self._s_rem = 0.0
        self.speed_mm_s = 0.0
        self.requested_feed_mm_s = 0.0
        self._px = self.x_mm
        self._py = self.y_mm

    # ------------------------------------------------------------------ parsing
    def feed_program(self, lines: Iterable[str]) -> int:
        """Feed several lines; return the number of segments queued."""
        return sum(self.feed_line(line) for line in lines)

    def feed_line(self, line: str) -> int:
        """Parse one G-code line and queue its motion; return the number of segments added.

        Understands G0/G1/G2/G3 (X Y, I J, F in units/min), G90/G91, G90.1/G91.1, G20/G21;
        ignores other words (M, S, T, N, Z, ...); words and comments are read as the daemon
        reads them (:mod:`dthc_bridge.controller.words`). Raises ``GcodeError`` and queues
        nothing for lines it cannot run.
        """
        try:
            pairs = words(line)
        except GcodeSyntaxError as exc:
            raise GcodeError(line, f"unparseable text ({exc})") from None
        coords: dict[str, float] = {}
        for letter, value in pairs:
            if letter == "G" and value in (18.0, 19.0):
                raise GcodeError(line, "only the XY plane (G17) is supported")
            if letter in "XYIJ":
                if letter in coords:
                    raise GcodeError(line, f"{letter} given twice")
                coords[letter] = value
            elif letter == "F" and value <= 0.0:
                raise GcodeError(line, "feed rate must be positive")
            elif letter == "R":
                raise GcodeError(line, "R-form arcs are not supported, use I J")
        modal = dataclasses.replace(self._modal)
        modal.apply(pairs)
        motion, feed = modal.motion, modal.feed_mm_min
        has_xy = "X" in coords or "Y" in coords
        if motion in (1, 2, 3) and has_xy and feed is None:
            raise GcodeError(line, "no feed rate (F) programmed")
        if motion in (2, 3) and has_xy and "I" not in coords and "J" not in coords:
            raise GcodeError(line, "arc without I or J")
        self._modal = modal  # the line is valid: its modal state holds, then its motion queues
        if not has_xy:
            return 0
        x0, y0 = self._px, self._py
        x1, y1 = modal.xy_target(x0, y0, coords)
        if motion == 0:
            return self._queue_points([(x1, y1)], self._rapid_mm_s)
        assert feed is not None
        feed_mm_s = feed / 60.0
        if motion == 1:
            return self._queue_points([(x1, y1)], feed_mm_s)
        cx, cy = modal.arc_centre(x0, y0, coords)
        points, radius = self._arc_points(x0, y0, x1, y1, cx=cx, cy=cy, clockwise=motion == 2)
        return self._queue_points(points, min(feed_mm_s, math.sqrt(self._accel * radius)))

    def _arc_points(
        self, x0: float, y0: float, x1: float, y1: float, *, cx: float, cy: float, clockwise: bool
    ) -> tuple[list[tuple[float, float]], float]:
        radius = math.hypot(x0 - cx, y0 - cy)
        if radius <= 1e-9:
            return [(x1, y1)], math.inf
        a0 = math.atan2(y0 - cy, x0 - cx)
        a1 = math.atan2(y1 - cy, x1 - cx)
        sweep = a1 - a0
        if clockwise:
            if sweep >= -1e-12:
                sweep -= 2.0 * math.pi
        elif sweep <= 1e-12:
            sweep += 2.0 * math.pi
        n = max(1, math.ceil(abs(sweep) * radius / self._chord_mm))
        points = [
            (cx + radius * math.cos(a0 + sweep * i / n), cy + radius * math.sin(a0 + sweep * i / n))
            for i in range(1, n)
        ]
        points.append((x1, y1))
        return points, radius

    def _queue_points(self, points: list[tuple[float, float]], feed_mm_s: float) -> int:
        added = 0
        x0, y0 = self._px, self._py
        tail = self._tail
        for x1, y1 in points:
            if math.hypot(x1 - x0, y1 - y0) < 1e-9:
                continue
            seg = Segment(x0, y0, x1, y1, feed_mm_s=feed_mm_s)
            if tail is not None:
                junction = self.junction_speed_mm_s(tail.ux, tail.uy, seg.ux, seg.uy)
                seg.max_entry_mm_s = min(junction, tail.feed_mm_s, feed_mm_s)
            self._queue.append(seg)
            tail = seg
            added += 1
            x0, y0 = x1, y1
        self._tail = tail
        self._px, self._py = x0, y0
        if added:
            self._replan(added)
        return added

    def _replan(self, added: int) -> None:
        """Backward pass: entry speeds from which a stop at the end of the queue is reachable.

        Uses the executor's discrete braking curve at the nominal sample period, so the
        planned speeds are the ones the per-step executor can actually shed.
        """
        dt = self._plan_dt_s
        exit_v = 0.0
        for i, seg in enumerate(reversed(self._queue)):
            entry = min(seg.max_entry_mm_s, self._brake_speed(seg.length_mm, exit_v, dt))
            if i >= added and entry == seg.entry_mm_s:
                break
            seg.entry_mm_s = entry
            exit_v = entry

    def _brake_speed(self, distance_mm: float, exit_mm_s: float, dt_s: float) -> float:
        """Largest speed from which shedding accel·dt per step reaches ``exit`` in ``distance``.

        Braking from ``exit + n·a·dt`` covers ``dt·(n·exit + a·dt·n(n+1)/2)``; solved for n.
        """
        half_adt2 = 0.5 * self._accel * dt_s * dt_s
        b = exit_mm_s * dt_s + half_adt2
        return exit_mm_s + (math.sqrt(b * b + 4.0 * half_adt2 * distance_mm) - b) / dt_s

    # ---------------------------------------------------------------- execution
    def step(self, dt_s: float) -> None:
        """Advance the motion by ``dt_s`` seconds."""
        seg = self._cur
        queue = self._queue
        if seg is None:
            if not queue:
                self.speed_mm_s = 0.0
                self.requested_feed_mm_s = 0.0
                return
            seg = queue.popleft()
            self._cur = seg
            self._s_rem = seg.length_mm
        v = self.speed_mm_s
        dv = self._accel * dt_s
        s_rem = self._s_rem
        if self._held:
            want = 0.0
        else:
            exit_v = queue[0].entry_mm_s if queue else 0.0
            # Discrete braking curve (see _brake_speed), inlined: this is the hot path.
            half_adt2 = 0.5 * dv * dt_s
            b = exit_v * dt_s + half_adt2
            want = exit_v + (math.sqrt(b * b + 4.0 * half_adt2 * s_rem) - b) / dt_s
            want = min(want, seg.feed_mm_s)
        if want > v + dv:
            v += dv
        elif want < v - dv:
            v -= dv
        else:
            v = want
        v = max(v, 0.0)
        s_rem -= v * dt_s
        while s_rem <= 0.0:
            if not queue:
                # End of the plan: land on the end point. The last creep speed (below
                # accel·dt) is reported for this sample and drops to zero on the next one.
                self.x_mm = seg.x0 + seg.ux * seg.length_mm
                self.y_mm = seg.y0 + seg.uy * seg.length_mm
                self._cur = None
                self._tail = None
                self._s_rem = 0.0
                self.speed_mm_s = v if v <= dv * 1.000001 else 0.0
                self.requested_feed_mm_s = seg.feed_mm_s
                return
            overshoot = -s_rem
            seg = queue.popleft()
            self._cur = seg
            s_rem = seg.length_mm - overshoot
        self._s_rem = s_rem
        done = seg.length_mm - s_rem
        self.x_mm = seg.x0 + seg.ux * done
        self.y_mm = seg.y0 + seg.uy * done
        self.speed_mm_s = v
        self.requested_feed_mm_s = seg.feed_mm_s
