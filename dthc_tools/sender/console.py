"""The operator console of ``dthc-bridge send``: progress on one line, keys at the table.

Keys (single keys, no Enter, when the terminal is interactive):

    c  cycle start: release a G200 S1 stop after pierce, or resume after a pause
    p  pause: motion held; a cut is ended (torch off, safe height: a paused program never
       keeps the arc lit), and c resumes it where the torch stands (touch-off, pierce)
    s  stop: torch off, safe height, motion held; the program ends
    a  re-arm after a fault (when no program is paused: then g or r re-arm)
    +  torch up 1 V       -  torch down 1 V
    >  feed +10 %         <  feed -10 %         =  feed 100 %   (grbl's feed override)
    u  cut height +0.1 mm d  cut height -0.1 mm (PlasmaC's height override)
After an error (arc lost, a fault, s), the program is paused where the torch stopped:

    [  back along the path 5 mm   ]  forward 5 mm        (paused motion, torch off)
    4 6 8 2  cut recovery: the torch 1 mm left, right, up, down off the path;  0 back on it
    g  resume here: re-arm, the start sequence where the torch stands, the program goes on
    r  re-arm, then restart from the last resume point (G100 P0) or the start of the cut
    q  quit

Not interactive (a pipe, a service, CI): no keys and no progress line; ``--yes-cycle-start``
presses cycle start at each S1 stop, and a restart is ``--start-line``. ``--wait-operator``
waits after an error for the same actions from a panel (:mod:`.remote`).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import termios
import tty
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, TextIO

import structlog

from dthc_bridge.controller.dialect import Dialect

from .backend import BackendError
from .daemon_client import DaemonError
from .recovery import PausedProgram, ResumeAt
from .sender import Sender, SendReport

__all__ = ["KEYS", "OperatorConsole"]

log = structlog.get_logger("dthc_tools.sender.console")

KEYS = (
    "c cycle start · p pause · s stop · a re-arm · +/- torch 1 V · u/d height 0.1 mm · "
    ">/</= feed · "
    "after an error: [/] path -/+5 mm · 4/6/8/2 offset 1 mm · 0 on path · g resume here · "
    "r re-arm+restart · q quit"
)
PATH_STEP_MM = 5.0
OFFSET_STEP_MM = 1.0
OFFSET_KEYS = {"4": (-1.0, 0.0), "6": (1.0, 0.0), "8": (0.0, 1.0), "2": (0.0, -1.0)}
PAUSED_ACTIONS = frozenset({"path_move", "recovery_offset", "resume", "restart", "quit"})
FEED_KEYS = {">": "+10", "<": "-10", "=": "reset"}
BAR = 20
TORCH_STEP_V = 1.0
HEIGHT_STEP_MM = 0.1


class OperatorConsole:
    def __init__(
        self,
        sender: Sender,
        *,
        out: TextIO = sys.stderr,
        interactive: bool,
        wait_operator: bool = False,
    ) -> None:
        self.sender = sender
        self.out = out
        self.interactive = interactive
        # After an error: wait for the operator (keys, or a panel's requests) to move, resume,
        # restart or quit, rather than end with the error.
        self.waits = interactive or wait_operator
        self.telemetry: dict[str, Any] = {}
        self.messages: list[str] = []
        # What the operator asks of a paused program, for the job loop, with the answer.
        self._actions: asyncio.Queue[tuple[str, dict[str, Any], asyncio.Future[Any]]] = (
            asyncio.Queue()
        )
        self.paused: PausedProgram | None = None
        self.operator_stop = False  # the paused program stopped for a pause, not an error
        self._pressed: asyncio.Queue[str] = asyncio.Queue()  # from the terminal
        sender.daemon.on_telemetry(self.telemetry.update)

    def status_line(self) -> str:
        """Where the torch is in the program (the line it is on, the cut being cut), the
        arc voltage beside the THC's target, and the height above the plate."""
        p = self.sender.progress
        done = p.line / p.total_lines if p.total_lines else 0.0
        filled = round(done * BAR)
        t = self.telemetry
        state = "waiting for cycle start" if p.waiting_cycle_start else str(t.get("state", "-"))
        if self.paused is not None:
            state = "paused (c resumes here)" if self.operator_stop else "stopped (g resumes here)"
        elif p.operator_paused:
            state = "paused (c resumes)"
        arc = f"arc {_figure(t.get('voltage_v'), 6, 1)} V"
        target = f"target {_figure(t.get('target_v'), 5, 1)} V"
        height = f"height {_figure(t.get('height_mm'), 5, 2)} mm"
        return (
            f"line {p.line}/{p.total_lines} | cut {p.cut}/{p.total_cuts} | {state} | "
            f"{arc}, {target} | {height} | [{'#' * filled}{'-' * (BAR - filled)}] {done:4.0%}"
        )

    async def press(self, key: str) -> None:
        """One key, as the operator pressed it; an error is shown, never raised."""
        sender = self.sender
        try:
            if key == "c":
                await self.cycle_start()
            elif key == "a":
                await self.rearm()
            elif key == "p":
                await sender.pause()
            elif key == "s":
                await sender.stop()
            elif key in "+-" and key:
                await sender.torch(TORCH_STEP_V if key == "+" else -TORCH_STEP_V)
            elif key in ("u", "d"):
                await sender.height(HEIGHT_STEP_MM if key == "u" else -HEIGHT_STEP_MM)
            elif key in FEED_KEYS:
                sender.feed_override(FEED_KEYS[key])
            elif key in "[]" and key:
                step = PATH_STEP_MM if key == "]" else -PATH_STEP_MM
                where = await self.act("path_move", mm=step)
                self._say(f"torch at line {where['line']}, X{where['x_mm']} Y{where['y_mm']}")
            elif key in OFFSET_KEYS or key == "0":
                x, y = self.paused.offset_mm if self.paused is not None else (0.0, 0.0)
                dx, dy = OFFSET_KEYS.get(key, (-x, -y))
                await self.act("recovery_offset", x_mm=round(x + dx, 3), y_mm=round(y + dy, 3))
            elif key == "g":
                await self.act("resume")
            elif key in "rq" and key:
                await self.act("restart" if key == "r" else "quit")
        except (DaemonError, BackendError) as exc:
            self._say(f"{key}: {exc}")

    async def cycle_start(self) -> None:
        """After the operator's pause of a cut: resume where the torch stands (the start
        sequence there). Else the sender's: an S1 stop, a pause with nothing lit."""
        if self.paused is not None and self.operator_stop:
            await self.act("resume")
        else:
            await self.sender.cycle_start()

    async def rearm(self) -> None:
        """The daemon leaves its fault state (a stale error is cleared with it). A paused
        program re-arms with its resume or restart instead."""
        if self.sender.progress.running or self.paused is not None:
            raise BackendError("re-arm: a program is running or paused (g or r re-arm it)")
        await self.sender.daemon.request("rearm")
        self._say("re-armed")

    async def act(self, name: str, **args: Any) -> Any:
        """An action on a paused program (keys, a panel): done by the job loop once the
        program has stopped; its answer, or BackendError with the reason. During an
        operator's pause (p) a move first stops the cut where the torch is."""
        if name not in PAUSED_ACTIONS:
            raise BackendError(f"{name}: unknown action")
        progress = self.sender.progress
        if progress.running:
            if name in ("path_move", "recovery_offset") and progress.operator_paused:
                if not self.sender.cut_paused:  # paused between cuts: the program ends here
                    await self.sender.stop()
                # else the pause has ended the cut, and the program is stopping by itself
            elif name != "quit":
                raise BackendError(f"{name}: the program is running (pause it, or stop it)")
        elif self.paused is None and name != "quit":
            raise BackendError(f"{name}: no program is paused")
        answer: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._actions.put_nowait((name, args, answer))
        return await answer

    def _say(self, text: str) -> None:
        """Once: on the terminal when there is one, else in the log."""
        self.messages.append(text)
        if self.interactive:
            self.out.write(f"\r\x1b[K{text}\n")
            self.out.flush()
        else:
            log.warning("console", message=text)

    async def run_job(
        self,
        lines: Sequence[str],
        *,
        start_line: int = 1,
        dialect: Dialect | None = None,
        codes: Mapping[str, str] | None = None,
    ) -> SendReport:
        """Run the program; after an error the operator may move along the path, resume
        where the torch stands, re-arm and restart, or quit (when someone is there)."""
        resume: ResumeAt | None = None
        whole: SendReport | None = None  # every run of the job: the summary counts them all
        with self._keyboard(), self._progress():
            while True:
                report = await self.sender.run(
                    lines, start_line=start_line, dialect=dialect, codes=codes, resume=resume
                )
                whole = report if whole is None else _merged(whole, report)
                # An operator's pause is waited on whoever paused (a panel, the controller's
                # hold button): it is there to be resumed, not an end.
                if report.ok or not (self.waits or report.operator_paused):
                    return whole
                self.operator_stop = report.operator_paused
                if report.operator_paused:
                    self._say(f"paused at line {report.error_line}: torch off and raised; "
                              "c resumes here (touch-off, pierce where it stands)")  # fmt: skip
                else:
                    self._say(f"stopped at line {report.error_line}: {report.error}")
                choice = await self._paused(report)
                if choice is None:
                    return whole
                start_line, resume = choice

    async def _paused(self, report: SendReport) -> tuple[int, ResumeAt | None] | None:
        """The operator's actions until a resume, a restart or quit: (start line, resume
        point) to run from, or None to end."""
        sender = self.sender
        paused = None
        if report.operator_paused:
            await sender.daemon_idle()  # the torch rises to safe height before it moves
        if sender.path is not None and sender.path.segments:
            paused = PausedProgram(sender, sender.path, up_to_step=sender.last_step)
            try:
                await paused.locate()
            except BackendError as exc:
                self._say(f"paused motion unavailable: {exc}")
                paused = None
        self.paused = paused
        sender.progress.paused_at = paused.where() if paused is not None else None
        restart = report.restart_line
        self._say(("g: resume here · [/]: along the path · " if paused else "")
                  + (f"r: re-arm and restart from line {restart} · " if restart else "")
                  + "q: quit")  # fmt: skip
        try:
            while True:
                name, args, answer = await self._actions.get()
                try:
                    result = await self._paused_action(name, args, paused, restart)
                except (DaemonError, BackendError) as exc:
                    answer.set_exception(BackendError(str(exc)))
                    continue
                if paused is not None:
                    sender.progress.paused_at = paused.where()
                if isinstance(result, tuple) or result is None:
                    answer.set_result({})
                    return result
                answer.set_result(result)
        finally:
            self.paused = None
            sender.progress.paused_at = None

    async def _paused_action(
        self,
        name: str,
        args: dict[str, Any],
        paused: PausedProgram | None,
        restart: int | None,
    ) -> dict[str, Any] | tuple[int, ResumeAt | None] | None:
        if name == "quit":
            return None
        if name == "restart":
            if restart is None:
                raise BackendError("restart: no line to restart from")
            await self.sender.rearm()
            return restart, None
        if paused is None:
            raise BackendError(f"{name}: the torch is not on the program's path")
        if name == "resume":
            at = paused.resume_at()
            await self.sender.rearm()
            await self.sender.daemon_idle()  # still raising after a pause: M3 waits for it
            return 1, at
        if name == "path_move":
            return await paused.move_along(_number(args, "mm"), _number(args, "feed_mm_min", None))
        return await paused.set_offset(
            _number(args, "x_mm"), _number(args, "y_mm"), _number(args, "feed_mm_min", None)
        )

    @contextlib.contextmanager
    def _keyboard(self) -> Iterator[None]:
        """Single keys from the terminal (cbreak: no Enter, no echo), restored on the way out."""
        if not self.interactive:
            yield
            return
        fd = sys.stdin.fileno()
        saved = termios.tcgetattr(fd)
        loop = asyncio.get_running_loop()

        def readable() -> None:
            # The descriptor, not sys.stdin: its buffer would swallow the bytes of an arrow
            # key or of two quick keys, and the descriptor would no longer look readable.
            data = os.read(fd, 64)
            if not data:  # end of input: no more keys
                loop.remove_reader(fd)
                return
            for key in data.decode("ascii", "ignore"):
                self._pressed.put_nowait(key)

        async def one_at_a_time() -> None:
            # In order, each done before the next: a quick p then c must not resume a hold
            # that has not completed yet.
            while True:
                await self.press(await self._pressed.get())

        tty.setcbreak(fd)
        loop.add_reader(fd, readable)
        keys = asyncio.ensure_future(one_at_a_time())
        try:
            yield
        finally:
            keys.cancel()
            loop.remove_reader(fd)
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)

    @contextlib.contextmanager
    def _progress(self) -> Iterator[None]:
        if not self.interactive:
            yield
            return
        self.out.write(f"keys: {KEYS}\n")

        async def draw() -> None:
            while True:
                self.out.write(f"\r\x1b[K{self.status_line()}")
                self.out.flush()
                await asyncio.sleep(0.2)

        task = asyncio.ensure_future(draw())
        try:
            yield
        finally:
            task.cancel()
            self.out.write(f"\r\x1b[K{self.status_line()}\n")


