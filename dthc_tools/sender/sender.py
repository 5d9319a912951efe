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
import contextlib
from collections import deque
from collections.abc import Coroutine, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import structlog

from dthc_bridge.controller.commands import (
    CommandError,
    ResumePoint,
    TorchStop,
    VelocityReduction,
)
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.controller.words import Word
from dthc_bridge.program.modal import ModalState
from dthc_bridge.program.plan import (
    DaemonStep,
    DwellStep,
    MotionStep,
    ProgramPlan,
    Refused,
    Step,
    detect_dialect,
    unknown_m_codes,
)

from .backend import BackendError, MotionBackend, Positioned
from .daemon_client import DaemonError, DaemonSeam
from .path import ProgramPath, build_path, starts_cut
from .recovery import ResumeAt

__all__ = ["POSITION_PERIOD_S", "SendReport", "Sender"]

log = structlog.get_logger("dthc_tools.sender")
_T = TypeVar("_T")

POSITION_PERIOD_S = 0.2
"""The torch's position is asked for this often while a program runs (the console's line,
the panel's marker): as often as the progress goes out."""
PAUSED_BY_OPERATOR = "paused by the operator"


@dataclass
class SendReport:
    lines_sent: int = 0
    plasma_commands: int = 0
    cuts_started: int = 0
    error: str = ""
    error_line: int | None = None
    resume_points: list[int] = field(default_factory=list)  # program line numbers of P0
    paused: list[str] = field(default_factory=list)
    cut_lines: list[int] = field(default_factory=list)  # program line of each cut start
    cycle_starts: list[int] = field(default_factory=list)  # the M3 lines released by it
    dialect: str = ""
    warnings: list[str] = field(default_factory=list)
    lines_run: set[int] = field(default_factory=set)  # program lines carried out (1-based)
    # The program stopped for the operator's pause (the cut ended, torch out, raised): not
    # an error; the resume runs the start sequence where the torch stands.
    operator_paused: bool = False

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

    @property
    def restart_line(self) -> int | None:
        """Where a restart after an error begins: the last resume point (RosettaCNC G100
        P0), else the start of the cut the error happened in (PlasmaC's cut recovery)."""
        if self.error_line is None:
            return None
        cuts = [n for n in self.cut_lines if n <= self.error_line]
        points = [n for n in (self.resume_from, cuts[-1] if cuts else None) if n is not None]
        return max(points) if points else None

    def as_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok, "lines_sent": self.lines_sent, "plasma_commands": self.plasma_commands,
            "cuts_started": self.cuts_started, "error": self.error, "error_line": self.error_line,
            "resume_points": self.resume_points, "resume_from": self.resume_from,
            "restart_line": self.restart_line, "paused": self.paused,
            "cut_lines": self.cut_lines, "cycle_starts": self.cycle_starts,
            "dialect": self.dialect, "warnings": self.warnings,
            "lines_run": len(self.lines_run), "operator_paused": self.operator_paused,
        }  # fmt: skip


@dataclass
class Progress:
    """What the operator console shows."""

    line: int = 0
    total_lines: int = 0
    cut: int = 0
    total_cuts: int = 0
    waiting_cycle_start: bool = False
    operator_paused: bool = False
    running: bool = False
    # After an error, while the operator may move the torch: where it is on the path.
    paused_at: dict[str, Any] | None = None
    # Where the torch is, as the motion controller reports it (None before it has): XY in
    # mm, its speed, and the path segment it is on (an index into the sender/path moves).
    x_mm: float | None = None
    y_mm: float | None = None
    feed_mm_min: float | None = None
    segment: int | None = None


