"""One connection to a board: handshake, sequenced requests, lease, telemetry.

Host-to-board commands are reliable: a sequence number, a reply future registered before
the frame is written, bounded retransmission of the same frame. Board-to-host telemetry is
unreliable and counted. A session lives until its transport is lost, the board reboots, or
requests time out repeatedly; then every waiter fails with one exception and ``lost``
resolves. The supervisor opens a new session; a session is never revived.
"""

from __future__ import annotations

import asyncio
import random
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Protocol

import structlog

import firmware_protocol as fp

from ..transport import Transport, TransportError, TransportOpener
from .clock import BoardClock
from .errors import (
    BoardRebooted,
    LinkDown,
    LinkError,
    NegativeAck,
    ProtocolVersionMismatch,
    RequestTimeout,
)
from .frametrace import new_frame_trace
from .stats import LinkStats
from .timing import LinkTiming

__all__ = ["BoardSession", "ReportCallback", "SamplesCallback", "SessionTrace"]

log = structlog.get_logger("dthc_bridge.link")

SamplesCallback = Callable[[fp.Samples, int], None]  # batch, 64-bit board time of its last sample
# EVENT, FAULT, MOTION_DONE or PROBE_RESULT, and its 64-bit board time
ReportCallback = Callable[[fp.Report, int], None]


class SessionTrace(Protocol):
    """Hooks a measuring tool gives the link (the latency bench), called on the hot path:
    which wire batch is being handled, and each Z velocity written meanwhile. The daemon
    gives none."""

    def samples_received(self, batch: fp.Samples, t_us: int) -> None:
        """A SAMPLES batch (``t_us``: its last sample's 64-bit board time), before the
        layers above handle it."""

    def samples_handled(self, batch: fp.Samples) -> None:
        """The layers above are done with ``batch``."""

    def velocity_sent(self, velocity_seq: int) -> None:
        """A Z_VELOCITY frame (its stream seq) was written to the transport."""


_REPLY_TYPES = (fp.Ack, fp.Nak, fp.HelloInfo, fp.Status, fp.Clock)
# The report a QUERY of each kind answers with (BoardClient asks the other way round).
REPORT_REPLY = {
    fp.QueryWhat.PROBE_RESULT: fp.ProbeResult,
    fp.QueryWhat.MOTION_DONE: fp.MotionDone,
    fp.QueryWhat.HOME_RESULT: fp.HomeResult,
}


@dataclass(slots=True)
class _Pending:
    future: asyncio.Future[fp.Message]
    command: fp.Message
    # A Query for a report is answered by that report, which otherwise arrives unsolicited.
    report_reply: type[fp.Message] | None


