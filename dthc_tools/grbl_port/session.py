"""One grbl sender's session on the port: its lines run in order through the reference
sender's own step logic (:meth:`~dthc_tools.sender.Sender.stream_line`), one answer each;
its real-time bytes acted on at once.

- A line's answer comes when it has been carried out as far as a program's line is before
  the next one goes: motion queued on the table's grbl, a daemon line answered (an ``M3``
  once XY may move). Lines the sender streamed behind it wait in the port, unanswered, so
  nothing moves XY before the pierce.
- A refused line: ``[MSG:<why>]``, then ``error:20`` (grbl's "unsupported command"), and
  nothing of it ran; a line grbl refused: grbl's own ``error:N``. A line longer than the
  receiver holds: ``error:11``.
- ``M2``/``M30``: the program's end (its motion done, the daemon's program_end); the next
  G-code line starts a new program.
- ``?``: grbl's latest status report, as it wrote it. ``!``: the sender's pause (feed
  hold; a lit cut is ended by the daemon: torch out, safe height). A pause (the sender's,
  an arc lost, a fault) holds the line in progress unanswered. ``~`` after it: the daemon
  re-armed where it allows it, the cut's start sequence run where the torch stands, grbl
  released, the held line carried on; after an S1 stop, the pierce's cycle start; with
  nothing waiting, passed to grbl. 0x18: the cut stopped, the
  lines waiting dropped, grbl reset (its banner is the sender's sign that a reset
  happened). Override bytes (0x80 and up): passed to grbl.

- ``$`` lines (``$$``, ``$I``, ``$G``, ``$H``, ``$X``, ``$J=``): to grbl as written, its
  output and answer back; a jog is refused (``error:8``) while a cut is lit. The receive
  buffer a sender is told of is the port's own, not grbl's: ``$I``'s ``[OPT:...]`` and a
  report's ``Bf:`` give :data:`RX_BUFFER_BYTES`, less the bytes of the lines received and
  not yet answered (a sender counting characters against grbl's figure would stream past
  lines the port holds behind an ``M3``).

The dialect: the one given, else detected from the lines as they come (the daemon's
``controller.dialect`` until a line shows one).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Coroutine
from typing import Any, Protocol

import structlog

from dthc_bridge.controller.commands import CommandError
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.controller.states import IN_A_CUT
from dthc_bridge.controller.words import GcodeSyntaxError, words
from dthc_bridge.program.plan import ProgramPlan

from ..sender.backend import BackendError, MotionBackend
from ..sender.daemon_client import DaemonError
from ..sender.sender import Sender
from .receiver import Line, RealTime, Receiver

__all__ = ["RX_BUFFER_BYTES", "PortBackend", "PortSession"]

log = structlog.get_logger("dthc_tools.grbl_port")

STATUS_QUERY, FEED_HOLD, CYCLE_START, SOFT_RESET = 0x3F, 0x21, 0x7E, 0x18
UNSUPPORTED = 20  # grbl's "unsupported or invalid g-code command found in block"
LINE_OVERFLOW = 11  # grbl's "max characters per line exceeded"
NOT_IDLE = 8  # grbl's "'$' command cannot be used unless grbl is idle"
LIT = frozenset(str(state) for state in IN_A_CUT)  # the daemon's states with a cut on
BANNER = "Grbl 1.1h ['$' for help]"
RX_BUFFER_BYTES = 128  # grbl 1.1's: a sender's window stays as short as with a bare grbl


class PortBackend(MotionBackend, Protocol):
    """The table's grbl as the port needs it: a motion backend, its latest status report
    as written, and real-time bytes passed on."""

    status_line: str

    def realtime(self, byte: int) -> None: ...

    async def relay(self, text: str) -> list[str]:
        """A ``$`` line sent to grbl as written: what it says back, its answer last."""
        ...


class PortSession:
    def __init__(
        self,
        sender: Sender,
        grbl: PortBackend,
        write: Callable[[bytes], None],
        *,
        dialect: Dialect | None = None,
        codes: dict[str, str] | None = None,
    ) -> None:
        self.sender = sender
        self.grbl = grbl
        self._write = write
        self.dialect = dialect
        self.codes = codes or {}
        self.receiver = Receiver()
        self._lines: asyncio.Queue[Line] = asyncio.Queue()
        self._plan: ProgramPlan | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._current: asyncio.Task[list[str]] | None = None  # the line being carried out
        self._resumed = asyncio.Event()  # cycle start has resumed a paused program
        self.answered = 0
        self.unanswered_bytes = 0  # of the lines received, ends included, not yet answered

    # --- from the sender -------------------------------------------------------------------

    def received(self, data: bytes) -> None:
        for item in self.receiver.feed(data):
            if isinstance(item, RealTime):
                self._realtime(item.byte)
            else:
                self.unanswered_bytes += _wire_bytes(item)
                self._lines.put_nowait(item)

    def _realtime(self, byte: int) -> None:
        if byte == STATUS_QUERY:
            if self.grbl.status_line:
                self._say(_with_rx_free(self.grbl.status_line, self._rx_free()))
        elif byte == FEED_HOLD:
            self._background(self.sender.pause())
        elif byte == CYCLE_START:
            progress = self.sender.progress
            if self._plan is not None and self.sender.stream_paused:
                self._background(self._resume(self._plan))
            elif progress.waiting_cycle_start or progress.operator_paused:
                self._background(self.sender.cycle_start())
            else:
                self.grbl.realtime(byte)
        elif byte == SOFT_RESET:
            # At once, as grbl does: what waits is gone before another byte is read, so
            # lines the sender writes after the reset are kept.
            while not self._lines.empty():
                self.unanswered_bytes -= _wire_bytes(self._lines.get_nowait())
            if self._current is not None:
                self._current.cancel()  # an M3 waiting for the pierce: the daemon aborts it
            self.receiver.reset()
            self._background(self._reset())
        else:
            self.grbl.realtime(byte)

    # --- the lines, in order ---------------------------------------------------------------

    async def run(self) -> None:
        """Until cancelled: each line carried out, then answered."""
        try:
            while True:
                line = await self._lines.get()
                current = self._current = asyncio.ensure_future(self._answer(line))
                await asyncio.wait({current})
                self._current = None
                self.unanswered_bytes -= _wire_bytes(line)
                if current.cancelled():
                    continue  # a reset: grbl forgets the line, so the sender does too
                for text in current.result():
                    self._say(text)
                self.answered += 1
        finally:
            if self._current is not None:
                self._current.cancel()
            for task in list(self._tasks):
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)

    async def _answer(self, line: Line) -> list[str]:
        if line.overflow:
            return [f"error:{LINE_OVERFLOW}"]
        text = line.text.strip()
        if not text or _comment_only(text):
            return ["ok"]
        if text.startswith("$"):
            return await self._relay(text)
        if self._plan is None:
            self._plan = await self.sender.open_stream(dialect=self.dialect, codes=self.codes)
        plan = self._plan
        try:
            await self.sender.stream_line(plan, text)
        except CommandError as exc:
            return [f"[MSG:{_one_line(str(exc))}]", f"error:{UNSUPPORTED}"]
        except (DaemonError, BackendError) as exc:
            failure: Exception | None = exc
            while failure is not None and self.sender.stream_paused:
                # Paused, not refused: the line waits unanswered (grbl holds its buffer the
                # same way) until cycle start has resumed the program, then goes on.
                log.info("grbl_port_line_held", line=text, reason=str(failure))
                self._resumed.clear()
                await self._resumed.wait()
                try:
                    await self.sender.stream_rest(plan)
                    failure = None
                except CommandError as refused:
                    return [f"[MSG:{_one_line(str(refused))}]", f"error:{UNSUPPORTED}"]
                except (DaemonError, BackendError) as again:
                    failure = again
            if failure is not None:
                log.warning("grbl_port_line_failed", line=text, error=str(failure))
                return [f"[MSG:{_one_line(str(failure))}]", f"error:{_grbl_code(str(failure))}"]
        if _ends_program(text):
            await self._close()
        return ["ok"]

    async def _relay(self, text: str) -> list[str]:
        """grbl's own commands (``$$``, ``$I``, ``$G``, ``$H``, ``$X``, ``$J=``) to grbl, its
        answer back as it wrote it; a jog never while a cut is lit."""
        if text[:3].upper() == "$J=":
            state = (await self.sender.daemon.request("status")).get("state")
            if state in LIT:
                return [f"[MSG:jog refused: a cut is lit ({state})]", f"error:{NOT_IDLE}"]
        try:
            said = await self.grbl.relay(text)
        except BackendError as exc:
            return [f"[MSG:{_one_line(str(exc))}]", f"error:{_grbl_code(str(exc))}"]
        return [_with_rx_size(line) for line in said]

    def _rx_free(self) -> int:
        return max(0, RX_BUFFER_BYTES - self.unanswered_bytes)

    async def _resume(self, plan: ProgramPlan) -> None:
        """Cycle start after a pause: re-armed, the cut started again where the torch
        stands when the pause ended it, grbl released; the held line goes on."""
        await self.sender.resume_stream(plan)
        self._resumed.set()

    async def _close(self) -> None:
        if self._plan is not None:
            self._plan = None
            await self.sender.close_stream()

    async def _reset(self) -> None:
        """After 0x18 (the waiting lines already dropped): the cut stopped, grbl reset, the
        banner."""
        if self._plan is not None:
            self._plan = None
            await self.sender.stop()
        try:
            await self.grbl.clear()
        except BackendError as exc:
            self._say(f"[MSG:{_one_line(str(exc))}]")
        self._say(BANNER)

    # --- to the sender ---------------------------------------------------------------------

    def _say(self, text: str) -> None:
        self._write(text.encode("ascii", "replace") + b"\r\n")

    def _background(self, work: Coroutine[Any, Any, None]) -> None:
        task = asyncio.ensure_future(self._logged(work))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _logged(self, work: Coroutine[Any, Any, None]) -> None:
        try:
            await work
        except (BackendError, DaemonError, CommandError) as exc:
            self._say(f"[MSG:{_one_line(str(exc))}]")


def _wire_bytes(line: Line) -> int:
    return len(line.text.encode("ascii", "replace")) + 1  # its end (LF)


def _with_rx_size(text: str) -> str:
    """``[OPT:flags,blocks,rx]`` with the port's receive buffer as rx."""
    if not (text.startswith("[OPT:") and text.endswith("]")):
        return text
    fields = text[5:-1].split(",")
    if len(fields) >= 3:
        fields[2] = str(RX_BUFFER_BYTES)
    return "[OPT:" + ",".join(fields) + "]"


def _with_rx_free(report: str, free: int) -> str:
    """A status report with ``Bf:blocks,rx``'s rx as the port's free bytes."""
    fields = report.split("|")
    for i, field in enumerate(fields):
        if field.startswith("Bf:") and "," in field:
            blocks, _, rest = field[3:].partition(",")
            tail = rest[len(rest.rstrip(">")) :]
            fields[i] = f"Bf:{blocks},{free}{tail}"
    return "|".join(fields)


def _comment_only(text: str) -> bool:
    with contextlib.suppress(GcodeSyntaxError):
        return not words(text)
    return False


def _ends_program(text: str) -> bool:
    try:
        return any(letter == "M" and value in (2.0, 30.0) for letter, value in words(text))
    except GcodeSyntaxError:
        return False


def _one_line(text: str) -> str:
    return " ".join(text.split()).replace("]", ")")


def _grbl_code(message: str) -> int:
    """grbl's own code when grbl refused the line (``... error:N (...)``), else 20."""
    _, found, rest = message.partition("error:")
    number = rest.split(" ", 1)[0]
    return int(number) if found and number.isdigit() else UNSUPPORTED