_REQUIRED = object()


def _figure(value: object, width: int, decimals: int) -> str:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return f"{value:{width}.{decimals}f}"
    return "-".rjust(width)


def _merged(whole: SendReport, run: SendReport) -> SendReport:
    """The job so far and its latest run (after a resume or a restart): its outcome is the
    latest run's, its counts the whole job's."""
    again = bool(run.cut_lines and whole.cut_lines and run.cut_lines[0] == whole.cut_lines[-1])
    if again:  # the run began by cutting again the cut the last one stopped in: one cut
        run.cuts_started -= 1
        del run.cut_lines[0]
    run.lines_run |= whole.lines_run
    run.lines_sent += whole.lines_sent
    run.plasma_commands += whole.plasma_commands
    run.cuts_started += whole.cuts_started
    run.cycle_starts[:0] = whole.cycle_starts
    run.paused[:0] = whole.paused
    run.resume_points = sorted(set(whole.resume_points) | set(run.resume_points))
    run.cut_lines[:0] = whole.cut_lines
    return run


def _number(args: dict[str, Any], key: str, default: Any = _REQUIRED) -> Any:
    """An argument that must be a number (or absent, when it has a default)."""
    if key not in args:
        if default is _REQUIRED:
            raise BackendError(f"{key}: required argument is missing")
        return default
    value = args[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BackendError(f"{key}: {value!r} is not a number")
    return float(value)
