"""The look-ahead planner behind the emulator: the mock board's gantry, counted in blocks.

Motion runs on :class:`mock_device.plant.gantry.Gantry` (junction deviation, acceleration,
arcs as chords), the planner the mock board's plant uses, so a plant mirroring this emulator
moves the same way. Every move is handed to it as an explicit line in machine millimetres
(``G90 G21 G91.1 G1 X.. Y.. F..``; rapids as G1 at the rapid rate), and the same line is what
the plant mirror receives.

Each gantry segment (a straight move, or one arc chord) counts as one planner block, as
each of grbl's arc segments does; :class:`PlannedBlock` keeps, per accepted move, how many
of its segments are still queued, which is how the status report knows the executing line
and how feed overrides re-time the queue (:meth:`GrblGantry.set_feeds`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from mock_device.plant.gantry import Gantry

from .blocks import Move, MoveKind

__all__ = ["GrblGantry", "MotionQueue", "PlannedBlock"]

OVERRIDE_MIN_PCT = 10
OVERRIDE_MAX_PCT = 200


class GrblGantry(Gantry):
    """:class:`Gantry` whose queued segments can be re-timed, as grbl's overrides do."""

    __slots__ = ()

    def set_feeds(self, feeds_mm_s: Sequence[float]) -> None:
        """New programmed speeds for the running and queued segments, in order; re-plan.

        Junction limits are recomputed from the new feeds and the backward pass runs over
        the whole queue, so the braking curve stays reachable.
        """
        segments = ([self._cur] if self._cur is not None else []) + list(self._queue)
        if len(feeds_mm_s) != len(segments):
            raise ValueError(f"{len(feeds_mm_s)} feeds for {len(segments)} segments")
        previous = None
        for seg, feed in zip(segments, feeds_mm_s, strict=True):
            seg.feed_mm_s = feed
            if previous is not None:
                junction = self.junction_speed_mm_s(previous.ux, previous.uy, seg.ux, seg.uy)
                seg.max_entry_mm_s = min(junction, previous.feed_mm_s, feed)
            previous = seg
        if self._queue:
            self._replan(len(self._queue))


@dataclass(slots=True)
class PlannedBlock:
    """One accepted move and how much of it is still in the planner."""

    move: Move
    segments: int
    programmed_mm_min: float  # F (or the rapid rate) before overrides
    cap_mm_s: float  # never faster: the max rate, and for arcs the centripetal limit

    @property
    def rapid(self) -> bool:
        """Scaled by the rapid override rather than the feed override."""
        return self.move.kind is MoveKind.RAPID