class BoardSession:
    def __init__(
        self,
        url: str,
        timing: LinkTiming,
        stats: LinkStats,
        *,
        on_samples: SamplesCallback | None = None,
        on_report: ReportCallback | None = None,
        on_event_gap: Callable[[int], None] | None = None,
        trace: SessionTrace | None = None,
    ) -> None:
        self.url = url
        self.timing = timing
        self.stats = stats
        self.on_samples = on_samples
        self.on_report = on_report
        self.on_event_gap = on_event_gap
        self.decoder = fp.StreamDecoder(on_error=self._on_decode_error)
        self.clock = BoardClock()
        self.info: fp.HelloInfo | None = None
        self.initial_status: fp.Status | None = None
        self.boot_id: int | None = None
        self._transport: Transport | None = None
        self._closing: asyncio.Task[None] | None = None  # fail()'s close; close() awaits it
        self._loop = asyncio.get_running_loop()
        self._pending: dict[int, _Pending] = {}
        self._window = asyncio.Semaphore(timing.window)
        self._next_seq = 1
        self._velocity_seq = 0
        self._last_tx_s = 0.0
        self._consecutive_timeouts = 0
        self._last_sample_seq: int | None = None
        self._last_sample_t_us: int | None = None
        self._clock_known = False  # the handshake's CLOCK reply anchors the 32-bit stamps
        self._last_event_counter: int | None = None
        self.lost: asyncio.Future[LinkError] = self._loop.create_future()
        self._heard = asyncio.Event()  # a valid frame arrived from the board
        self._trace = new_frame_trace()  # None unless the trace switch is on
        self._hooks = trace  # a measuring tool's (SessionTrace); None in the daemon

    # --- lifetime --------------------------------------------------------------------------

    async def open(self, opener: TransportOpener) -> None:
        self._transport = await opener(self._on_bytes, self._on_lost)
        # Not a byte yet: the board may be in its bootloader (handshake, boot_window_s).

    @property
    def is_up(self) -> bool:
        return not self.lost.done()

    def fail(self, error: LinkError, *, expected: bool = False) -> None:
        """Declare the session dead: every waiter gets ``error``; the transport is closed."""
        if self.lost.done():
            return
        self.lost.set_result(error)
        for pending in self._pending.values():
            if not pending.future.done():
                pending.future.set_exception(error)
        self._pending.clear()
        if self._transport is None:
            return  # never opened: nothing was lost (the opener's error says why)
        if self._transport.is_open:
            self._closing = self._loop.create_task(self._transport.close(), name="transport-close")
        (log.info if expected else log.warning)("link_lost", url=self.url, reason=str(error))

    async def close(self) -> None:
        """End the session; the transport is closed when this returns (the supervisor calls
        it after every session, lost or not, so the close ``fail`` started is awaited here)."""
        self.fail(LinkDown("closed by the host"), expected=True)
        if self._closing is not None:
            try:
                await self._closing
            except Exception as exc:  # closing the transport is best effort, said once
                log.warning("transport_close_failed", url=self.url, error=repr(exc))
        if self._transport is not None:
            await self._transport.close()

    def _on_lost(self, exc: Exception | None) -> None:
        self.fail(LinkDown(str(exc) if exc else "transport closed"))

    def _write(self, data: bytes) -> None:
        if self._transport is None or self.lost.done():
            raise self.lost.result() if self.lost.done() else LinkDown("not connected")
        try:
            self._transport.write(data)
        except TransportError as exc:
            error = LinkDown(str(exc))
            self.fail(error)
            raise error from exc
        self.stats.bytes_out += len(data)
        self.stats.frames_out += 1
        self._last_tx_s = self._loop.time()
        if self._trace is not None:
            self._trace.record_out(data)

    # --- requests --------------------------------------------------------------------------

    def _allocate_seq(self) -> int:
        seq = self._next_seq
        while seq in self._pending:
            seq = seq % 255 + 1
        self._next_seq = seq % 255 + 1
        return seq

    async def request(self, command: fp.Message, ack_wait_s: float | None = None) -> fp.Message:
        """Send a sequenced command and return the board's reply; NAK raises NegativeAck."""
        if self.lost.done():
            raise self.lost.result()
        name = type(command).__name__
        timeout = self.timing.ack_timeout_s if ack_wait_s is None else ack_wait_s
        async with self._window:
            seq = self._allocate_seq()
            command = command._replace(seq=seq)
            frame = fp.encode(command)
            future: asyncio.Future[fp.Message] = self._loop.create_future()
            report_reply = (
                REPORT_REPLY.get(fp.QueryWhat(command.what))
                if isinstance(command, fp.Query) and command.what in REPORT_REPLY
                else None
            )
            self._pending[seq] = _Pending(future, command, report_reply)
            self.stats.requests += 1
            try:
                reply = await self._send_until_answered(future, frame, name, timeout)
            finally:
                self._pending.pop(seq, None)
        if isinstance(reply, fp.Nak):
            self.stats.naks += 1
            if reply.code == fp.NakCode.NO_SESSION and self.boot_id is not None:
                self.fail(BoardRebooted(self.boot_id, None))
            raise NegativeAck(name, reply.code, reply.detail)
        return reply

    async def _send_until_answered(
        self, future: asyncio.Future[fp.Message], frame: bytes, name: str, per_attempt_s: float
    ) -> fp.Message:
        attempts = self.timing.max_attempts
        for attempt in range(attempts):
            if attempt:
                self.stats.retransmits += 1
            sent_s = self._loop.time()
            self._write(frame)
            try:
                reply = await asyncio.wait_for(asyncio.shield(future), per_attempt_s)
            except TimeoutError:
                continue
            if attempt == 0:  # Karn's rule: a retransmitted request's RTT is ambiguous
                self.stats.observe_rtt(self._loop.time() - sent_s)
            self._consecutive_timeouts = 0
            return reply
        self.stats.timeouts += 1
        self._consecutive_timeouts += 1
        error = RequestTimeout(name, attempts, per_attempt_s)
        if self._consecutive_timeouts >= self.timing.max_consecutive_timeouts:
            self.fail(LinkDown(f"{self._consecutive_timeouts} requests in a row unanswered"))
        raise error

    def send_velocity(self, velocity_um_s: int, expiry_ms: int | None = None) -> None:
        """THC output: a Z velocity setpoint, unacknowledged, superseded by the next one."""
        self._velocity_seq = (self._velocity_seq + 1) & 0xFFFF
        expiry = self.timing.velocity_expiry_ms if expiry_ms is None else expiry_ms
        self._write(fp.encode(fp.ZVelocity(0, self._velocity_seq, velocity_um_s, expiry)))
        self.stats.velocity_frames += 1
        if self._hooks is not None:
            self._hooks.velocity_sent(self._velocity_seq)

    @property
    def velocity_seq(self) -> int:
        return self._velocity_seq

    # --- handshake, lease, clock -----------------------------------------------------------

    async def wait_for_board(self) -> bool:
        """Wait until the board has sent a valid frame (True), or ``boot_window_s`` passed
        without one (False): an Arduino opened through its USB-serial chip resets and runs
        its bootloader first, and a host that talks into that window keeps it there."""
        if self._heard.is_set():
            return True
        started_s = self._loop.time()
        try:
            await asyncio.wait_for(self._heard.wait(), self.timing.boot_window_s)
        except TimeoutError:
            log.debug("board_silent", url=self.url, waited_s=self.timing.boot_window_s)
            return False
        log.debug(
            "board_heard", url=self.url, after_ms=round((self._loop.time() - started_s) * 1e3)
        )
        return True

    async def handshake(self) -> fp.HelloInfo:
        await self.wait_for_board()
        self._write(b"\x00")  # ends any partial frame the board holds
        hello = fp.Hello(0, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, random.getrandbits(32))
        info = await self.request(hello, self.timing.handshake_timeout_s)
        assert isinstance(info, fp.HelloInfo)
        if info.proto_major != fp.PROTOCOL_MAJOR:
            error = ProtocolVersionMismatch(
                (info.proto_major, info.proto_minor), (fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR)
            )
            self.fail(error)
            raise error
        self.info = info
        self.boot_id = info.boot_id
        self.stats.handshakes += 1
        await self.request(fp.SetLease(0, self.timing.lease_ms))
        await self.sync_clock()
        status = await self.request(fp.Query(0, fp.QueryWhat.STATUS))
        assert isinstance(status, fp.Status)
        # Reports of events before this session are history: start counting from here. A
        # fault latched before it is in ``initial_status.faults`` instead.
        self.initial_status = status
        self._last_event_counter = status.event_counter
        log.info(
            "board_hello",
            url=self.url,
            serial=info.serial,
            boot_id=f"{info.boot_id:08x}",
            firmware=f"{info.fw_major}.{info.fw_minor}.{info.fw_patch}",
            protocol=f"{info.proto_major}.{info.proto_minor}",
            sample_rate_hz=info.sample_rate_hz,
        )
        return info

    async def sync_clock(self) -> None:
        """Learn the board's time, so the first SAMPLES stamps extend near it."""
        reply = await self.request(fp.ClockQuery(0))
        assert isinstance(reply, fp.Clock)

    async def keep_alive(self) -> None:
        """Renew the lease when the host has been silent for a third of it, until the link
        dies (the THC's Z velocity stream renews it while cutting)."""
        period = self.timing.heartbeat_period_s
        while not self.lost.done():
            idle_until = self._last_tx_s + period
            now = self._loop.time()
            if now >= idle_until:
                await self._quietly(self.request(fp.Heartbeat(0)))
            else:
                await asyncio.wait({self.lost}, timeout=idle_until - now)

    async def _quietly(self, work: Awaitable[object]) -> None:
        try:
            await work
        except (RequestTimeout, NegativeAck) as exc:
            log.warning("keep_alive_failed", url=self.url, error=str(exc))
        except LinkError:
            pass  # the session is over; the loop condition ends it

    # --- receiving -------------------------------------------------------------------------

    def _on_decode_error(self, error: fp.DecodeError) -> None:
        log.debug("bad_frame", url=self.url, error=str(error))
        if self._trace is not None:
            self._trace.dump(log, "bad_frame", url=self.url, error=str(error))

    def _on_bytes(self, data: bytes) -> None:
        if self._trace is not None:
            self._trace.record_in(data)  # before decoding: a bad frame is in its own dump
        for msg in self.decoder.feed(data):
            self._heard.set()
            cls = type(msg)
            if cls is fp.Samples:
                self._on_samples(msg)  # type: ignore[arg-type]
            elif cls in _REPLY_TYPES:
                self._on_reply(msg)
            else:
                self._on_report(msg)

    def _on_samples(self, batch: fp.Samples) -> None:
        stats = self.stats
        stats.telemetry_batches += 1
        if not self._clock_known:
            return  # before the handshake's CLOCK: its 32-bit stamp cannot be placed yet
        last = self._last_sample_seq
        if last is not None:
            gap = (batch.stream_seq - last - 1) & 0xFFFF
            if gap < 0x8000:
                stats.telemetry_gaps += gap
        self._last_sample_seq = batch.stream_seq
        t_us = self.clock.extend(batch.t_last_us)
        last_t = self._last_sample_t_us
        if last_t is not None and t_us <= last_t and self.boot_id is not None:
            # A board's samples only move forward: time going back is a reboot that no
            # reply has shown yet (while cutting, the Z velocity stream is unacknowledged).
            self.stats.reboots += 1
            self.fail(BoardRebooted(self.boot_id, None))
            return
        self._last_sample_t_us = t_us
        hooks = self._hooks
        if hooks is not None:
            hooks.samples_received(batch, t_us)
        if self.on_samples is not None:
            self.on_samples(batch, t_us)
        if hooks is not None:
            hooks.samples_handled(batch)

    def _check_boot_id(self, boot_id: int) -> bool:
        if self.boot_id is not None and boot_id != self.boot_id:
            self.stats.reboots += 1
            self.fail(BoardRebooted(self.boot_id, boot_id))
            return False
        return True

    def _on_reply(self, msg: fp.Message) -> None:
        if isinstance(msg, fp.Ack | fp.Nak | fp.Status) and not self._check_boot_id(msg.boot_id):
            return
        if isinstance(msg, fp.HelloInfo) and not self._check_boot_id(msg.boot_id):
            return
        if isinstance(msg, fp.Clock):
            self.clock.last_board_us = max(self.clock.last_board_us, msg.t_us)
            self._clock_known = True
        pending = self._pending.get(msg.seq)
        if pending is None or pending.report_reply is not None:
            self.stats.duplicate_replies += 1  # a late answer to a retransmitted request
            return
        if not pending.future.done():
            pending.future.set_result(msg)

    def _on_report(self, msg: fp.Message) -> None:
        pending = self._pending.get(msg.seq) if msg.seq else None
        if pending is not None and pending.report_reply is type(msg):
            if not pending.future.done():
                pending.future.set_result(msg)
            return
        if isinstance(msg, fp.Event | fp.Fault):
            if self.initial_status is None:
                return  # before the handshake's STATUS: history, which STATUS summarises
            if not self._count_event(msg.counter):
                return  # a FAULT re-report (same counter) or an older report: already handled
        if not isinstance(
            msg, fp.Event | fp.Fault | fp.MotionDone | fp.ProbeResult | fp.HomeResult
        ):
            # A host message coming back (an echoing transceiver) or a type this host does
            # not expect here: counted and dropped, never a reason to end the link.
            self.stats.unexpected_frames += 1
            return
        if not self._clock_known:
            return  # before the handshake (a fault latched then is in its STATUS)
        if self.on_report is not None:
            self.on_report(msg, self.clock.extend(msg.t_us))

    def _count_event(self, counter: int) -> bool:
        """Track the shared event counter; False for a report seen before."""
        last = self._last_event_counter
        if last is not None:
            ahead = (counter - last) & 0xFFFFFFFF
            if ahead == 0 or ahead >= 0x80000000:
                return False
            if ahead > 1:
                self.stats.event_gaps += ahead - 1
                if self.on_event_gap is not None:
                    self.on_event_gap(ahead - 1)
        self._last_event_counter = counter
        return True