class Sender:
    def __init__(
        self, daemon: DaemonSeam, backend: MotionBackend, *, auto_cycle_start: bool = False
    ) -> None:
        self.daemon = daemon
        self.backend = backend
        self.auto_cycle_start = auto_cycle_start  # --yes-cycle-start: tests, remote panels
        self.progress = Progress()
        self.report = SendReport()
        self._pause: asyncio.Event = asyncio.Event()
        self._pause_reason = ""
        self._paused_cut = False  # the pause came from the daemon ending a cut for a pause
        self._at_line: int | None = None  # the daemon line in flight: the torch is there
        self._go = asyncio.Event()  # cleared while the operator has paused the program
        self._go.set()
        self.velocity_percent = 100.0  # PlasmaC M67/M68 E3: the machine runs slower
        daemon.on_event(self._on_event)
        daemon.on_offline(self._on_daemon_offline)
        backend.add_motion_listener(self._on_motion)
        self._reports: set[asyncio.Task[None]] = set()
        self.motion_reports = 0
        self.path: ProgramPath | None = None  # the running program's XY path
        self._open_cut: DaemonStep | None = None  # the line that started the cut in progress
        self._streamed: deque[Step] = deque()  # a streamed line's steps not yet carried out
        self._detect_stream = False  # a streamed program's dialect comes from its lines
        self.last_step = -1  # the last plan step sent: the torch is on the path up to it

    def _on_motion(self, speed_mm_s: float, state: str) -> None:
        """The motion controller's measured XY speed, to the daemon's anti-dive (boards
        without an XY speed input). Fire and forget: the next report is 100 ms away."""
        self.motion_reports += 1
        self._background(
            self.daemon.notify("motion", xy_speed_mm_s=round(speed_mm_s, 2), state=state)
        )

    def _on_daemon_offline(self) -> None:
        # Torch and Z are the daemon's: without it, motion must not go on with a cut.
        self._pause_reason = "the daemon went offline"
        self._pause.set()
        self._background(self._hold())  # now: the loop may be waiting for buffer room

    def _on_event(self, event: dict[str, Any]) -> None:
        if event.get("cause") == "stop_after_pierce":
            # G200 S1: the pending M3 is answered once the operator presses cycle start.
            self.progress.waiting_cycle_start = True
            log.warning("waiting_for_cycle_start", line=self._at_line)
            if self.auto_cycle_start:
                self._background(self.cycle_start())
            return
        if event.get("type") in ("pause", "arc_lost"):
            self._pause_reason = str(event.get("reason", event.get("type")))
            # The daemon ended a lit cut for a pause (invariant 7): the program stops where
            # the torch is, to be resumed there; nothing to abort.
            self._paused_cut = event.get("cause") == "operator_pause"
            self._pause.set()
            # Held now, within one status period, not when the loop next looks: it may be
            # waiting for room in the controller's buffer while grbl runs what it has.
            self._background(self._hold())

    def _background(self, work: Coroutine[Any, Any, None]) -> None:
        task = asyncio.ensure_future(work)
        self._reports.add(task)
        task.add_done_callback(self._reports.discard)

    # --- the operator's keys ---------------------------------------------------------------

    async def cycle_start(self) -> None:
        """After a G200 S1 stop: release the pending M3. After a pause: resume."""
        if self._pause.is_set() or not self.progress.running:
            reason = self._pause_reason or "no program runs"
            raise BackendError(f"nothing to start ({reason}): re-arm and restart instead")
        if self.progress.waiting_cycle_start:
            self.progress.waiting_cycle_start = False
            line = self._at_line if self._at_line is not None else self.progress.line
            self.report.cycle_starts.append(line)
            log.info("cycle_start", line=line)
            await self.daemon.request("cycle_start")
        elif self.progress.operator_paused:
            await self.backend.resume()
            await self.daemon.request("thc_hold", on=False)
            self.progress.operator_paused = False
            self._go.set()
            log.info("resumed_by_operator", line=self.progress.line)
        else:
            raise BackendError("nothing waits for cycle start (no S1 stop, no pause)")

    async def pause(self) -> None:
        """Feed hold and THC hold. A cut running is ended by the daemon (torch out, safe
        height: docs/DESIGN.md invariant 7) and the program stops where the torch is, to be
        resumed there through the start sequence; with nothing lit the motion only holds,
        and cycle start releases it."""
        if self.progress.operator_paused or not self.progress.running:
            return
        self.progress.operator_paused = True
        self._go.clear()
        _, held = await asyncio.gather(
            self.backend.hold(), self.daemon.request("thc_hold", on=True)
        )
        if held.get("cut_ended"):
            self._paused_cut = True
            self._pause_reason = PAUSED_BY_OPERATOR
            self._pause.set()  # as the daemon's pause event does, should it come late
        log.info("paused_by_operator", line=self.progress.line, cut_ended=self._paused_cut)

    async def stop(self) -> None:
        """Torch off and safe height (the daemon's abort: re-arm before the next cut), motion
        held; the program ends."""
        self._pause_reason = "stopped by the operator"
        await self._stop_machine()

    def feed_override(self, step: str) -> None:
        """``+10``/``-10``/``reset``: the motion controller's feed override, when it has one."""
        override = getattr(self.backend, "feed_override", None)
        if override is None:
            raise BackendError("this motion backend has no feed override")
        override(step)

    async def height(self, step_mm: float) -> None:
        """Height override: the cut height up (+) or down (-) by ``step_mm`` (0.1 mm steps)."""
        await self.daemon.request("height_override", mm=step_mm)

    async def torch(self, volts: float) -> None:
        """Torch up (+) or down (-): the THC target moves by ``volts``."""
        await self.daemon.request("torch_up" if volts > 0 else "torch_down", volts=abs(volts))

    async def rearm(self) -> None:
        """Before a restart: the daemon leaves its fault state, the motion queue is dropped."""
        try:
            await self.daemon.request("rearm")
        except DaemonError as exc:
            if "nothing to re-arm" not in str(exc):
                raise
        await self.backend.clear()
        await self.backend.resume()

    @property
    def cut_paused(self) -> bool:
        """The operator's pause has ended a cut: the program stops by itself, to be resumed
        where the torch stands (nothing to stop or abort)."""
        return self._paused_cut

    async def daemon_idle(self, timeout_s: float = 15.0) -> None:
        """Until the daemon's sequence rests (the raise after a pause ends): a resume's M3
        would be refused while it runs. BackendError after ``timeout_s``."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            state = (await self.daemon.request("status")).get("state")
            if state in ("idle", "faulted") or state is None:
                return
            if loop.time() >= deadline:
                raise BackendError(f"the daemon is still busy ({state}) after {timeout_s:g} s")
            await asyncio.sleep(0.05)

    async def run(
        self,
        lines: Sequence[str],
        *,
        start_line: int = 1,
        dialect: Dialect | None = None,
        codes: Mapping[str, str] | None = None,
        resume: ResumeAt | None = None,
    ) -> SendReport:
        """Send the program from ``start_line`` (1-based), or from a point of its path
        (``resume``: after paused motion, see :mod:`.recovery`); stop at the first error.

        ``dialect``: None detects it (:func:`~dthc_bridge.program.plan.detect_dialect`;
        the daemon's ``controller.dialect`` when nothing dialect-specific is found);
        ``codes`` maps a shop's own codes to the daemon's (``{"H1": "M667"}``), on top of
        the daemon's ``controller.codes`` table."""
        report = self.report = SendReport()
        self._pause.clear()
        self._pause_reason = ""
        self._paused_cut = False
        self.velocity_percent = 100.0
        self.progress = Progress(total_lines=len(lines), running=True)
        self._go.set()
        tracker: asyncio.Task[None] | None = None
        try:
            if isinstance(self.backend, Positioned):
                # A sender killed mid-program leaves its hold (and queue) behind.
                await self.backend.release_stale_hold()
                tracker = asyncio.ensure_future(self._track(self.backend))
            return await self._run(lines, start_line, dialect, codes, report, resume=resume)
        except asyncio.CancelledError:
            # Ctrl-C, or the caller gave up: nothing may go on without the sender.
            await asyncio.shield(self._stop_machine())
            raise
        finally:
            if tracker is not None:
                tracker.cancel()
            self.progress.running = False
            self.progress.operator_paused = False
            self.progress.waiting_cycle_start = False

    # --- a program that arrives line by line (the grbl port's sender streams it) -----------

    async def open_stream(
        self, *, dialect: Dialect | None = None, codes: Mapping[str, str] | None = None
    ) -> ProgramPlan:
        """Start a program whose lines come one at a time from another sender: the daemon's
        program_start, then the plan in the dialect given, or else detected from the lines as
        they come (the daemon's ``controller.dialect`` until a line shows one: there are no
        lines ahead to look at), with the shop's codes and the pins of the material in
        force. Each line then goes to :meth:`stream_line`;
        :meth:`close_stream` ends the program."""
        self.report = SendReport()
        self._pause.clear()
        self._pause_reason = ""
        self._paused_cut = False
        self.velocity_percent = 100.0
        self.progress = Progress(running=True)
        self._go.set()
        self._open_cut = None
        self._streamed.clear()
        started = await self.daemon.request("program_start")
        daemon = _daemon_dialect(started)
        self._detect_stream = dialect is None
        chosen = dialect or (daemon[0] if daemon is not None else Dialect.MASSO)
        self.report.dialect = str(chosen)
        plan = ProgramPlan([], chosen, _code_table(started, codes))
        plan.note_pins(started)
        return plan

    async def stream_line(self, plan: ProgramPlan, text: str) -> None:
        """One more line, its steps run as a whole program's are (motion queued, daemon
        lines after the motion before them, an M3 answered when XY may move). Raises
        CommandError for a refused line (nothing of it ran), DaemonError or BackendError
        when it failed, and BackendError while the program is paused."""
        number = len(plan.lines) + 1
        self.progress.line = self.progress.total_lines = number
        self.report.lines_run.add(number)
        self._streamed = deque(plan.stream(text, detect=self._detect_stream))
        self.report.dialect = str(plan.dialect)
        await self.stream_rest(plan)

    async def stream_rest(self, plan: ProgramPlan) -> None:
        """The current streamed line's steps not yet carried out (all of them, or those a
        pause interrupted: :meth:`resume_stream` first). BackendError while paused."""
        while self._streamed:
            if not await self._step(self._streamed[0], plan, self.report):
                break
            self._streamed.popleft()
        if self._pause.is_set():
            raise BackendError(f"paused: {self._pause_reason}", line_number=len(plan.lines))

    @property
    def stream_paused(self) -> bool:
        """A streamed program paused (the operator's, an arc lost, a fault), to be resumed."""
        return self.progress.running and self._pause.is_set()

    async def resume_stream(self, plan: ProgramPlan) -> None:
        """Cycle start after a streamed program paused: the daemon re-armed where it allows
        it; when the pause ended a cut, its start sequence (the line that started it) run
        where the torch stands; then the motion released. The interrupted line goes on with
        :meth:`stream_rest`. Without a pause: :meth:`cycle_start`."""
        if not self._pause.is_set():
            await self.cycle_start()
            return
        try:
            await self.daemon.request("rearm")
        except DaemonError as exc:
            if "nothing to re-arm" not in str(exc):
                raise
        await self.daemon_idle()
        self._pause.clear()
        self._pause_reason = ""
        self._paused_cut = False
        self.progress.operator_paused = False
        self._go.set()
        with contextlib.suppress(DaemonError):
            await self.daemon.request("thc_hold", on=False)
        cut = self._open_cut
        if cut is not None:  # torch out mid-cut: pierce again here, XY still held
            where = await self.backend.where() if isinstance(self.backend, Positioned) else None
            xy = (where.x_mm, where.y_mm) if where is not None else None
            log.info("cut_restarted_here", line=cut.source_line, xy=xy)
            await self.daemon.gcode(cut.line, line_number=cut.source_line, xy=xy,
                                    dialect=str(plan.dialect))  # fmt: skip
        await self.backend.resume()

    async def close_stream(self) -> None:
        """The streamed program's end: its motion done, then program_end (the height
        override resets, as at the end of any program)."""
        try:
            if not self._pause.is_set():
                await self._wait_motion()
        finally:
            self.progress.running = False
            with contextlib.suppress(DaemonError):
                await self.daemon.request("program_end")

    async def _track(self, backend: Positioned) -> None:
        """Until cancelled: where the torch is, and the program line it is on (the path's
        segment there, searched forward from the last one among the lines sent so far)."""
        progress = self.progress
        while True:
            try:
                where = await backend.where()
            except BackendError as exc:
                log.debug("position_unavailable", error=str(exc))
                where = None
            if where is not None:
                progress.x_mm, progress.y_mm = round(where.x_mm, 3), round(where.y_mm, 3)
                progress.feed_mm_min = round(where.speed_mm_s * 60.0, 1)
                path = self.path
                if self._at_line is not None:  # at rest for it (a pierce, an S1 stop)
                    progress.line = self._at_line
                elif path is not None:
                    segment = path.follow(where.x_mm, where.y_mm, progress.segment or 0,
                                          up_to_step=self.last_step)  # fmt: skip
                    if segment is not None:
                        progress.segment = segment.index
                        progress.line = segment.source_line
                if where.held and progress.running and not progress.operator_paused \
                        and not self._pause.is_set():  # fmt: skip
                    # A hold from the controller itself (its feed-hold button): a pause.
                    log.warning("feed_hold_on_the_controller", line=progress.line)
                    self._background(self.pause())
            await asyncio.sleep(POSITION_PERIOD_S)

    async def _run(
        self,
        lines: Sequence[str],
        start_line: int,
        dialect: Dialect | None,
        codes: Mapping[str, str] | None,
        report: SendReport,
        *,
        resume: ResumeAt | None = None,
    ) -> SendReport:
        try:
            started = await self.daemon.request("program_start")
        except DaemonError as exc:
            report.error, report.error_line = str(exc), start_line
            return report
        if dialect is None:
            dialect, why = detect_dialect(lines, _daemon_dialect(started))
            log.info("dialect_detected", dialect=str(dialect), why=why)
        report.dialect = str(dialect)
        table = _code_table(started, codes)
        # Counted, and the path drawn, on a plan of its own: the running plan's NGC reads
        # the daemon's answers (cut-feed-rate after an M190), so its steps cannot be listed
        # ahead. This one reads the pins of the material in force at the start: a later
        # M190 changes a feed or a Z origin, not where the cuts are.
        ahead = ProgramPlan(lines, dialect, table)
        ahead.note_pins(started)
        listed = list(ahead.steps())
        self.progress.total_cuts = sum(_cuts_in(step) for step in listed)
        self.path = build_path(ahead, listed)
        unknown = unknown_m_codes(listed) if not self.progress.total_cuts else []
        if unknown:  # as check-program: codes nobody knows and no cut is not a program run
            report.error, report.error_line = unknown[0].error, unknown[0].source_line
            return report
        plan = ProgramPlan(lines, dialect, table)
        plan.note_pins(started)  # the HAL pins the material in force answers
        number = start_line
        restart = RestartPosition()
        resumed = _Resumption(self.path, resume) if resume is not None else None
        tracked = isinstance(self.backend, Positioned)
        for index, step in enumerate(plan.steps()):
            number = step.source_line
            if not tracked or isinstance(step, DaemonStep):
                # The torch is there: daemon lines wait for the motion before them. Motion
                # lines go ahead of the torch, which the tracker follows.
                self.progress.line = number
            if resumed is not None and index < resumed.step_index:
                restart.skip(step)
                if not resumed.replays(index, step):
                    self.progress.cut += _cuts_in(step)
                continue
            if resumed is None and number < start_line:
                restart.skip(step)
                self.progress.cut += _cuts_in(step)
                continue
            self.last_step = index
            report.lines_run.add(number)
            try:
                if resumed is not None:  # the step whose segment the resume point splits
                    await self._resume_here(resumed, restart, plan, report, number)
                    resumed = None
                    continue
                for line in restart.lines():  # once: back to where the skipped lines end
                    await self._unless_paused(self.backend.queue(line, source_line=number))
                await self._step(step, plan, report)
            except BackendError as exc:
                report.error, report.error_line = str(exc), exc.line_number or number
            except (CommandError, DaemonError) as exc:
                report.error, report.error_line = str(exc), number
            if self._pause.is_set() and not report.error:
                # Where the torch stopped (the tracker's line), not the line sent last.
                here = self.progress.line if tracked else number
                report.error, report.error_line = f"paused: {self._pause_reason}", here
            if report.error:
                report.paused.append(self._pause_reason or report.error)
                if self._paused_cut:
                    # The daemon has ended the cut for the pause: hold, nothing to abort
                    # (an abort would make the pause a fault to re-arm).
                    report.operator_paused = True
                    await self._hold()
                else:
                    await self._stop_machine()
                log.warning("program_stopped", line=report.error_line, error=report.error)
                report.warnings = plan.warnings
                return report
        try:
            await self._wait_motion()
        except BackendError as exc:  # a line refused late (streamed ahead), an alarm
            report.error, report.error_line = str(exc), exc.line_number or number
            await self._stop_machine()
        if self._pause.is_set() and not report.error:
            report.error, report.error_line = f"paused: {self._pause_reason}", number
        if not report.error:
            self.progress.line = len(lines)  # the torch has run the whole file
            # At its end: PlasmaC resets the height override; an old daemon without the
            # request still answers, with an error, and ran the program just the same.
            with contextlib.suppress(DaemonError):
                await self.daemon.request("program_end")
        report.warnings = plan.warnings
        return report

    async def _resume_here(
        self,
        resumed: _Resumption,
        restart: RestartPosition,
        plan: ProgramPlan,
        report: SendReport,
        number: int,
    ) -> None:
        """To the resume point (plus a cut recovery offset), the cut's start sequence there
        with the cut's plasma lines before the point, back onto the path, the rest of the
        split segment."""
        path, point = resumed.path, resumed.at.point
        x, y = path.xy(point)
        dx, dy = resumed.at.offset_mm
        restart.x_mm, restart.y_mm, restart.pending = x + dx, y + dy, True
        restart.unknown = ""  # the point is known: the path was followed to it
        for line in restart.lines():
            await self._unless_paused(self.backend.queue(line, source_line=number))
        for step in resumed.replay:  # the cut's M3 first: touch-off, pierce, cut height here
            await self._step(step, plan, report)
        segment = path.segments[point.segment]
        if (dx, dy) != (0.0, 0.0) and segment.feed is not None:
            back = f"G1 X{x / path.scale:.4f} Y{y / path.scale:.4f} F{segment.feed:g}"
            await self._unless_paused(self.backend.queue(back, source_line=number))
        rest = path.rest_of(point)
        if rest is not None:
            await self._unless_paused(self.backend.queue(rest, source_line=number))
        report.lines_sent += 1
        log.info("resumed_at", line=number, x=round(x, 3), y=round(y, 3), offset=[dx, dy])

    async def _stop_machine(self) -> None:
        """The program stops: motion held and, at the same time, the daemon told to end a
        cut that may be running (a refused line, a lost grbl, Ctrl-C mid-cut must never
        leave the torch burning at a standstill). Harmless when no cut runs."""
        self._pause.set()
        await asyncio.gather(self._hold(), self._abort_quietly())

    async def _abort_quietly(self) -> None:
        try:
            await self.daemon.request("abort")
        except DaemonError as exc:  # gone: its board's lease has turned the torch off
            log.error("abort_failed", error=str(exc))

    async def _unless_paused(self, work: Coroutine[Any, Any, _T]) -> _T | None:
        """``work``'s result (a queue waiting for room in the controller's buffer, a wait for
        idle), or None: given up when the program pauses meanwhile."""
        task = asyncio.ensure_future(work)
        paused = asyncio.ensure_future(self._pause.wait())
        try:
            await asyncio.wait({task, paused}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            paused.cancel()
        if task.done():
            return task.result()
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        return None

    async def _hold(self) -> None:
        try:
            await self.backend.hold()
        except BackendError as exc:
            log.error("hold_failed", error=str(exc))

    async def _step(self, step: Step, plan: ProgramPlan, report: SendReport) -> bool:
        """One step carried out; False when a pause came first and it did not go out (a
        streamed program carries on with it after the pause)."""
        if self._pause.is_set():
            return False  # paused (a fault, the daemon gone): nothing more goes out
        if isinstance(step, Refused):
            raise CommandError("", step.error)
        number = step.source_line
        if isinstance(step, MotionStep):
            line = self._reduced(step.line, step.words)
            queued = await self._unless_paused(self._queue(line, number))
            report.lines_sent += 1
            return queued is True
        if isinstance(step, DwellStep):
            await self._wait_motion()
            if self._pause.is_set():
                return False
            await asyncio.sleep(step.seconds)
            return True
        dialect = str(plan.dialect)
        if step.feed_note:
            await self.daemon.gcode(step.line, line_number=step.source_line, dialect=dialect)
            return True
        return await self._daemon_line(step, plan, report)

    async def _queue(self, line: str, number: int) -> bool:
        await self.backend.queue(line, source_line=number)
        return True

    async def _daemon_line(self, step: DaemonStep, plan: ProgramPlan, report: SendReport) -> bool:
        parsed = step.parsed
        xy = await self._wait_motion()
        await self._unless_paused(self._go.wait())  # an operator pause: not during it
        if self._pause.is_set():
            return False
        cuts = sum(1 for command in parsed.commands if starts_cut(command))
        if cuts:
            report.cut_lines.append(step.source_line)  # where a restart re-cuts from
            self.progress.cut += cuts  # the cut being cut: from its M3, pierce included
        self._at_line = step.source_line
        try:
            data = await self.daemon.gcode(
                step.line, line_number=step.source_line, xy=xy, dialect=str(plan.dialect)
            )
        finally:
            self._at_line = None
        plan.note_pins(data)  # an M190 changed them
        report.lines_sent += 1
        report.plasma_commands += len(parsed.commands)
        for command in parsed.commands:
            if isinstance(command, ResumePoint):
                report.resume_points.append(step.source_line)
            if isinstance(command, VelocityReduction):
                self.velocity_percent = command.percent if command.percent > 0 else 100.0
            if starts_cut(command):
                report.cuts_started += 1
                self._open_cut = step
            elif isinstance(command, TorchStop):
                self._open_cut = None
        return True

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
        xy = await self._unless_paused(self.backend.wait_idle())
        return (float("nan"), float("nan")) if xy is None else xy


class _Resumption:
    """A run that starts at a point of the path: which steps it skips, and which of them
    (the cut's own plasma lines, from its M3 on) are sent again at the point."""

    def __init__(self, path: ProgramPath, at: ResumeAt) -> None:
        self.path = path
        self.at = at
        segment = path.segments[at.point.segment]
        self.step_index = segment.step_index
        self.replay_from = (
            path.cut_steps[segment.cut] if segment.cut is not None else segment.step_index
        )
        self.replay: list[DaemonStep] = []

    def replays(self, index: int, step: Step) -> bool:
        if index >= self.replay_from and isinstance(step, DaemonStep):
            self.replay.append(step)
            return True
        return False


class RestartPosition:
    """The motion state the skipped lines of a restart leave, so the restart first goes
    where they end (``G0``) and then carries on modally: units, work offset (G54-G59),
    distance mode, motion mode and feed. Positions are kept in millimetres and written in
    the units in force. X and Y of G10, G28, G30, G53 and G92 lines are not targets (and
    those lines are not replayed: an origin set again here would be set at the wrong
    place); an incremental program whose start is unknown cannot be restarted."""

    _NOT_TARGETS = frozenset({10.0, 28.0, 28.1, 30.0, 30.1, 53.0, 92.0, 92.1})

    def __init__(self) -> None:
        self.modal = ModalState()
        self.offset: float | None = None  # G54-G59
        self.x_mm: float | None = None
        self.y_mm: float | None = None
        self.unknown = ""  # why the position is unknown, if it is
        self.pending = False

    def skip(self, step: Step) -> None:
        if not isinstance(step, MotionStep):
            return
        self.pending = True
        modal = self.modal
        modal.apply((w.letter, w.value) for w in step.words)
        codes = {w.value for w in step.words if w.letter == "G"}
        self.offset = next((code for code in codes if 54.0 <= code <= 59.0), self.offset)
        if codes & self._NOT_TARGETS:
            return
        for word in step.words:
            if word.letter not in "XY":
                continue
            value = modal.to_mm(word.value)
            now = self.x_mm if word.letter == "X" else self.y_mm
            if not modal.absolute:
                if now is None:
                    self.unknown = (
                        f"line {step.source_line} moves incrementally from an unknown start"
                    )
                    continue
                value += now
            if word.letter == "X":
                self.x_mm = value
            else:
                self.y_mm = value

    def lines(self) -> list[str]:
        """The lines that restore the state (once; then nothing). BackendError when the
        position the restart must go to is unknown."""
        if not self.pending:
            return []
        self.pending = False
        if self.unknown:
            raise BackendError(f"cannot restart here: {self.unknown}")
        modal = self.modal
        offset = f" G{self.offset:g}" if self.offset is not None else ""
        out = [f"G{20 if modal.inches else 21} G90{offset}"]
        target = "".join(f" {axis}{v / modal.mm_per_unit:.4f}" for axis, v in (("X", self.x_mm),
                         ("Y", self.y_mm)) if v is not None)  # fmt: skip
        if target:
            out.append(f"G0{target}")
        feed = modal.feed_in_units
        words = [f"G{modal.motion:g}" if modal.motion != 0 else "",
                 f"F{feed:g}" if feed is not None else ""]  # fmt: skip
        if any(words):
            out.append("".join(words))
        if not modal.absolute:
            out.append("G91")
        return out


def _cuts_in(step: Step) -> int:
    if not isinstance(step, DaemonStep) or step.feed_note:
        return 0
    return sum(1 for command in step.parsed.commands if starts_cut(command))


def _code_table(started: Mapping[str, Any], codes: Mapping[str, str] | None) -> dict[str, str]:
    """The daemon's ``controller.codes`` (from its program_start answer), the sender's own
    on top."""
    shop_codes = started.get("codes")
    return {**(shop_codes if isinstance(shop_codes, dict) else {}), **(codes or {})}


def _daemon_dialect(started: Mapping[str, Any]) -> tuple[Dialect, str] | None:
    """The daemon's configured dialect from its ``program_start`` answer, if it gave one."""
    try:
        return Dialect(str(started["dialect"])), "the daemon's controller.dialect"
    except (KeyError, ValueError):
        return None
