"""BoardClient: the typed async API the plasma controller uses to drive the board.

Units at this level are millimetres, seconds, volts and amperes; the wire's integer units
stay below it. What the board sends is converted here, into typed values in those units
with board time in seconds on the link's continuous timeline: a SAMPLES batch into a
:class:`Batch` (once per batch), an EVENT into an :class:`InputChange`, a FAULT into a
:class:`FaultReport`, a move's and a probe's completion into :class:`MoveEnded` and
:class:`ProbeEnded`. Batches and reports arrive through their own registered listeners (the
THC loop, lowest latency) and as an async stream (diagnostics, tests).
"""

from __future__ import annotations

import asyncio
from collections import OrderedDict
from collections.abc import AsyncGenerator, Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple, TypeVar

import firmware_protocol as fp

from .link import BoardTooOld, LinkSupervisor, RequestTimeout
from .link.session import REPORT_REPLY, BoardSession
from .link.supervisor import ErrorListener, StateListener

__all__ = [
    "Batch",
    "BatchListener",
    "BoardClient",
    "BoardReport",
    "FaultReport",
    "HomeEnded",
    "HomingMode",
    "HomingPlan",
    "InputChange",
    "MoveEnded",
    "ProbeEnded",
    "ReportListener",
    "Telemetry",
    "batch_from_wire",
]


class Batch(NamedTuple):
    """One SAMPLES batch in mm, s and V: what the cut sequence reads from the board.

    Immutable, and a NamedTuple as the wire's messages are rather than a frozen dataclass:
    one is made per batch on the hot path, and a tuple is built in a third of the time
    (about 0.3 against 0.85 µs here)."""

    t_s: float  # board time of its last sample (the link's continuous timeline)
    period_s: float  # between two samples
    volts: Sequence[float]  # arc voltage, calibrated and filtered by the board, oldest first
    z_mm: float  # machine Z when the batch was taken
    xy_speed_mm_s: float | None  # the board's measured XY speed; None: it has no such input
    duration_s: float  # the time the batch covers: len(volts) periods
    inputs: int  # raw input levels (fp.InputBit), as the board's pins read them
    status: int  # board status bits (fp.StatusBit)


def batch_from_wire(msg: fp.Samples, t_s: float) -> Batch:
    """The SAMPLES message in SI units, stamped ``t_s`` (the link's board time of its last
    sample). Runs once per batch on the hot path: plain arithmetic, one list."""
    cv = msg.samples_cv
    return Batch(
        t_s, msg.period_us / 1e6, [c / 100 for c in cv], msg.z_um / 1000,
        msg.xy_speed_dmm_s / 10 if msg.xy_speed_dmm_s != fp.XY_SPEED_UNKNOWN else None,
        len(cv) * msg.period_us / 1e6, msg.inputs, msg.status,
    )  # fmt: skip


@dataclass(frozen=True, slots=True)
class InputChange:
    """An EVENT: one input changed level."""

    t_s: float  # board time of the change
    input: int  # the fp.InputBit that changed
    level: bool
    inputs: int  # every input's level after the change
    z_mm: float


@dataclass(frozen=True, slots=True)
class FaultReport:
    """A FAULT the board latched (or, ``idle_lapse``, a lease that ran out at rest)."""

    t_s: float
    code: int  # fp.FaultCode
    detail: int
    faults: int  # the whole latched set, bit 1 << fp.FaultCode
    z_mm: float

    @property
    def idle_lapse(self) -> bool:
        """The lease ran out while the board was at rest: it latched nothing."""
        return self.code == fp.FaultCode.LEASE_EXPIRED and self.detail == fp.LEASE_DETAIL_IDLE


@dataclass(frozen=True, slots=True)
class MoveEnded:
    """MOTION_DONE: how a Z move ended."""

    result: int  # fp.MotionResult
    z_mm: float

    @property
    def reached(self) -> bool:
        return self.result == fp.MotionResult.REACHED


