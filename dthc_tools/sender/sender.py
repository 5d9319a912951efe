"""The reference sender: runs a G-code program against the daemon and a motion backend.

The program is planned by :class:`dthc_bridge.program.ProgramPlan` (dialect rules, NGC
evaluation, Z to the board); the sender carries the steps out. Daemon lines go in program
order (after the motion queued before them has finished) and the sender waits for each
answer; M3 returns when XY motion may start. Motion lines go to the backend; a feed note
tells the daemon the programmed cutting feed (the anti-dive reference). ``G4`` dwells
after motion has finished. A pause request from the daemon (arc lost, a fault), or the
daemon going offline, holds the motion and stops the program at once; RosettaCNC ``G100
P0`` lines are resume points the program can be restarted from after the operator has
re-armed.
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping, Sequence
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
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.controller.gcode import parse_line
from dthc_bridge.controller.words import Word, tokenize
from dthc_bridge.program.plan import (
    DaemonStep,
    DwellStep,
    MotionStep,
    ProgramPlan,
    Refused,
    Step,
    detect_dialect,
)

from .backend import BackendError, MotionBackend
from .daemon_client import DaemonClient, DaemonError

__all__ = ["SendReport", "Sender"]

log = structlog.get_logger("dthc_tools.sender")


@dataclass
class SendReport:
    lines_sent: int = 0
    plasma_commands: int = 0
    cuts_started: int = 0
    error: str = ""
    error_line: int | None = None
    resume_points: list[int] = field(default_factory=list)  # program line numbers of P0
    paused: list[str] = field(default_factory=list)
    dialect: str = ""
    warnings: list[str] = field(default_factory=list)

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
            "paused": self.paused, "dialect": self.dialect, "warnings": self.warnings,
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
        if event.get("cause") == "stop_after_pierce":
            # G200 S1: the pending M3 is answered once the operator presses cycle start.
            log.warning("waiting_for_cycle_start", reason=event.get("reason"))
            return
        if event.get("type") in ("pause", "arc_lost"):
            self._pause_reason = str(event.get("reason", event.get("type")))
            self._pause.set()

    async def run(
        self,
        lines: Sequence[str],
        *,
        start_line: int = 1,
        dialect: Dialect | None = None,
        codes: Mapping[str, str] | None = None,
    ) -> SendReport:
        """Send the program from ``start_line`` (1-based); stop at the first error.

        ``dialect``: None detects it (:func:`~dthc_bridge.program.plan.detect_dialect`;
        the daemon's ``controller.dialect`` when nothing dialect-specific is found);
        ``codes`` maps a shop's own codes to the daemon's (``{"H1": "M667"}``), on top of
        the daemon's ``controller.codes`` table."""
        report = SendReport()
        self._pause.clear()
        self.velocity_percent = 100.0
        try:
            started = await self.daemon.request("program_start")
        except DaemonError as exc:
            report.error, report.error_line = str(exc), start_line
            return report
        if dialect is None:
            dialect, why = detect_dialect(lines, _daemon_dialect(started))
            log.info("dialect_detected", dialect=str(dialect), why=why)
        report.dialect = str(dialect)
        shop_codes = started.get("codes")
        table = {**(shop_codes if isinstance(shop_codes, dict) else {}), **(codes or {})}
        plan = ProgramPlan(lines, dialect, table)
        self._note_cut_feed(started, plan)
        number = start_line
        for step in plan.steps():
            number = step.source_line
            if number < start_line:
                continue
            try:
                await self._step(step, plan, report)
            except (CommandError, DaemonError, BackendError) as exc:
                report.error, report.error_line = str(exc), number
            if self._pause.is_set() and not report.error:
                report.error, report.error_line = f"paused: {self._pause_reason}", number
            if report.error:
                report.paused.append(self._pause_reason or report.error)
                await self._hold()
                log.warning("program_stopped", line=number, error=report.error)
                report.warnings = plan.warnings
                return report
        await self.backend.wait_idle()
        if self._pause.is_set():
            report.error, report.error_line = f"paused: {self._pause_reason}", number
        report.warnings = plan.warnings
        return report

    async def _hold(self) -> None:
        try:
            await self.backend.hold()
        except BackendError as exc:
            log.error("hold_failed", error=str(exc))

    async def _step(self, step: Step, plan: ProgramPlan, report: SendReport) -> None:
        if isinstance(step, Refused):
            raise CommandError("", step.error)
        if isinstance(step, MotionStep):
            words = tokenize(step.line).words  # the plan has checked every number
            await self.backend.queue(self._reduced(step.line, words))
            report.lines_sent += 1
            return
        if isinstance(step, DwellStep):
            await self._wait_motion()
            if not self._pause.is_set():
                await asyncio.sleep(step.seconds)
            return
        dialect = str(plan.dialect)
        if step.feed_note:
            await self.daemon.gcode(step.line, line_number=step.source_line, dialect=dialect)
            return
        await self._daemon_line(step, plan, report)

    @staticmethod
    def _note_cut_feed(data: Mapping[str, Any], plan: ProgramPlan) -> None:
        """The material in force changed (program start, M190): ``plasmac.cut-feed-rate``."""
        if isinstance(data.get("cut_feed_mm_min"), int | float):
            plan.cut_feed_mm_min = float(data["cut_feed_mm_min"])

    async def _daemon_line(self, step: DaemonStep, plan: ProgramPlan, report: SendReport) -> None:
        parsed = parse_line(step.line, line_number=step.source_line, dialect=plan.dialect)
        xy = await self._wait_motion()
        if self._pause.is_set():
            return
        data = await self.daemon.gcode(
            step.line, line_number=step.source_line, xy=xy, dialect=str(plan.dialect)
        )
        self._note_cut_feed(data, plan)
        report.lines_sent += 1
        report.plasma_commands += len(parsed.commands)
        for command in parsed.commands:
            if isinstance(command, ResumePoint):
                report.resume_points.append(step.source_line)
            if isinstance(command, VelocityReduction):
                self.velocity_percent = command.percent if command.percent > 0 else 100.0
            if starts_cut(command):
                report.cuts_started += 1

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


def _daemon_dialect(started: Mapping[str, Any]) -> tuple[Dialect, str] | None:
    """The daemon's configured dialect from its ``program_start`` answer, if it gave one."""
    try:
        return Dialect(str(started["dialect"])), "the daemon's controller.dialect"
    except (KeyError, ValueError):
        return None
