"""A program stopped mid-way (arc lost, a fault, the operator's stop): PlasmaC's paused
motion and cut recovery, then a resume where the torch stands.

- **Paused motion**: the torch moves backwards along the programmed path (as far as the
  start of the cut it is on) or forwards (through any number of cuts, to the end of the
  program), torch off, at a chosen feed.
- **Cut recovery**: the torch moves off the path by a small offset (within
  ``radius_mm``), to pierce on scrap beside the kerf; after the pierce it travels back onto
  the path at the cut's feed. The offset serves one resume.
- **Resume**: the daemon is re-armed and the program goes on from the point: the cut's
  start line (M3) runs the start sequence there (touch-off unless IHS may be skipped,
  pierce, cut height) with the cut's own plasma lines before the point replayed (THC on,
  velocity reductions), then the rest of the split segment, then the program.

Z never moves here (the board's, through the daemon) and the torch cannot light: only XY
lines go to the motion backend, and only while the daemon says no cut runs."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import structlog

from .backend import BackendError
from .path import PathPoint, ProgramPath

__all__ = ["DEFAULT_PATH_FEED_MM_MIN", "PausedProgram", "ResumeAt"]

log = structlog.get_logger("dthc_tools.sender.recovery")

DEFAULT_PATH_FEED_MM_MIN = 1000.0  # paused motion's feed unless the operator picks one
MAX_PATH_FEED_MM_MIN = 10_000.0
DEFAULT_RECOVERY_RADIUS_MM = 10.0  # QtPlasmaC's cut recovery moves about a kerf or two
NOT_CUTTING = frozenset({"idle", "faulted"})


@dataclass(frozen=True, slots=True)
class ResumeAt:
    """Where a resumed program starts: a point of the path, and an offset off it."""

    point: PathPoint
    offset_mm: tuple[float, float] = (0.0, 0.0)


class PausedProgram:
    def __init__(
        self,
        sender: Any,  # the Sender (typed loosely: it imports this module)
        path: ProgramPath,
        *,
        up_to_step: int | None,
        radius_mm: float = DEFAULT_RECOVERY_RADIUS_MM,
    ) -> None:
        self.sender = sender
        self.path = path
        self.up_to_step = up_to_step
        self.radius_mm = radius_mm
        self.point: PathPoint | None = None
        self.offset_mm = (0.0, 0.0)

    async def locate(self) -> PathPoint:
        """Drop the program's queued motion, release the hold, find the torch on the path."""
        backend = self.sender.backend
        await backend.clear()
        await backend.resume()
        x, y = await backend.wait_idle()
        self.point = self.path.locate(x, y, up_to_step=self.up_to_step)
        log.info("paused_motion_ready", x=round(x, 3), y=round(y, 3), **self.where())
        return self.point

    def where(self) -> dict[str, Any]:
        """For the console and the panel: where the torch is, what it may do."""
        if self.point is None:
            return {}
        path, point = self.path, self.point
        segment = path.segments[point.segment]
        x, y = path.xy(point)
        return {
            "line": segment.source_line, "x_mm": round(x, 3), "y_mm": round(y, 3),
            "cut": None if segment.cut is None else segment.cut + 1,
            "behind_mm": round(-path.distance(point, path.cut_start(point)), 3),
            "ahead_mm": round(path.distance(point, path.end()), 3),
            "offset_mm": [round(v, 3) for v in self.offset_mm],
        }  # fmt: skip

    async def _torch_is_off(self, what: str) -> None:
        status = await self.sender.daemon.request("status")
        state = str(status.get("state"))
        if state not in NOT_CUTTING:
            raise BackendError(f"{what}: a cut is running ({state}): stop it first")

    async def move_along(self, mm: float, feed_mm_min: float | None = None) -> dict[str, Any]:
        """Along the path, ``mm`` forwards (negative: backwards), torch off."""
        point = self._ready("path_move")
        if not math.isfinite(mm) or mm == 0.0:
            raise BackendError(f"path_move mm: {mm!r} must be a distance other than 0")
        feed = _feed(feed_mm_min)
        if self.offset_mm != (0.0, 0.0):
            raise BackendError("path_move: the torch is off the path (cut recovery): "
                               "set the offset back to 0 first")  # fmt: skip
        path = self.path
        if mm < 0.0:
            start = path.cut_start(point)
            behind = -path.distance(point, start)
            if -mm > behind + 1e-6:
                line = path.segments[start.segment].source_line
                raise BackendError(
                    f"path_move {mm:g} mm: only {behind:.1f} mm of this cut lie behind the "
                    f"torch (it starts at line {line})"
                )
        target, available = path.walk(point, mm)
        if available < abs(mm) - 1e-6:
            raise BackendError(f"path_move {mm:g} mm: the program ends {available:.1f} mm ahead")
        await self._torch_is_off("path_move")
        await self._run([*self._modal(), *path.moves(point, target, feed)])
        self.point = target
        log.info("paused_motion", mm=mm, feed_mm_min=feed, **self.where())
        return self.where()

    async def set_offset(
        self, x_mm: float, y_mm: float, feed_mm_min: float | None = None
    ) -> dict[str, Any]:
        """Cut recovery: the torch to the path point plus (x, y); (0, 0) back onto it."""
        point = self._ready("recovery_offset")
        for name, value in (("x_mm", x_mm), ("y_mm", y_mm)):
            if not math.isfinite(value):
                raise BackendError(f"recovery_offset {name}: {value!r} is not a distance")
        if math.hypot(x_mm, y_mm) > self.radius_mm + 1e-9:
            raise BackendError(
                f"recovery_offset: {math.hypot(x_mm, y_mm):.1f} mm off the path is beyond "
                f"the {self.radius_mm:g} mm cut recovery allows"
            )
        feed = _feed(feed_mm_min)
        await self._torch_is_off("recovery_offset")
        px, py = self.path.xy(point)
        scale = self.path.scale
        target = f"G1 X{(px + x_mm) / scale:.4f} Y{(py + y_mm) / scale:.4f} F{feed / scale:g}"
        await self._run([*self._modal(), target])
        self.offset_mm = (x_mm, y_mm)
        log.info("recovery_offset", x_mm=x_mm, y_mm=y_mm)
        return self.where()

    def resume_at(self) -> ResumeAt:
        point = self._ready("resume")
        self.path.rest_of(point)  # refuses a split it cannot write, before anything moves
        return ResumeAt(point, self.offset_mm)

    def _ready(self, what: str) -> PathPoint:
        if self.point is None:
            raise BackendError(f"{what}: the torch has not been found on the path")
        return self.point

    def _modal(self) -> list[str]:
        # The backend was cleared (grbl: a soft reset); say the units and modes outright.
        units = "G20" if self.path.scale != 1.0 else "G21"
        return [f"{units} G90 G91.1" if self.path.arc_absolute else f"{units} G90"]

    async def _run(self, lines: list[str]) -> None:
        backend = self.sender.backend
        for line in lines:
            await backend.queue(line)
        await backend.wait_idle()


def _feed(feed_mm_min: float | None) -> float:
    if feed_mm_min is None:
        return DEFAULT_PATH_FEED_MM_MIN
    if not math.isfinite(feed_mm_min) or not 0.0 < feed_mm_min <= MAX_PATH_FEED_MM_MIN:
        raise BackendError(
            f"feed_mm_min: {feed_mm_min!r} must be more than 0 and at most {MAX_PATH_FEED_MM_MIN:g}"
        )
    return feed_mm_min