@dataclass(frozen=True, slots=True)
class ProbeEnded:
    """PROBE_RESULT: how a probe ended (``contact_z_mm``: Z at contact, or at release for
    a probe away; else where it stopped)."""

    result: int  # fp.ProbeOutcome
    sensor: int  # the input bits that ended it
    contact_z_mm: float
    stop_z_mm: float


HomingMode = Literal["off", "at_start", "required"]


@dataclass(frozen=True, slots=True)
class HomingPlan:
    """When and how the daemon homes Z (the daemon's [board.homing], whose defaults these
    are): ``off``, ``at_start`` (each time the board comes online unhomed) or ``required``
    (and no cut until homed)."""

    mode: HomingMode = "off"
    seek_mm_s: float = 20.0
    locate_mm_s: float = 2.0
    backoff_mm: float = 2.0
    max_travel_mm: float = 200.0
    timeout_s: float = 30.0


@dataclass(frozen=True, slots=True)
class HomeEnded:
    """HOME_RESULT: how a Z homing ended (protocol 1.3)."""

    result: int  # fp.HomeOutcome
    z_mm: float  # where Z came to rest (on the homed count when homed)
    shift_mm: float  # how far homing moved the board's Z: 0 when its count was right

    @property
    def homed(self) -> bool:
        return self.result == fp.HomeOutcome.HOMED

    @property
    def outcome(self) -> str:
        """The outcome's name, as an owner reads it in a log line."""
        try:
            return fp.HomeOutcome(self.result).name.lower().replace("_", " ")
        except ValueError:
            return f"outcome {self.result}"


BoardReport = InputChange | FaultReport
# A batch (its own board time inside it); a report (likewise).
BatchListener = Callable[[Batch], None]
ReportListener = Callable[[BoardReport], None]
Telemetry = Batch | BoardReport  # what the telemetry() stream yields
_Report = TypeVar("_Report", fp.MotionDone, fp.ProbeResult, fp.HomeResult)
_COMPLETION_QUERY = {report: what for what, report in REPORT_REPLY.items()}


def _report_from_wire(msg: fp.Report, t_s: float) -> BoardReport | None:
    if isinstance(msg, fp.Event):
        return InputChange(t_s, msg.input, bool(msg.level), msg.inputs, msg.z_um / 1000)
    if isinstance(msg, fp.Fault):
        return FaultReport(t_s, msg.code, msg.detail, msg.faults, msg.z_um / 1000)
    return None  # a completion: to its waiter (wait_move, wait_probe)


def _move_ended(msg: fp.MotionDone) -> MoveEnded:
    return MoveEnded(msg.result, msg.z_um / 1000)


def _probe_ended(msg: fp.ProbeResult) -> ProbeEnded:
    return ProbeEnded(msg.result, msg.sensor, msg.contact_z_um / 1000, msg.stop_z_um / 1000)


PROBE_AWAY_MINOR = 2  # Z_PROBE_AWAY came with protocol 1.2
HOMING_MINOR = 3  # Z_HOME came with protocol 1.3


def _um(mm: float) -> int:
    return round(mm * 1000.0)


