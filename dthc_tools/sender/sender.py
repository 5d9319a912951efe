"""The reference sender: runs a G-code program against the daemon and a motion backend.

Plasma lines go to the daemon (in program order: after the motion queued before them has
finished) and the sender waits for each answer; M3 returns when XY motion may start.
Motion lines go to the backend, and lines with a feed also to the daemon, which uses the
programmed feed as the anti-dive reference. A pause request from the daemon (arc lost, a
fault), or the daemon going offline, holds the motion and stops the program at once;
RosettaCNC ``G100 P0`` lines are resume
points the program can be restarted from after the operator has re-armed.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

import structlog

from dthc_bridge.controller.commands import (
    Command,
    CommandError,
    ProbeAndStart,
    ResumePoint,
    TorchStart,
    VelocityReduction,
)
from dthc_bridge.controller.gcode import parse_line
from dthc_bridge.controller.words import Word, tokenize

from .backend import BackendError, MotionBackend
from .daemon_client import DaemonClient, DaemonError

__all__ = ["SendReport", "Sender"]

log = structlog.get_logger("dthc_tools.sender")

# Lines holding only these modal G codes (plane, units, offsets, cycles, distance and feed
# mode) are not passed to the backend.
_MODAL_ONLY_G = frozenset({17.0, 20.0, 21.0, 40.0, 49.0, 80.0, 90.0, 91.0, 94.0})


@dataclass
class SendReport:
    lines_sent: int = 0
    plasma_commands: int = 0
    cuts_started: int = 0
    error: str = ""
    error_line: int | None = None
    resume_points: list[int] = field(default_factory=list)  # program line numbers of P0
    paused: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.error

    @property
    def resume_from(self) -> int | None:
        """The line to restart from after an error: the last P0 at or before it."""
        if self.error_line is None:
            return None
        earlier = [n for n in self.resume_points if n <= self.error_line]
        return earlier[-1] if earlier else None

    def as_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok, "lines_sent": self.lines_sent, "plasma_commands": self.plasma_commands,
            "cuts_started": self.cuts_started, "error": self.error, "error_line": self.error_line,
            "resume_points": self.resume_points, "resume_from": self.resume_from,
            "paused": self.paused,
        }  # fmt: skip


class Sender:
    def __init__(self, daemon: DaemonClient, backend: MotionBackend) -> None:
        self.daemon = daemon
        self.backend = backend
        self._pause: asyncio.Event = asyncio.Event()
        self._pause_reason = ""
        self.velocity_percent = 100.0  # PlasmaC M67/M68 E3: the machine runs slower
        daemon.on_event(self._on_event)
        daemon.on_offline(self._on_daemon_offline)

    def _on_daemon_offline(self) -> None:
        # Torch and Z are the daemon's: without it, motion must not go on with a cut.
        self._pause_reason = "the daemon went offline"
        self._pause.set()

    def _on_event(self, event: dict[str, Any]) -> None:
        if event.get("type") in ("pause", "arc_lost"):
            self._pause_reason = str(event.get("reason", event.get("type")))
            self._pause.set()

    async def run(self, lines: list[str], *, start_line: int = 1) -> SendReport:
        """Send lines ``start_line``.. (1-based) of the program; stop at the first error."""
        report = SendReport()
        self._pause.clear()
        for number, line in enumerate(lines, start=1):
            if number < start_line:
                continue
            try:
                await self._line(number, line, report)
            except (CommandError, DaemonError, BackendError) as exc:
                report.error, report.error_line = str(exc), number
            if self._pause.is_set() and not report.error:
                report.error, report.error_line = f"paused: {self._pause_reason}", number
            if report.error:
                report.paused.append(self._pause_reason or report.error)
                await self._hold()
                log.warning("program_stopped", line=number, error=report.error)
                return report
        await self.backend.wait_idle()
        if self._pause.is_set():
            report.error, report.error_line = f"paused: {self._pause_reason}", len(lines)
        return report

    async def _hold(self) -> None:
        try:
            await self.backend.hold()
        except BackendError as exc:
            log.error("hold_failed", error=str(exc))

    async def _line(self, number: int, line: str, report: SendReport) -> None:
        parsed = parse_line(line, line_number=number)
        if parsed.commands:
            xy = await self._wait_motion()
            if self._pause.is_set():
                return
            await self.daemon.gcode(line, line_number=number, xy=xy)
            report.lines_sent += 1
            report.plasma_commands += len(parsed.commands)
            for command in parsed.commands:
                if isinstance(command, ResumePoint):
                    report.resume_points.append(number)
                if isinstance(command, VelocityReduction):
                    self.velocity_percent = command.percent if command.percent > 0 else 100.0
                if starts_cut(command):
                    report.cuts_started += 1
            return
        motion = parsed.motion
        if motion is None:
            return
        words = tokenize(motion).words  # parse_line has checked every number
        if all(w.letter == "G" and w.value in _MODAL_ONLY_G for w in words):
            return
        if any(w.letter == "F" for w in words):
            await self.daemon.gcode(motion, line_number=number)  # the programmed feed
        await self.backend.queue(self._reduced(motion, words))
        report.lines_sent += 1

    def _reduced(self, motion: str, words: tuple[Word, ...]) -> str:
        """The line as the machine runs it: feed scaled by a velocity reduction."""
        if self.velocity_percent == 100.0:
            return motion
        scale = self.velocity_percent / 100.0
        parts: list[str] = []
        kept = 0  # motion[:kept] is in parts
        for word in words:
            if word.letter == "F":
                parts += [motion[kept : word.start], f"F{word.value * scale:.1f}"]
                kept = word.end
        return "".join(parts) + motion[kept:]

    async def _wait_motion(self) -> tuple[float, float]:
        """Wait for queued motion to finish, unless the daemon asks for a pause meanwhile."""
        idle = asyncio.ensure_future(self.backend.wait_idle())
        paused = asyncio.ensure_future(self._pause.wait())
        try:
            await asyncio.wait({idle, paused}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            paused.cancel()
        if idle.done():
            return idle.result()
        idle.cancel()
        return (float("nan"), float("nan"))


def starts_cut(command: Command) -> bool:
    """M3, or RosettaCNC G100 P6 in a mode that starts the torch (I0/I1; I2/I3 set values)."""
    return isinstance(command, TorchStart) or (
        isinstance(command, ProbeAndStart) and command.mode in (0, 1)
    )