class MotionQueue:
    """The planner: moves in, segments executed by ``step``, blocks counted out."""

    def __init__(
        self,
        *,
        accel_mm_s2: float,
        rapid_mm_min: float,
        junction_deviation_mm: float,
        max_rate_mm_min: float,
        arc_chord_mm: float,
        start_xy: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self._chord_mm = arc_chord_mm
        self._junction_mm = junction_deviation_mm
        self.rapid_mm_min = rapid_mm_min
        self.max_rate_mm_min = max_rate_mm_min
        self.gantry = self._new_gantry(accel_mm_s2, junction_deviation_mm, start_xy)
        self._blocks: deque[PlannedBlock] = deque()
        self._queued = 0  # segments across _blocks
        self._sent_xy = start_xy  # the end point of the last line the gantry got, as sent
        self._idle_z = 0.0
        self.feed_override_pct = 100
        self.rapid_override_pct = 100
        self.plant_ops: list[dict[str, str]] = []  # for the plant mirror, oldest first

    def _new_gantry(
        self, accel_mm_s2: float, junction_deviation_mm: float, xy: tuple[float, float]
    ) -> GrblGantry:
        return GrblGantry(
            accel_mm_s2=accel_mm_s2,
            rapid_mm_min=self.rapid_mm_min,
            junction_deviation_mm=junction_deviation_mm,
            arc_chord_mm=self._chord_mm,
            x_mm=xy[0],
            y_mm=xy[1],
        )

    # ------------------------------------------------------------------ views
    @property
    def segments(self) -> int:
        """Planner blocks in use: segments queued, the executing one included."""
        return self.gantry.queue_len

    @property
    def empty(self) -> bool:
        """Nothing queued and the table stands still."""
        return not self._blocks and self.gantry.idle

    @property
    def front(self) -> PlannedBlock | None:
        """The block executing (or next to execute)."""
        return self._blocks[0] if self._blocks else None

    @property
    def position_mm(self) -> tuple[float, float, float]:
        """Machine position; Z jumps to a block's target when that block starts."""
        z = self._blocks[0].move.end[2] if self._blocks else self._idle_z
        return self.gantry.x_mm, self.gantry.y_mm, z

    @property
    def speed_mm_s(self) -> float:
        """Actual path speed."""
        return self.gantry.speed_mm_s

    @property
    def segment_feed_mm_s(self) -> float:
        """Programmed speed of the executing segment, overrides and caps applied."""
        return self.gantry.requested_feed_mm_s

    # --------------------------------------------------------------- planning
    def _feed_mm_s(self, block: PlannedBlock) -> float:
        pct = self.rapid_override_pct if block.rapid else self.feed_override_pct
        return min(block.programmed_mm_min * pct / 100.0 / 60.0, block.cap_mm_s)

    def plan(self, move: Move) -> int:
        """Queue a move; return the planner blocks (segments) it takes (0: nothing to do)."""
        cap_mm_s = self.max_rate_mm_min / 60.0
        programmed = self.rapid_mm_min if move.kind is MoveKind.RAPID else move.feed_mm_min
        if move.is_arc:
            cap_mm_s = min(cap_mm_s, math.sqrt(self.gantry.accel_mm_s2 * move.radius_mm))
        block = PlannedBlock(move, 0, programmed, cap_mm_s)
        x1, y1 = round(move.end[0], 6), round(move.end[1], 6)
        feed_mm_min = self._feed_mm_s(block) * 60.0
        if move.is_arc and move.center is not None:
            i, j = move.center[0] - self._sent_xy[0], move.center[1] - self._sent_xy[1]
            text = (
                f"G90 G21 G91.1 {move.kind.value} X{x1:.6f} Y{y1:.6f} I{i:.6f} J{j:.6f} "
                f"F{feed_mm_min:.6f}"
            )
        else:
            text = f"G90 G21 G91.1 G1 X{x1:.6f} Y{y1:.6f} F{feed_mm_min:.6f}"
        block.segments = self.gantry.feed_line(text)
        self._sent_xy = (x1, y1)
        if block.segments or self._blocks or move.end[2] != self._idle_z:
            self._blocks.append(block)
            self._queued += block.segments
        if block.segments:
            self.plant_ops.append({"op": "line", "gcode": text})
        self._sync()
        return block.segments

    # -------------------------------------------------------------- execution
    def step(self, dt_s: float) -> None:
        """Advance the motion by ``dt_s`` and retire finished blocks."""
        self.gantry.step(dt_s)
        self._sync()

    def _sync(self) -> None:
        done = self._queued - self.gantry.queue_len
        self._queued -= done
        while self._blocks:
            block = self._blocks[0]
            take = min(done, block.segments)
            block.segments -= take
            done -= take
            if block.segments:
                break
            self._idle_z = block.move.end[2]
            self._blocks.popleft()

    def hold(self) -> None:
        """Feed hold: decelerate along the path."""
        self.gantry.hold()
        self.plant_ops.append({"op": "hold"})

    def resume(self) -> None:
        """Release a feed hold."""
        self.gantry.resume()
        self.plant_ops.append({"op": "resume"})

    def clear(self) -> None:
        """Drop every queued move and stand still where the table is; release any hold."""
        if self._blocks:
            self._idle_z = self._blocks[0].move.end[2]
        self.gantry.clear()
        self.gantry.resume()
        self._blocks.clear()
        self._queued = 0
        self._sent_xy = (self.gantry.x_mm, self.gantry.y_mm)
        self.plant_ops += [{"op": "clear"}, {"op": "resume"}]

    def set_overrides(self, feed_pct: int, rapid_pct: int) -> None:
        """Feed and rapid overrides (percent); the queued motion is re-timed at once."""
        feed_pct = max(OVERRIDE_MIN_PCT, min(OVERRIDE_MAX_PCT, feed_pct))
        if (feed_pct, rapid_pct) == (self.feed_override_pct, self.rapid_override_pct):
            return
        self.feed_override_pct, self.rapid_override_pct = feed_pct, rapid_pct
        feeds: list[float] = []
        for block in self._blocks:
            feeds += [self._feed_mm_s(block)] * block.segments
        self.gantry.set_feeds(feeds)

    def reconfigure(
        self, *, accel_mm_s2: float, junction_deviation_mm: float, max_rate_mm_min: float
    ) -> bool:
        """New motion settings; only applied with an empty planner. True if applied."""
        if not self.empty:
            return False
        xy = (self.gantry.x_mm, self.gantry.y_mm)
        self.max_rate_mm_min = max_rate_mm_min
        self._junction_mm = junction_deviation_mm
        self.gantry = self._new_gantry(accel_mm_s2, junction_deviation_mm, xy)
        self._sent_xy = xy
        return True