class BoardClient:
    def __init__(self, supervisor: LinkSupervisor, *, stream_size: int = 1024) -> None:
        self.link = supervisor
        self._queues: list[asyncio.Queue[Telemetry]] = []
        self._stream_size = stream_size
        # Completions that arrived before anybody waited (an ACK and the report can come in
        # one read), and waiters keyed by (report type, command seq).
        self._recent: OrderedDict[tuple[type, int], fp.Message] = OrderedDict()
        self._waiters: dict[tuple[type, int], asyncio.Future[fp.Message]] = {}
        self.last_status: fp.Status | None = None
        # The status refresh after lost event reports, kept so it is awaited (stop_background).
        self._refresh: asyncio.Task[None] | None = None
        # The last SAMPLES message converted and its Batch: converted once per batch, by
        # whichever batch listener the link calls first.
        self._wire: fp.Samples | None = None
        self._batch: Batch | None = None
        supervisor.add_report_listener(self._on_report)  # completions to their waiters first
        self.add_samples_listener(self._to_streams)
        self.add_report_listener(self._to_streams)
        supervisor.add_event_gap_listener(self._on_event_gap)

    # --- telemetry -------------------------------------------------------------------------

    def add_samples_listener(self, listener: BatchListener) -> None:
        """Every batch, in mm, s and V, on the hot path, in registration order. Each listener
        is called (and guarded) by the link on its own: one that raises is reported to the
        error listeners (``add_error_listener``) and the others still run."""

        def call(msg: fp.Samples, t_s: float) -> None:
            listener(self._converted(msg, t_s))

        call.__qualname__ = getattr(listener, "__qualname__", repr(listener))  # its logs' name
        self.link.add_samples_listener(call)

    def add_report_listener(self, listener: ReportListener) -> None:
        """Input changes (EVENT) and faults (FAULT), each once, in mm and s, on the hot path;
        guarded by the link as batch listeners are. A move's or a probe's completion goes to
        whoever waits for it (``wait_move``, ``wait_probe``)."""

        def call(msg: fp.Report, t_s: float) -> None:
            report = _report_from_wire(msg, t_s)
            if report is not None:
                listener(report)

        call.__qualname__ = getattr(listener, "__qualname__", repr(listener))  # its logs' name
        self.link.add_report_listener(call)

    def z_range_mm(self) -> tuple[float, float] | None:
        """The board's Z travel (min, max) as its HELLO_INFO says, or None before one."""
        session = self.link.session
        info = None if session is None else session.info
        return None if info is None else (info.z_min_um / 1000, info.z_max_um / 1000)

    def _converted(self, msg: fp.Samples, t_s: float) -> Batch:
        if msg is not self._wire or self._batch is None:
            self._batch = batch_from_wire(msg, t_s)
            self._wire = msg
        return self._batch

    def add_state_listener(self, listener: StateListener) -> None:
        self.link.add_state_listener(listener)

    def add_error_listener(self, listener: ErrorListener) -> None:
        """Called when a listener raised while handling board data (docs/DESIGN.md invariant 6)."""
        self.link.add_error_listener(listener)

    @property
    def board_time_s(self) -> float:
        """The latest board time seen, in seconds: when a host command takes effect."""
        return self.link.timeline.now_s

    def _to_streams(self, item: Telemetry) -> None:
        for queue in self._queues:
            if queue.full():
                queue.get_nowait()  # the stream keeps the newest; counted as a gap upstream
            queue.put_nowait(item)

    async def telemetry(self) -> AsyncGenerator[Telemetry, None]:
        """Samples and reports as they arrive (bounded; the oldest are dropped if unread)."""
        queue: asyncio.Queue[Telemetry] = asyncio.Queue(self._stream_size)
        self._queues.append(queue)
        try:
            while True:
                yield await queue.get()
        finally:
            self._queues.remove(queue)

    def _on_report(self, msg: fp.Report, _t_s: float) -> None:
        if isinstance(msg, fp.MotionDone | fp.ProbeResult | fp.HomeResult):
            key = (type(msg), msg.seq)
            waiter = self._waiters.pop(key, None)
            if waiter is not None and not waiter.done():
                waiter.set_result(msg)
            else:
                self._recent[key] = msg
                while len(self._recent) > 16:
                    self._recent.popitem(last=False)

    def _on_event_gap(self, missed: int) -> None:
        # A lost edge or fault report: learn the current state instead of guessing. One
        # refresh at a time: a STATUS asked while another is on its way learns nothing new.
        if self._refresh is None or self._refresh.done():
            self._refresh = asyncio.get_running_loop().create_task(
                self._refresh_status(), name="status-after-gap"
            )

    async def stop_background(self) -> None:
        """Cancel and await the client's own background work (a status refresh); the
        client stays usable. Its owner (the controller service's run) calls it on the way out."""
        refresh, self._refresh = self._refresh, None
        if refresh is not None and not refresh.done():
            refresh.cancel()
            await asyncio.wait({refresh})

    async def _refresh_status(self) -> None:
        try:
            await self.status()
        except Exception:  # best effort; the link layer logs its own failures
            return

    # --- commands --------------------------------------------------------------------------

    def _session(self) -> BoardSession:
        return self.link.current()

    async def _ack(self, command: fp.Message) -> None:
        await self._session().request(command)

    async def torch(self, on: bool) -> None:
        await self._ack(fp.Torch(0, on))

    async def ohmic_sense(self, on: bool) -> None:
        await self._ack(fp.OhmicSense(0, on))

    async def set_current(self, current_a: float) -> None:
        await self._ack(fp.SetCurrent(0, round(current_a * 10)))

    async def fault_reset(self, mask: int = 0xFFFF) -> None:
        await self._ack(fp.FaultReset(0, mask))

    async def configure(
        self,
        *,
        sample_rate_hz: int = fp.DEFAULT_SAMPLE_RATE_HZ,
        batch_size: int = fp.DEFAULT_BATCH_SIZE,
        filter_kind: int = fp.FilterKind.NONE,
        filter_param: int = 0,
        arc_lost_ms: int = 0,
        cal_offset: int = 0,
        cal_scale: float = 0.01,
    ) -> None:
        await self._ack(
            fp.Configure(
                0, sample_rate_hz, batch_size, filter_kind, filter_param, arc_lost_ms,
                cal_offset, cal_scale,
            )
        )  # fmt: skip

    async def status(self) -> fp.Status:
        reply = await self._session().request(fp.Query(0, fp.QueryWhat.STATUS))
        assert isinstance(reply, fp.Status)
        self.last_status = reply
        return reply

    def z_velocity(self, velocity_mm_s: float, expiry_ms: int | None = None) -> None:
        """THC output: send a Z velocity setpoint now (not acknowledged, expires on the board)."""
        self._session().send_velocity(_um(velocity_mm_s), expiry_ms)

    async def move_z(
        self, target_mm: float, feed_mm_s: float, timeout_s: float = 10.0
    ) -> MoveEnded:
        """Move Z and wait for the board to report the move ended."""
        seq = await self.start_move_z(target_mm, feed_mm_s)
        return await self.wait_move(seq, timeout_s)

    async def start_move_z(self, target_mm: float, feed_mm_s: float) -> int:
        """Start a Z move; returns its seq once the board accepted it (ACK)."""
        ack = await self._session().request(fp.ZMove(0, _um(target_mm), _um(feed_mm_s)))
        return ack.seq

    async def probe(
        self,
        feed_mm_s: float,
        max_travel_mm: float,
        sensors: int = fp.InputMask.OHMIC | fp.InputMask.FLOAT,
        timeout_s: float = 20.0,
        *,
        away: bool = False,
    ) -> ProbeEnded:
        """Probe down; the board stops on contact by itself and reports where (``away``:
        up, stopped when every sensor is released; PROBE_RESULT RELEASED or NO_RELEASE)."""
        seq = await self.start_probe(feed_mm_s, max_travel_mm, sensors, away=away)
        return await self.wait_probe(seq, timeout_s)

    async def start_probe(
        self, feed_mm_s: float, max_travel_mm: float, sensors: int, *, away: bool = False
    ) -> int:
        """Start a probe (Z_PROBE; ``away``: Z_PROBE_AWAY, refused with BoardTooOld before
        anything is sent when the board's protocol predates it); returns its seq once the
        board accepted it (ACK)."""
        session = self._session()
        feed_um_s, travel_um = _um(feed_mm_s), _um(max_travel_mm)
        command: fp.ZProbe | fp.ZProbeAway
        if away:
            info = session.info
            if info is not None and info.proto_minor < PROBE_AWAY_MINOR:
                raise BoardTooOld(
                    "Z_PROBE_AWAY",
                    (fp.PROTOCOL_MAJOR, PROBE_AWAY_MINOR),
                    (info.proto_major, info.proto_minor),
                )
            command = fp.ZProbeAway(0, feed_um_s, travel_um, sensors)
        else:
            command = fp.ZProbe(0, feed_um_s, travel_um, sensors)
        ack = await session.request(command)
        return ack.seq

    def can_home(self) -> bool:
        """The board homes Z: protocol 1.3 or later and the HOMING capability."""
        info = self._session().info
        return (
            info is not None
            and info.proto_minor >= HOMING_MINOR
            and bool(info.capabilities & fp.Capability.HOMING)
        )

    async def home(
        self,
        *,
        seek_mm_s: float,
        locate_mm_s: float,
        backoff_mm: float,
        max_travel_mm: float,
        timeout_s: float,
    ) -> HomeEnded:
        """Home Z on the board's home switch (Z_HOME) and wait for its HOME_RESULT; refused
        with BoardTooOld before anything is sent when the board's protocol predates it."""
        session = self._session()
        info = session.info
        if info is not None and info.proto_minor < HOMING_MINOR:
            raise BoardTooOld(
                "Z_HOME", (fp.PROTOCOL_MAJOR, HOMING_MINOR), (info.proto_major, info.proto_minor)
            )
        timeout_ms = min(round(timeout_s * 1000), 0xFFFF)
        ack = await session.request(
            fp.ZHome(
                0, _um(seek_mm_s), _um(locate_mm_s), _um(backoff_mm), _um(max_travel_mm),
                timeout_ms,
            )
        )  # fmt: skip
        msg = await self._wait_report(fp.HomeResult, ack.seq, timeout_ms / 1000 + 2.0)
        return HomeEnded(msg.result, msg.z_um / 1000, msg.shift_um / 1000)

    async def wait_move(self, seq: int, timeout_s: float) -> MoveEnded:
        """Wait for the Z move ``seq`` (``start_move_z``) to end."""
        return _move_ended(await self._wait_report(fp.MotionDone, seq, timeout_s))

    async def wait_probe(self, seq: int, timeout_s: float) -> ProbeEnded:
        """Wait for the probe ``seq`` (``start_probe``) to end."""
        return _probe_ended(await self._wait_report(fp.ProbeResult, seq, timeout_s))

    async def _wait_report(self, report: type[_Report], seq: int, timeout_s: float) -> _Report:
        """Wait for the completion report of the command ``seq`` (MOTION_DONE/PROBE_RESULT)."""
        session = self._session()
        key = (report, seq)  # the completion carries the seq of the command it ends
        found = self._recent.pop(key, None)
        if isinstance(found, report):
            return found
        waiter: asyncio.Future[fp.Message] = asyncio.get_running_loop().create_future()
        self._waiters[key] = waiter
        try:
            watched: set[asyncio.Future[Any]] = {waiter, session.lost}
            done, _ = await asyncio.wait(
                watched, timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED
            )
        finally:
            self._waiters.pop(key, None)
        if waiter in done:
            result = waiter.result()
            assert isinstance(result, report)
            return result
        if session.lost in done:
            raise session.lost.result()
        # The completion report may have been lost on the way: if Z has stopped, ask for it.
        what = _COMPLETION_QUERY[report]
        status = await self.status()
        if not status.status & fp.StatusBit.Z_BUSY:
            queried = await session.request(fp.Query(0, what))
            if isinstance(queried, report):
                return queried._replace(seq=seq)
        raise RequestTimeout(report.__name__, 1, timeout_s)
