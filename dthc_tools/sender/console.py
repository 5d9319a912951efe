"""The operator console of ``dthc-bridge send``: progress on one line, keys at the table.

Keys (single keys, no Enter, when the terminal is interactive):

    c  cycle start: release a G200 S1 stop after pierce, or resume after a pause
    p  pause: feed hold and THC hold (c resumes)
    s  stop: torch off, safe height, motion held; the program ends
    +  torch up 1 V       -  torch down 1 V
    >  feed +10 %         <  feed -10 %         =  feed 100 %   (grbl's feed override)
    u  cut height +0.1 mm d  cut height -0.1 mm (PlasmaC's height override)
    r  after an error: re-arm, then restart from the last resume point (G100 P0) or the
       start of the cut the error happened in
    q  after an error: quit

Not interactive (a pipe, a service, CI): no keys and no progress line; ``--yes-cycle-start``
presses cycle start at each S1 stop, and a restart is ``--start-line``.
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
from .sender import Sender, SendReport

__all__ = ["KEYS", "OperatorConsole"]

log = structlog.get_logger("dthc_tools.sender.console")

KEYS = (
    "c cycle start · p pause · s stop · +/- torch 1 V · u/d height 0.1 mm · >/</= feed · "
    "r re-arm+restart · q quit"
)
FEED_KEYS = {">": "+10", "<": "-10", "=": "reset"}
BAR = 20
TORCH_STEP_V = 1.0
HEIGHT_STEP_MM = 0.1


class OperatorConsole:
    def __init__(self, sender: Sender, *, out: TextIO = sys.stderr, interactive: bool) -> None:
        self.sender = sender
        self.out = out
        self.interactive = interactive
        self.telemetry: dict[str, Any] = {}
        self.messages: list[str] = []
        self._keys: asyncio.Queue[str] = asyncio.Queue()  # r / q, for the job loop
        self._pressed: asyncio.Queue[str] = asyncio.Queue()  # from the terminal
        sender.daemon.on_telemetry(self.telemetry.update)

    def status_line(self) -> str:
        p = self.sender.progress
        done = p.line / p.total_lines if p.total_lines else 0.0
        filled = round(done * BAR)
        t = self.telemetry
        volts = t.get("voltage_v")
        z = t.get("z_mm")
        state = "waiting for cycle start" if p.waiting_cycle_start else str(t.get("state", "-"))
        if p.operator_paused:
            state = "paused (c resumes)"
        arc = f"{volts:6.1f} V" if isinstance(volts, int | float) else "     - V"
        height = f"{z:5.2f} mm" if isinstance(z, int | float) else "    - mm"
        return (
            f"line {p.line}/{p.total_lines} | cut {p.cut}/{p.total_cuts} | {state} | "
            f"{arc} {height} | [{'#' * filled}{'-' * (BAR - filled)}] {done:4.0%}"
        )

    async def press(self, key: str) -> None:
        """One key, as the operator pressed it; an error is shown, never raised."""
        sender = self.sender
        try:
            if key == "c":
                await sender.cycle_start()
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
            else:
                self._keys.put_nowait(key)  # r / q: the job loop's, after an error
        except (DaemonError, BackendError) as exc:
            self._say(f"{key}: {exc}")

    def _say(self, text: str) -> None:
        self.messages.append(text)
        log.warning("console", message=text)
        if self.interactive:
            self.out.write(f"\r\x1b[K{text}\n")
            self.out.flush()

    async def run_job(
        self,
        lines: Sequence[str],
        *,
        start_line: int = 1,
        dialect: Dialect | None = None,
        codes: Mapping[str, str] | None = None,
    ) -> SendReport:
        """Run the program; after an error an interactive operator may re-arm and restart."""
        with self._keyboard(), self._progress():
            while True:
                report = await self.sender.run(
                    lines, start_line=start_line, dialect=dialect, codes=codes
                )
                restart = report.restart_line
                if report.ok or not self.interactive or restart is None:
                    return report
                self._say(f"stopped at line {report.error_line}: {report.error}")
                self._say(f"r: re-arm and restart from line {restart} · q: quit")
                if await self._restart_key() != "r":
                    return report
                try:
                    await self.sender.rearm()
                except (DaemonError, BackendError) as exc:
                    self._say(f"re-arm failed: {exc}")
                    return report
                start_line = restart

    async def _restart_key(self) -> str:
        while True:
            key = await self._keys.get()
            if key in "rq" and key:
                return key

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
