"""A host end of the board link with nothing automatic in it: the conformance suite's probe.

The daemon's :class:`~dthc_bridge.link.BoardSession` hides sequence numbers, retransmits on
its own and keeps the lease alive. The suite needs the opposite: choose each sequence
number, resend a frame byte for byte, write corrupt bytes, and fall silent on purpose. So
this link only frames, matches replies to the sequence number it was told to wait for, and
keeps every board message with the host time it arrived, for checks to look back at.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import TypeVar

import structlog

import firmware_protocol as fp

from ..link import LinkDown, RequestTimeout
from ..transport import Transport, TransportError, TransportOpener, open_transport

__all__ = ["REPLY_TYPES", "RawBoardLink", "Received"]

log = structlog.get_logger("dthc_bridge.conformance")

# Replies to a sequenced command carry its seq; everything else is a report or telemetry.
REPLY_TYPES: tuple[type[fp.Message], ...] = (fp.Ack, fp.Nak, fp.HelloInfo, fp.Status, fp.Clock)

_M = TypeVar("_M", bound=fp.Message)


@dataclass(frozen=True, slots=True)
class Received:
    """One board message and the host monotonic time (s) its bytes arrived."""

    host_s: float
    msg: fp.Message


@dataclass(slots=True)
class _Pending:
    future: asyncio.Future[Received]
    accepts: tuple[type[fp.Message], ...]


class RawBoardLink:
    """Frames in and out of one board, every sequence number and every byte chosen by the
    caller. Open with ``async with``; it owns its transport and its keep-alive task."""

    def __init__(
        self,
        url: str,
        *,
        ack_timeout_s: float,
        baudrate: int = 921_600,
        opener: TransportOpener | None = None,
    ) -> None:
        self.url = url
        self._opener = opener
        self.ack_timeout_s = ack_timeout_s
        self._baudrate = baudrate
        self._loop = asyncio.get_running_loop()
        self.decoder = fp.StreamDecoder()
        self.history: list[Received] = []
        self._samples_listeners: list[Callable[[fp.Samples], None]] = []
        self._transport: Transport | None = None
        self._lost: str | None = "not opened"
        self._pending: dict[int, _Pending] = {}
        self._arrivals: list[asyncio.Future[None]] = []
        self._next_seq = 1
        self.last_tx_s = 0.0
        self.frames_out = 0
        self._generation = 0
        self._keepalive: asyncio.Task[None] | None = None
        self._keepalive_lease_ms: int | None = None
        self.keepalive_timeouts = 0

    # --- lifetime --------------------------------------------------------------------------

    async def open(self) -> None:
        """Open the transport (TransportError or ValueError if that fails)."""
        self.decoder.reset()
        # Callbacks of a transport this link has since closed (a reopen after a board
        # reset) must not touch the new one: each opening is a generation.
        self._generation += 1
        generation = self._generation

        def on_bytes(data: bytes) -> None:
            if generation == self._generation:
                self._on_bytes(data)

        def on_lost(exc: Exception | None) -> None:
            if generation == self._generation:
                self._on_lost(exc)

        if self._opener is not None:
            self._transport = await self._opener(on_bytes, on_lost)
        else:
            self._transport = await open_transport(
                self.url, on_bytes, on_lost, baudrate=self._baudrate
            )
        self._lost = None
        # No byte yet: a board whose port just opened may be in its bootloader (the
        # handshake sends the 0x00 that ends a partial frame when the board has spoken).

    async def close(self) -> None:
        await self.stop_keepalive()
        transport, self._transport = self._transport, None
        self._fail_pending("closed by the suite")
        self._generation += 1
        if transport is not None:
            await transport.close()

    async def __aenter__(self) -> RawBoardLink:
        await self.open()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    @property
    def lost_reason(self) -> str | None:
        """Why the link is down, or None while it is up."""
        return self._lost

    def _on_lost(self, exc: Exception | None) -> None:
        self._fail_pending(str(exc) if exc is not None else "transport closed")

    def _fail_pending(self, reason: str) -> None:
        if self._lost is None:
            self._lost = reason
        for pending in self._pending.values():
            if not pending.future.done():
                pending.future.set_exception(LinkDown(reason))
        self._pending.clear()
        self._wake()

    # --- sending ---------------------------------------------------------------------------

    def next_seq(self) -> int:
        """The next sequence number in 1..255 that no request is waiting on."""
        seq = self._next_seq
        while seq in self._pending:
            seq = seq % 255 + 1
        self._next_seq = seq % 255 + 1
        return seq

    def write(self, data: bytes) -> float:
        """Write bytes as they are; returns the host time they were handed to the transport."""
        if self._lost is not None or self._transport is None:
            raise LinkDown(self._lost or "not connected")
        try:
            self._transport.write(data)
        except TransportError as exc:
            self._fail_pending(str(exc))
            raise LinkDown(str(exc)) from exc
        self.last_tx_s = self._loop.time()
        self.frames_out += 1
        return self.last_tx_s

    def send(self, msg: fp.Message) -> float:
        """Encode and write one message with the header ``seq`` it already has."""
        return self.write(fp.encode(msg))

    async def request(
        self,
        msg: fp.Message,
        *,
        timeout_s: float | None = None,
        attempts: int = 3,
        accepts: tuple[type[fp.Message], ...] = REPLY_TYPES,
    ) -> fp.Message:
        """Send ``msg`` (seq 0: take the next one) and return the reply carrying its seq.

        A NAK is returned, not raised: checks judge it. RequestTimeout after ``attempts``
        sends of the same bytes, each waiting ``timeout_s`` (default: the ack timeout).
        """
        if not msg.seq:
            msg = msg._replace(seq=self.next_seq())
        return (await self.exchange(fp.encode(msg), msg, timeout_s, attempts, accepts)).msg

    async def exchange(
        self,
        frame: bytes,
        msg: fp.Message,
        timeout_s: float | None = None,
        attempts: int = 3,
        accepts: tuple[type[fp.Message], ...] = REPLY_TYPES,
    ) -> Received:
        """Write ``frame`` (any bytes, e.g. a retransmission or a malformed frame) and wait
        for a reply of a type in ``accepts`` whose seq is ``msg.seq``."""
        seq = msg.seq
        wait_s = self.ack_timeout_s if timeout_s is None else timeout_s
        future: asyncio.Future[Received] = self._loop.create_future()
        self._pending[seq] = _Pending(future, accepts)  # registered before the write
        try:
            for _ in range(attempts):
                self.write(frame)
                try:
                    return await asyncio.wait_for(asyncio.shield(future), wait_s)
                except TimeoutError:
                    continue
        finally:
            if self._pending.get(seq) is not None and self._pending[seq].future is future:
                del self._pending[seq]
            if not future.done():
                future.cancel()
        raise RequestTimeout(type(msg).__name__, attempts, wait_s)

    # --- receiving -------------------------------------------------------------------------

    def add_samples_listener(self, listener: Callable[[fp.Samples], None]) -> None:
        """Every SAMPLES batch as it arrives (the suite's motion-window guard)."""
        self._samples_listeners.append(listener)

    def _on_bytes(self, data: bytes) -> None:
        now = self._loop.time()
        for msg in self.decoder.feed(data):
            item = Received(now, msg)
            self.history.append(item)
            if isinstance(msg, fp.Samples):
                for listener in self._samples_listeners:
                    listener(msg)
                continue
            pending = self._pending.get(msg.seq) if msg.seq else None
            if pending is not None and isinstance(msg, pending.accepts):
                del self._pending[msg.seq]
                if not pending.future.done():
                    pending.future.set_result(item)
        self._wake()

    def _wake(self) -> None:
        arrivals, self._arrivals = self._arrivals, []
        for waiter in arrivals:
            if not waiter.done():
                waiter.set_result(None)

    def mark(self) -> int:
        """A position in :attr:`history`; pass it as ``since`` to look only at what follows."""
        return len(self.history)

    def since(self, mark: int) -> list[Received]:
        return self.history[mark:]

    def messages(self, cls: type[_M], since: int = 0) -> list[_M]:
        return [r.msg for r in self.history[since:] if isinstance(r.msg, cls)]

    async def wait_for(
        self, match: Callable[[fp.Message], bool], timeout_s: float, *, since: int
    ) -> Received | None:
        """The first message from ``since`` on that ``match`` accepts, or None at the
        deadline. LinkDown if the link is lost meanwhile."""
        deadline = self._loop.time() + timeout_s
        index = since
        while True:
            history = self.history
            for i in range(index, len(history)):
                if match(history[i].msg):
                    return history[i]
            index = len(history)
            if self._lost is not None:
                raise LinkDown(self._lost)
            remaining = deadline - self._loop.time()
            if remaining <= 0:
                return None
            arrival: asyncio.Future[None] = self._loop.create_future()
            self._arrivals.append(arrival)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(arrival, remaining)

    async def wait_for_type(
        self,
        cls: type[_M],
        timeout_s: float,
        *,
        since: int,
        where: Callable[[_M], bool] = lambda _: True,
    ) -> tuple[float, _M] | None:
        """Like :meth:`wait_for`, for one message type; returns (arrival time, message)."""
        found = await self.wait_for(
            lambda m: isinstance(m, cls) and where(m), timeout_s, since=since
        )
        if found is None:
            return None
        assert isinstance(found.msg, cls)
        return found.host_s, found.msg

    # --- the lease -------------------------------------------------------------------------

    def start_keepalive(self, lease_ms: int) -> None:
        """Send HEARTBEAT whenever nothing was sent for a third of ``lease_ms``."""
        if self._keepalive is not None:
            return
        self._keepalive_lease_ms = lease_ms
        self._keepalive = self._loop.create_task(
            self._keep_alive(lease_ms / 3000.0), name="conformance-keepalive"
        )

    async def stop_keepalive(self) -> None:
        """Stop the heartbeats; when this returns, the keep-alive writes nothing more."""
        task, self._keepalive = self._keepalive, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    @contextlib.asynccontextmanager
    async def silent(self) -> AsyncIterator[None]:
        """Within: no heartbeats (the caller decides every frame); resumed on exit."""
        lease_ms = self._keepalive_lease_ms
        running = self._keepalive is not None
        await self.stop_keepalive()
        try:
            yield
        finally:
            if running and lease_ms is not None and self._lost is None:
                self.start_keepalive(lease_ms)

    async def _keep_alive(self, period_s: float) -> None:
        while True:
            idle_s = self._loop.time() - self.last_tx_s
            if idle_s < period_s:
                await asyncio.sleep(period_s - idle_s)
                continue
            try:
                await self.request(fp.Heartbeat(0), attempts=1)
            except RequestTimeout:
                self.keepalive_timeouts += 1
                log.warning("conformance_heartbeat_unanswered", url=self.url)
            except LinkDown:
                return
