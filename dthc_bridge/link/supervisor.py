"""Keeps a board session up: connect, handshake, watch, and reconnect with backoff.

A link fault never crashes the process: the session fails every waiter with one exception,
the board is reported offline, and reconnection retries with capped, jittered backoff,
including while the device path does not exist yet (USB cable still unplugged). A device
that cannot be opened is said once per distinct OS error (``board_link_unavailable
path=/dev/dthc0 error="[Errno 2] No such file or directory"``), not at every retry, and the
board stays offline with that reason ("cannot open /dev/dthc0: No such file or directory")
while the retries go on, instead of flickering through ``connecting``.

The supervisor is also the link's boundary towards the layers above: they register
listeners (samples, reports, state changes, handler errors), receive board data stamped
with board time on one continuous timeline, and a listener that raises is caught here
(docs/DESIGN.md invariant 6): logged with its traceback, counted, and reported to the error
listeners, while the transport and the session carry on.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import structlog

import firmware_protocol as fp

from ..backoff import backoff_delay_s
from ..transport import LinkUnavailable, TransportError, TransportOpener, open_transport
from .clock import BoardTimeline
from .errors import BoardRebooted, LinkDown, LinkError, ProtocolVersionMismatch
from .session import BoardSession, SessionTrace
from .stats import LinkStats
from .timing import LinkTiming

__all__ = [
    "ErrorListener",
    "LinkState",
    "LinkStateChange",
    "LinkSupervisor",
    "ReportListener",
    "SamplesListener",
    "StateListener",
]

log = structlog.get_logger("dthc_bridge.link")

HANDLER_ERROR_LOG_PERIOD_S = 1.0  # at most one traceback a second for a repeating bug


class LinkState(StrEnum):
    OFFLINE = "offline"
    CONNECTING = "connecting"
    ONLINE = "online"
    INCOMPATIBLE = "incompatible"


@dataclass(frozen=True, slots=True)
class LinkStateChange:
    state: LinkState
    reason: str
    board_rebooted: bool = False  # the session ended because the board restarted


# A batch and its board time (s): the time of its last sample, when the batch is handled
# (so a command arriving next takes effect then, not (n - 1) periods earlier).
SamplesListener = Callable[[fp.Samples, float], None]
ReportListener = Callable[[fp.Report, float], None]  # report, board time it happened (s)
StateListener = Callable[[LinkStateChange], None]
ErrorListener = Callable[[Exception], None]  # a listener raised while handling board data


class LinkSupervisor:
    def __init__(
        self,
        url: str,
        timing: LinkTiming | None = None,
        *,
        baudrate: int = 921_600,
        opener: TransportOpener | None = None,
        rng: random.Random | None = None,
        session_trace: SessionTrace | None = None,
    ) -> None:
        """``session_trace``: hooks every session calls on the hot path (a measuring tool's;
        the daemon gives none)."""
        self.url = url
        self.timing = timing or LinkTiming()
        self.stats = LinkStats()
        self.timeline = BoardTimeline()
        self._opener = opener or (
            lambda on_bytes, on_lost: open_transport(url, on_bytes, on_lost, baudrate=baudrate)
        )
        self._samples_listeners: list[SamplesListener] = []
        self._report_listeners: list[ReportListener] = []
        self._gap_listeners: list[Callable[[int], None]] = []
        self._state_listeners: list[StateListener] = []
        self._error_listeners: list[ErrorListener] = []
        self.rng = rng or random.Random()
        self._session_trace = session_trace
        self._handler_error_logged_s = -math.inf
        self._handler_errors_unlogged = 0
        self._last_boot_id: int | None = None
        self._reboot_announced = False  # this reboot was reported when its session ended
        self.state = LinkState.OFFLINE
        self.reason = ""
        self.session: BoardSession | None = None
        self.last_error: str = ""
        self._unavailable: str | None = None  # the open failure last logged, until it opens
        self._online = asyncio.Event()

    # --- listeners -------------------------------------------------------------------------

    def add_samples_listener(self, listener: SamplesListener) -> None:
        """Every SAMPLES batch, on the hot path (called from the transport's read)."""
        self._samples_listeners.append(listener)

    def add_report_listener(self, listener: ReportListener) -> None:
        """EVENT, FAULT, MOTION_DONE and PROBE_RESULT reports, each once."""
        self._report_listeners.append(listener)

    def add_event_gap_listener(self, listener: Callable[[int], None]) -> None:
        """EVENT/FAULT reports were lost on the way (how many)."""
        self._gap_listeners.append(listener)

    def add_state_listener(self, listener: StateListener) -> None:
        self._state_listeners.append(listener)

    def add_error_listener(self, listener: ErrorListener) -> None:
        """A listener raised while handling board data: the caller's fault path."""
        self._error_listeners.append(listener)

    def _notify(self, listeners: list[Callable[..., None]], *args: Any) -> None:
        """Call each listener; a raising one is a bug above the link, never the link's end."""
        for listener in listeners:
            try:
                listener(*args)
            except Exception as exc:  # invariant 6: a bug is a fault, never the link's end
                self.stats.handler_errors += 1
                self._log_handler_error(listener, args)
                for on_error in self._error_listeners:
                    try:
                        on_error(exc)
                    except Exception:  # the fault path itself failed: log it, go on
                        with contextlib.suppress(Exception):
                            log.exception("board_data_error_handler_failed")

    def _log_handler_error(self, listener: Callable[..., None], args: tuple[Any, ...]) -> None:
        """The traceback of the first failure, then at most one a second: a bug that fires
        on every batch must not turn the hot path into a stream of tracebacks."""
        now = time.monotonic()
        if now - self._handler_error_logged_s < HANDLER_ERROR_LOG_PERIOD_S:
            self._handler_errors_unlogged += 1
            return
        self._handler_error_logged_s = now
        unlogged, self._handler_errors_unlogged = self._handler_errors_unlogged, 0
        with contextlib.suppress(Exception):  # nor may a failing log line end the link
            log.exception(
                "board_data_handler_failed",
                handler=getattr(listener, "__qualname__", repr(listener)),
                data=type(args[0]).__name__ if args else None,
                not_logged_since_last=unlogged,
            )

    def _on_samples(self, batch: fp.Samples, board_us: int) -> None:
        self._notify(self._samples_listeners, batch, self.timeline.seconds(board_us))

    def _on_report(self, report: fp.Report, board_us: int) -> None:
        self._notify(self._report_listeners, report, self.timeline.seconds(board_us))

    def _on_event_gap(self, missed: int) -> None:
        self._notify(self._gap_listeners, missed)

    # --- state -----------------------------------------------------------------------------

    def _set_state(self, state: LinkState, reason: str, *, board_rebooted: bool = False) -> None:
        if state is self.state and reason == self.reason and state is not LinkState.ONLINE:
            return
        self.state, self.reason = state, reason
        if state is LinkState.ONLINE:
            self._online.set()
        else:
            self._online.clear()
        log.info("link_state", url=self.url, state=str(state), reason=reason)
        self._notify(self._state_listeners, LinkStateChange(state, reason, board_rebooted))

    async def wait_online(self, timeout_s: float | None = None) -> BoardSession:
        await asyncio.wait_for(self._online.wait(), timeout_s)
        assert self.session is not None
        return self.session

    def current(self) -> BoardSession:
        """The live session, or LinkDown if the board is offline right now."""
        session = self.session
        if session is None or not session.is_up or self.state is not LinkState.ONLINE:
            raise LinkDown(self.last_error or "board offline")
        return session

    def backoff_s(self, failures: int) -> float:
        t = self.timing
        return backoff_delay_s(
            failures, initial_s=t.backoff_initial_s, max_s=t.backoff_max_s, rng=self.rng
        )

    async def _connect_once(self) -> BoardSession:
        self.timeline.new_session()
        session = BoardSession(
            self.url, self.timing, self.stats,
            on_samples=self._on_samples, on_report=self._on_report,
            on_event_gap=self._on_event_gap, trace=self._session_trace,
        )  # fmt: skip
        try:
            await session.open(self._opener)
            await session.handshake()
        except BaseException:
            await session.close()  # a failed connect leaves nothing behind
            raise
        return session

    def _note_unavailable(self, exc: LinkUnavailable) -> None:
        """One warning per distinct reason the device cannot be opened (at start, and
        again only when the OS says something else or after the link was up)."""
        if exc.os_error == self._unavailable:
            return
        self._unavailable = exc.os_error
        log.warning("board_link_unavailable", path=exc.url, error=exc.os_error)

    async def run(self) -> None:
        """Run until cancelled."""
        failures = 0
        try:
            while True:
                if self._unavailable is None:  # retrying a device that is not there: quiet
                    self._set_state(LinkState.CONNECTING, "connecting")
                try:
                    session = await self._connect_once()
                except ProtocolVersionMismatch as exc:
                    failures = max(failures + 1, 8)
                    self._unavailable = None
                    self.last_error = str(exc)
                    self._set_state(LinkState.INCOMPATIBLE, str(exc))
                except LinkUnavailable as exc:
                    failures += 1
                    self.last_error = str(exc)
                    self._note_unavailable(exc)
                    self._set_state(LinkState.OFFLINE, str(exc))
                except (LinkError, TransportError, OSError) as exc:
                    failures += 1
                    self._unavailable = None
                    self.last_error = str(exc)
                    self._set_state(LinkState.OFFLINE, str(exc))
                else:
                    failures = 0
                    self._unavailable = None
                    if self.stats.handshakes > 1:
                        self.stats.reconnects += 1
                    self.session = session
                    # A board that rebooted while the link was down (a USB board drops off
                    # the bus first) shows it only by a new boot id.
                    rebooted = (
                        self._last_boot_id is not None
                        and session.boot_id != self._last_boot_id
                        and not self._reboot_announced
                    )
                    self._last_boot_id = session.boot_id
                    self._reboot_announced = False
                    self._set_state(LinkState.ONLINE, "handshake complete", board_rebooted=rebooted)
                    keep_alive = asyncio.create_task(session.keep_alive(), name="link-keepalive")
                    try:
                        error = await session.lost
                    finally:
                        keep_alive.cancel()
                        with contextlib.suppress(asyncio.CancelledError):
                            await keep_alive
                    await session.close()
                    self.last_error = str(error)
                    rebooted = isinstance(error, BoardRebooted)
                    self._reboot_announced = rebooted
                    reason = "board_rebooted" if rebooted else str(error)
                    self._set_state(LinkState.OFFLINE, reason, board_rebooted=rebooted)
                    if rebooted:
                        continue  # the board is there: re-handshake at once
                    failures = 1
                await asyncio.sleep(self.backoff_s(failures))
        finally:
            if self.session is not None:
                await self.session.close()
            if self.state is not LinkState.OFFLINE:
                self._set_state(LinkState.OFFLINE, "stopped")
