"""Keeps a board session up: connect, handshake, watch, and reconnect with backoff.

A link fault never crashes the process: the session fails every waiter with one exception,
the board is reported offline, and reconnection retries with capped, jittered backoff,
including while the device path does not exist yet (USB cable still unplugged).
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from collections.abc import Callable
from enum import StrEnum

import structlog

from ..backoff import backoff_delay_s
from ..transport import TransportError, TransportOpener, open_transport
from .errors import BoardRebooted, LinkDown, LinkError, ProtocolVersionMismatch
from .session import BoardSession, ReportCallback, SamplesCallback
from .stats import LinkStats
from .timing import LinkTiming

__all__ = ["LinkState", "LinkSupervisor", "StateCallback"]

log = structlog.get_logger("dthc_bridge.link")


class LinkState(StrEnum):
    OFFLINE = "offline"
    CONNECTING = "connecting"
    ONLINE = "online"
    INCOMPATIBLE = "incompatible"


StateCallback = Callable[[LinkState, str], None]  # new state, reason


class LinkSupervisor:
    def __init__(
        self,
        url: str,
        timing: LinkTiming | None = None,
        *,
        baudrate: int = 921_600,
        opener: TransportOpener | None = None,
        on_samples: SamplesCallback | None = None,
        on_report: ReportCallback | None = None,
        on_event_gap: Callable[[int], None] | None = None,
        on_state: StateCallback | None = None,
        rng: random.Random | None = None,
    ) -> None:
        self.url = url
        self.timing = timing or LinkTiming()
        self.stats = LinkStats()
        self._opener = opener or (
            lambda on_bytes, on_lost: open_transport(url, on_bytes, on_lost, baudrate=baudrate)
        )
        self.on_samples = on_samples
        self.on_report = on_report
        self.on_event_gap = on_event_gap
        self.on_state = on_state
        self.rng = rng or random.Random()
        self.state = LinkState.OFFLINE
        self.session: BoardSession | None = None
        self.last_error: str = ""
        self._online = asyncio.Event()
        self._stopping = False

    def _set_state(self, state: LinkState, reason: str) -> None:
        if state is self.state and state is not LinkState.ONLINE:
            return
        self.state = state
        if state is LinkState.ONLINE:
            self._online.set()
        else:
            self._online.clear()
        log.info("link_state", url=self.url, state=str(state), reason=reason)
        if self.on_state is not None:
            self.on_state(state, reason)

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
        session = BoardSession(
            self.url, self.timing, self.stats,
            on_samples=self.on_samples, on_report=self.on_report,
            on_event_gap=self.on_event_gap,
        )  # fmt: skip
        try:
            await session.open(self._opener)
            await session.handshake()
        except BaseException:
            await session.close()  # a failed connect leaves nothing behind
            raise
        return session

    async def run(self) -> None:
        """Run until cancelled."""
        failures = 0
        try:
            while True:
                self._set_state(LinkState.CONNECTING, "connecting")
                try:
                    session = await self._connect_once()
                except ProtocolVersionMismatch as exc:
                    failures = max(failures + 1, 8)
                    self.last_error = str(exc)
                    self._set_state(LinkState.INCOMPATIBLE, str(exc))
                except (LinkError, TransportError, OSError) as exc:
                    failures += 1
                    self.last_error = str(exc)
                    self._set_state(LinkState.OFFLINE, str(exc))
                else:
                    failures = 0
                    if self.stats.handshakes > 1:
                        self.stats.reconnects += 1
                    self.session = session
                    self._set_state(LinkState.ONLINE, "handshake complete")
                    keep_alive = asyncio.create_task(session.keep_alive(), name="link-keepalive")
                    try:
                        error = await session.lost
                    finally:
                        keep_alive.cancel()
                        with contextlib.suppress(asyncio.CancelledError):
                            await keep_alive
                    await session.close()
                    self.last_error = str(error)
                    reason = "board_rebooted" if isinstance(error, BoardRebooted) else str(error)
                    self._set_state(LinkState.OFFLINE, reason)
                    if isinstance(error, BoardRebooted):
                        continue  # the board is there: re-handshake at once
                    failures = 1
                await asyncio.sleep(self.backoff_s(failures))
        finally:
            if self.session is not None:
                await self.session.close()
            if self.state is not LinkState.OFFLINE:
                self._set_state(LinkState.OFFLINE, "stopped")
