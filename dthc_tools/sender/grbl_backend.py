"""The grbl / grblHAL motion backend: the XY axes of a table whose Z is on the DTHC board.

Over a serial port (``/dev/ttyUSB0``, a pty) or TCP (``socket://host:port``, grblHAL over
Ethernet), through the daemon's own transports. On connect: a soft reset and the banner
(a USB Arduino also reboots when the port opens; its boot banner serves as well), then
``$I`` for the planner size and the receive buffer the character counting must use.

- **Streaming**: character counting against the firmware's receive buffer (``count``,
  the default), or one line at a time (``sync``: each ``ok`` before the next line). Every
  line is answered ``ok`` or ``error:N``; on an error the motion is held at once (the
  lines streamed behind the refused one would run on without it) and the program stops
  naming the refused line and grbl's reason.
- **Status**: ``?`` at ``poll_hz`` (5-20 Hz). Each report updates the state and the work
  position; the XY speed is measured from positions (:class:`~.grbl_protocol.SpeedMeter`)
  and given to the motion listeners (the sender sends it to the daemon as the anti-dive
  input of a board without an XY speed input).
- **Verbs**: ``wait_idle`` = every line acknowledged and then a report of ``Idle`` with the
  planner empty; ``hold`` = ``!`` until ``Hold:0``; ``resume`` = ``~``; ``clear`` = hold if
  moving (a reset in motion loses position: ``ALARM:3``), soft reset, banner, re-sync.
- Z words and the spindle's M3/M4/M5/S never reach grbl (:func:`~.grbl_protocol.for_grbl`).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import structlog

from dthc_bridge.transport import Transport, TransportError, open_transport

from .backend import BackendError, MotionListener, Where
from .grbl_protocol import (
    CYCLE_START,
    FEED_HOLD,
    FEED_OVERRIDE,
    JOG_CANCEL,
    SOFT_RESET,
    STATUS_QUERY,
    CharCounter,
    FirmwareInfo,
    LineRefused,
    SpeedMeter,
    StatusReport,
    alarm_text,
    error_text,
    for_grbl,
    is_banner,
    parse_status,
)

__all__ = ["GrblBackend", "GrblFigures"]

log = structlog.get_logger("dthc_tools.sender.grbl")

BANNER_TIMEOUT_S = 3.0  # an Arduino's bootloader takes 1-2 s after the port opens
ANSWER_TIMEOUT_S = 5.0  # $I, a hold coming to rest
STATUS_SILENCE_S = 2.0  # no status report for this long: the controller is gone
MOVING = ("Run", "Jog", "Home")


@dataclass
class GrblFigures:
    """Counted for the log and the tests."""

    lines_sent: int = 0
    bytes_sent: int = 0
    max_in_flight_bytes: int = 0
    status_reports: int = 0
    resets: int = 0


@dataclass
class _Sent:
    text: str
    source_line: int | None


class GrblBackend:
    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 115_200,
        poll_hz: float = 10.0,
        streaming: str = "count",
        speed_window_s: float = 0.1,
    ) -> None:
        if not 5.0 <= poll_hz <= 20.0:
            raise ValueError(f"grbl status polling at {poll_hz:g} Hz: use 5-20 Hz")
        if streaming not in ("count", "sync"):
            raise ValueError(f"grbl streaming {streaming!r}: 'count' or 'sync'")
        self.url = url
        self.baudrate = baudrate
        self.poll_s = 1.0 / poll_hz
        self.streaming = streaming
        self.info = FirmwareInfo()
        self.status: StatusReport | None = None
        self.status_line = ""  # the latest report as grbl wrote it (the grbl port's '?')
        self.position: tuple[float, float] = (float("nan"), float("nan"))
        self._speed_mm_s = 0.0
        self.figures = GrblFigures()
        self._transport: Transport | None = None
        self._buffer = b""
        self._counter = CharCounter(self.info.rx_buffer)
        self._sent: deque[_Sent] = deque()
        self._failure: BackendError | None = None
        self._changed = asyncio.Event()
        self._status_seq = 0
        self._status_seq_at_ack = 0
        self._status_at = time.monotonic()
        self._banners = 0
        self._info_lines: list[str] | None = None  # collecting $I output
        self._relayed: list[str] | None = None  # a relayed command's output, its answer last
        self._resetting = True  # a banner is expected (connect, clear), else a failure
        self._since_idle = 0  # lines sent since the last wait_idle
        self._wco: tuple[float, ...] | None = None
        self._meter = SpeedMeter(speed_window_s)
        self._listeners: list[MotionListener] = []
        self._poll: asyncio.Task[None] | None = None

    # --- connection ------------------------------------------------------------------------

    async def connect(self) -> FirmwareInfo:
        try:
            self._transport = await open_transport(
                self.url, self._on_bytes, self._on_lost, baudrate=self.baudrate
            )
        except (TransportError, ValueError) as exc:
            raise BackendError(f"grbl at {self.url}: {exc}") from None
        # Whatever it printed before we opened is gone: a reset makes it say who it is.
        banners = self._banners
        self._write(SOFT_RESET)
        await self._until(lambda: self._banners > banners, BANNER_TIMEOUT_S,
                          f"no grbl banner from {self.url} after a soft reset")  # fmt: skip
        await asyncio.sleep(0.05)  # the [MSG:...] lines that follow a banner
        self._resetting = False
        self._info_lines = []
        await self._command("$I")
        for line in self._info_lines:
            self.info.read(line)
        self._info_lines = None
        self._counter = CharCounter(self.info.rx_buffer)
        log.info(
            "grbl_connected", url=self.url, banner=self.info.banner, version=self.info.version,
            firmware=self.info.firmware, planner_blocks=self.info.planner_blocks,
            rx_buffer=self.info.rx_buffer, streaming=self.streaming,
        )  # fmt: skip
        self._status_at = time.monotonic()
        self._poll = asyncio.create_task(self._poll_loop(), name="grbl-status")
        seq = self._status_seq
        await self._until(lambda: self._status_seq > seq, ANSWER_TIMEOUT_S,
                          "grbl does not answer status queries")  # fmt: skip
        assert self.status is not None
        if self.status.state == "Alarm":
            raise BackendError(
                "grbl is in alarm: check the machine, then home ($H) or unlock ($X) it "
                "from its console before a program"
            )
        return self.info

    async def _command(self, text: str) -> None:
        """A line sent alone, its ok awaited (set-up: nothing is streaming)."""
        await self._send(text, None)
        await self._until(lambda: not self._sent, ANSWER_TIMEOUT_S, f"no answer to {text}")
        self._raise_failure()

    def _on_lost(self, exc: Exception | None) -> None:
        self._fail(BackendError(f"grbl at {self.url}: connection lost ({exc or 'closed'})"))

    def _write(self, data: bytes) -> None:
        if self._transport is None or not self._transport.is_open:
            raise BackendError(f"grbl at {self.url}: not connected")
        self._transport.write(data)

    # --- what grbl says --------------------------------------------------------------------

    def _on_bytes(self, data: bytes) -> None:
        self._buffer += data
        *lines, self._buffer = self._buffer.split(b"\n")
        for raw in lines:
            line = raw.decode("ascii", "replace").strip()
            if line:
                self._on_line(line)
        self._changed.set()

    def _on_line(self, line: str) -> None:
        relayed = self._relayed
        if relayed is not None and not line.startswith("<"):
            relayed.append(line)  # a relayed command's output and answer: the caller's
            if line == "ok" or line.startswith("error:"):
                self._acknowledge()
            return
        if line == "ok":
            self._acknowledge()
        elif line.startswith("error:"):
            sent = self._acknowledge()
            code = _code(line)
            where = f"line {sent.source_line}: " if sent and sent.source_line else ""
            self._write_quietly(FEED_HOLD)  # what streamed behind it must not run without it
            self._fail(BackendError(
                f"grbl refused {where}{sent.text if sent else '?'!r}: {line} ({error_text(code)})",
                line_number=sent.source_line if sent else None,
            ))  # fmt: skip
        elif line.startswith("<"):
            self._on_status(line)
        elif line.startswith("ALARM:"):
            self._fail(BackendError(f"grbl {line}: {alarm_text(_code(line))}"))
        elif is_banner(line):
            self.info.banner = line
            self._banners += 1
            self._counter.clear()  # a reset empties its receive buffer
            self._sent.clear()
            if not self._resetting:
                # A brownout, a DTR or EMI reset: the modal state (G91, units, feed, work
                # offsets) is gone and the queued motion with it. Never carry on silently.
                self._fail(BackendError(f"grbl at {self.url} reset unexpectedly ({line}): "
                                        "the program's modal state is lost"))  # fmt: skip
        elif self._info_lines is not None and line.startswith("["):
            self._info_lines.append(line)
        else:
            log.info("grbl_message", text=line)

    def _acknowledge(self) -> _Sent | None:
        self._counter.acknowledged()
        self._status_seq_at_ack = self._status_seq
        return self._sent.popleft() if self._sent else None

    def _on_status(self, line: str) -> None:
        try:
            report = parse_status(line)
        except ValueError as exc:
            log.warning("grbl_status_unreadable", text=line, error=str(exc))
            return
        self.status = report
        self.status_line = line
        self._status_seq += 1
        self._status_at = time.monotonic()
        self.figures.status_reports += 1
        if report.wco is not None:
            self._wco = report.wco
        position = report.work_position(self._wco)
        if position is None or len(position) < 2:
            return
        self.position = (position[0], position[1])
        measured = self._meter.add(self._status_at, position[0], position[1])
        speed = anti_dive_speed(report, measured)
        self._speed_mm_s = speed if speed is not None else 0.0
        if speed is not None:
            for listener in self._listeners:
                listener(speed, report.state)

    def _fail(self, error: BackendError) -> None:
        if self._failure is None:
            self._failure = error
            log.error("grbl_failure", error=str(error))
        self._changed.set()

    def _raise_failure(self) -> None:
        if self._failure is not None:
            raise self._failure

    def _write_quietly(self, data: bytes) -> None:
        try:
            self._write(data)
        except BackendError as exc:
            log.error("grbl_write_failed", error=str(exc))

    async def _until(
        self,
        done: Callable[[], bool],
        timeout_s: float | None,
        what: str,
        *,
        failures: bool = True,
    ) -> None:
        """Wait for ``done()`` (re-checked on every line from grbl). A failure raises it, even
        when ``done()`` holds too (a refused line must never pass for idle), unless
        ``failures`` is False (hold and clear: they are what follows a failure). A timeout
        after ``timeout_s`` becomes a BackendError naming ``what``."""
        loop = asyncio.get_running_loop()
        deadline = None if timeout_s is None else loop.time() + timeout_s
        while True:
            self._changed.clear()
            if failures:
                self._raise_failure()
            if done():
                return
            remaining = None if deadline is None else deadline - loop.time()
            if remaining is not None and remaining <= 0:
                raise BackendError(f"grbl at {self.url}: {what}")
            try:
                await asyncio.wait_for(self._changed.wait(), remaining)
            except TimeoutError:
                raise BackendError(f"grbl at {self.url}: {what}") from None

    async def _poll_loop(self) -> None:
        while True:
            self._write_quietly(STATUS_QUERY)
            await asyncio.sleep(self.poll_s)
            silent = time.monotonic() - self._status_at
            if silent > STATUS_SILENCE_S:
                self._fail(BackendError(f"grbl at {self.url}: no status report for {silent:.1f} s"))

    # --- the MotionBackend verbs -----------------------------------------------------------

    def add_motion_listener(self, listener: MotionListener) -> None:
        self._listeners.append(listener)

    async def queue(self, line: str, *, source_line: int | None = None) -> None:
        self._raise_failure()
        try:
            text = for_grbl(line)
        except LineRefused as exc:
            raise BackendError(str(exc), line_number=source_line) from None
        if not text:
            return  # a comment-only line: nothing for grbl
        await self._send(text, source_line)

    async def _send(self, text: str, source_line: int | None) -> None:
        size = len(text) + 1
        if size > self.info.line_limit:
            raise BackendError(
                f"{text!r}: {size} characters, more than grbl takes on a line "
                f"({self.info.line_limit})", line_number=source_line,
            )  # fmt: skip
        if self.streaming == "sync":
            await self._until(lambda: not self._sent, None, "waiting for ok")
        else:
            await self._until(lambda: self._counter.fits(size), None, "waiting for buffer room")
        self._sent.append(_Sent(text, source_line))
        self._since_idle += 1
        self._counter.sent(size)
        self._write(text.encode("ascii") + b"\n")
        self.figures.lines_sent += 1
        self.figures.bytes_sent += size
        self.figures.max_in_flight_bytes = max(self.figures.max_in_flight_bytes, self._counter.used)

    def _idle(self) -> bool:
        report = self.status
        if self._sent or report is None or self._status_seq <= self._status_seq_at_ack:
            return False  # an ok outstanding, or no report since the last one
        planner_empty = report.planner_free is None or (
            report.planner_free >= self.info.planner_blocks
        )
        return report.state == "Idle" and planner_empty

    async def wait_idle(self) -> tuple[float, float]:
        """Every line done: a ``G4P0`` is answered only once grbl's planner has emptied (a
        status report alone may come between a line's ok and its cycle start, and stock grbl
        omits ``Bf:``), then a report of ``Idle``."""
        if self._since_idle:
            await self._send("G4P0", None)
        await self._until(self._idle, None, "waiting for idle")
        self._since_idle = 0
        return self.position

    async def hold(self) -> None:
        self._write(FEED_HOLD)
        seq = self._status_seq

        def at_rest() -> bool:
            report = self.status
            fresh = self._status_seq > seq + 1  # two reports: the first may predate the '!'
            return (
                fresh
                and report is not None
                and (report.hold_complete or report.state in ("Idle", "Alarm"))
            )

        await self._until(at_rest, ANSWER_TIMEOUT_S, "the feed hold did not complete",
                          failures=False)  # fmt: skip

    async def resume(self) -> None:
        self._write(CYCLE_START)

    async def where(self) -> Where | None:
        """From the latest status report (polled at ``poll_hz``): no request of its own."""
        x, y = self.position
        if self.status is None or math.isnan(x) or math.isnan(y):  # none reported yet
            return None
        held = self.status.state in ("Hold", "Door")
        return Where(x, y, self._speed_mm_s, held)

    async def release_stale_hold(self) -> None:
        """A hold left by a sender that died keeps grbl's queue: dropped (soft reset), never
        resumed (that would run the dead program's lines)."""
        if self.status is not None and self.status.state in ("Hold", "Door"):
            log.warning("grbl_stale_hold_released", state=self.status.state)
            await self.clear()

    async def clear(self) -> None:
        """Drop what is queued: hold first if moving (no ALARM:3), soft reset, re-sync."""
        if self.status is not None and self.status.state == "Jog":
            self._write(JOG_CANCEL)  # a jog is cancelled, not held
            await self._until(lambda: self.status is not None and self.status.state != "Jog",
                              ANSWER_TIMEOUT_S, "the jog did not stop")  # fmt: skip
        report = self.status
        if report is not None and (report.state in MOVING or report.state == "Hold"):
            await self.hold()  # at rest first (Hold:1 too): a reset in motion loses position
        banners = self._banners
        self._failure = None
        self._resetting = True
        self._write(SOFT_RESET)
        self.figures.resets += 1
        try:
            await self._until(lambda: self._banners > banners, BANNER_TIMEOUT_S,
                              "no banner after a soft reset")  # fmt: skip
            await asyncio.sleep(0.05)  # the [MSG:...] lines that follow a banner
        finally:
            self._resetting = False
        self._meter.clear()
        self._since_idle = 0
        seq = self._status_seq
        await self._until(lambda: self._status_seq > seq, ANSWER_TIMEOUT_S, "no status")
        if self.status is not None and self.status.state == "Alarm":
            self._failure = None
            raise BackendError(
                "grbl is still in alarm after the reset: check the machine, then home ($H) "
                "or unlock ($X) it from its console"
            )

    async def relay(self, text: str) -> list[str]:
        """A line a sender wrote for grbl itself (``$$``, ``$I``, ``$H``, ``$X``, ``$J=``), sent
        once what is streaming has been answered: everything grbl says back, its ``ok`` or
        ``error:N`` last. A refusal here is the sender's to show, not a failure of ours."""
        self._raise_failure()
        await self._until(lambda: not self._sent, None, "waiting for the lines before")
        relayed: list[str] = []
        self._relayed = relayed
        try:
            await self._send(text, None)
            await self._until(
                lambda: bool(relayed) and (relayed[-1] == "ok" or relayed[-1].startswith("error:")),
                None if text.startswith("$H") else ANSWER_TIMEOUT_S,  # homing takes its time
                f"no answer to {text}",
            )  # fmt: skip
        finally:
            self._relayed = None
        return relayed

    def realtime(self, byte: int) -> None:
        """A real-time command byte passed on as a sender wrote it (the grbl port):
        overrides, jog cancel; the port handles ``?``, ``!``, ``~`` and reset itself."""
        self._write(bytes([byte]))

    def feed_override(self, step: str) -> None:
        """``reset``, ``+10``, ``-10``, ``+1``, ``-1`` (grbl's real-time override bytes)."""
        self._write(FEED_OVERRIDE[step])

    async def close(self) -> None:
        if self._poll is not None:
            self._poll.cancel()
            await asyncio.gather(self._poll, return_exceptions=True)
            self._poll = None
        if self._transport is not None:
            await self._transport.close()
            self._transport = None
        log.info("grbl_closed", **vars(self.figures))


def anti_dive_speed(report: StatusReport, measured_mm_s: float | None) -> float | None:
    """The XY speed the THC should see, in mm/s: 0 unless running (a hold or a stop holds
    Z); while running, the lower of the measured speed and grbl's ``FS`` (the planned speed
    of the executing block, which falls at a corner before the position shows it): the
    lock comes early and lifts only when both are back at speed. None until measured."""
    if report.state not in MOVING:
        return 0.0
    if measured_mm_s is None:
        return None
    if report.feed is None:
        return measured_mm_s
    return min(measured_mm_s, report.feed / 60.0)


def _code(line: str) -> int:
    _, _, number = line.partition(":")
    return int(number) if number.strip().isdigit() else -1
