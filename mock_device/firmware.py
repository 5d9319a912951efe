"""The board firmware, as PROTOCOL.md specifies it, driving a simulated plant.

Pure logic stepped by a clock: ``receive(bytes)`` takes host bytes, ``tick()`` runs one
sample period (plant step, inputs, safety latches, probe stop, sampling), and every byte
the board sends goes to the ``write`` callback. The real-time process and the in-process
simulated-time harness both drive this same object.
"""

from __future__ import annotations

import random
import statistics
from collections import Counter, OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import firmware_protocol as fp
from firmware_protocol import FaultCode, InputMask, NakCode, StatusBit

__all__ = ["BoardFirmware", "BoardIdentity", "PlantPort", "ZAxisPort"]

FAULT_REPORT_PERIOD_US = 250_000
ADC_COUNTS_PER_VOLT = 100  # the simulated front end: a 16-bit ADC in centivolts
CONTACT_SENSORS = InputMask.OHMIC | InputMask.FLOAT
PROBE_AWAY_MINOR = 2  # the protocol minor that brought Z_PROBE_AWAY (1.2)


class ZAxisPort(Protocol):
    position_mm: float
    min_mm: float
    max_mm: float
    max_velocity_mm_s: float

    @property
    def limit_hit(self) -> str | None: ...
    @property
    def is_idle(self) -> bool: ...
    def move_to(self, target_mm: float, feed_mm_s: float) -> None: ...
    def jog(self, velocity_mm_s: float) -> None: ...
    def stop(self) -> None: ...


class PlantPort(Protocol):
    """What the firmware needs of the machine behind it (see mock_device.plant.Plant)."""

    @property
    def zaxis(self) -> ZAxisPort: ...
    @property
    def xy_speed_mm_s(self) -> float: ...
    def step(self, dt_s: float) -> None: ...
    def measured_voltage_v(self) -> float: ...
    def input_bits(self) -> int: ...
    def set_torch(self, on: bool) -> None: ...
    def set_ohmic_sense(self, on: bool) -> None: ...
    def set_current_a(self, current_a: float) -> None: ...
    def reset_breakaway(self) -> bool: ...
    def count_violation(self, kind: str) -> None: ...


@dataclass(frozen=True)
class BoardIdentity:
    serial: str = "MOCK-0001"
    fw_version: tuple[int, int, int] = (0, 1, 0)
    proto_major: int = fp.PROTOCOL_MAJOR
    proto_minor: int = fp.PROTOCOL_MINOR
    capabilities: int = int(
        fp.Capability.XY_SPEED
        | fp.Capability.OHMIC
        | fp.Capability.FLOAT
        | fp.Capability.BREAKAWAY
        | fp.Capability.THC_UPDOWN
        | fp.Capability.CURRENT_OUT
        | fp.Capability.ESTOP
        | fp.Capability.Z_LIMITS
        | fp.Capability.FILTERS
    )
    max_feed_um_s: int = 60_000


@dataclass
class _Probe:
    seq: int
    sensors: int
    start_z_um: int
    max_travel_um: int
    contact_z_um: int | None = None  # where contact (away: the release) was detected
    fired: int = 0  # the sensors that fired; away: the ones last seen active
    outcome: int | None = None
    away: bool = False  # Z_PROBE_AWAY (1.2): up until every sensor is released


@dataclass
class _Sampling:
    rate_hz: int = fp.DEFAULT_SAMPLE_RATE_HZ
    batch_size: int = fp.DEFAULT_BATCH_SIZE
    filter_kind: int = fp.FilterKind.NONE
    filter_param: int = 0
    arc_lost_ms: int = 0
    cal_offset: int = 0
    cal_scale: float = 1.0 / ADC_COUNTS_PER_VOLT
    history: deque[float] = field(default_factory=lambda: deque(maxlen=32))
    lowpass_v: float | None = None

    @property
    def period_us(self) -> int:
        return 1_000_000 // self.rate_hz


def _um(mm: float) -> int:
    return round(mm * 1000.0)


class BoardFirmware:
    """One board: session, lease, duplicate memory, faults, motion, probing, sampling."""

    def __init__(
        self,
        plant: PlantPort,
        write: Callable[[bytes], None],
        *,
        rng: random.Random | None = None,
        identity: BoardIdentity | None = None,
        reset_reason: int = fp.ResetReason.POWER_ON,
    ) -> None:
        self.plant = plant
        self.write = write
        self.identity = identity or BoardIdentity()
        self.rng = rng or random.Random()
        self.boot_id = self.rng.getrandbits(32)
        self.reset_reason = reset_reason
        self.t_us = 0
        self.session = False
        self.lease_ms = fp.DEFAULT_LEASE_MS
        self.lease_expired = False  # ran out in use: LEASE_EXPIRED latched until FAULT_RESET
        self.lease_lapsed_idle = False  # ran out at rest: reported once, until the next frame
        self.lease_violation_counted = False
        self.unsafe_torch_us = 0  # torch on past lease + one period: the soak's figure
        self.last_rx_us = 0
        self.faults = 0
        self.fault_counter_of: dict[int, int] = {}
        self.last_fault_report_us = 0
        self.event_counter = 0
        self.torch_on = False
        self.ohmic_sense = False
        self.current_da = 0
        self.inputs = 0
        self.sampling = _Sampling()
        self.sample_seq = 0
        self.batch: list[int] = []
        self.batch_t0_us = 0
        self.zvel_seq = 0
        self.zvel_applied = False  # the stream restarts with each session
        self.zvel_expiry_us: int | None = None
        self.zvel_velocity_um_s = 0
        self.move_seq: int | None = None
        self.probe: _Probe | None = None
        self.last_probe_result: fp.ProbeResult | None = None
        self.last_motion_done: fp.MotionDone | None = None
        self.arc_ok_seen = False
        self.arc_off_since_us: int | None = None
        # seq -> encoded reply of the last HOST_WINDOW executed side-effecting commands.
        self.replies: OrderedDict[int, bytes] = OrderedDict()
        self.rx_duplicates = 0
        # Commands executed (duplicates answered from memory are not): what the host had the
        # board do, for tests that check nothing was done that nobody asked for.
        self.executed: Counter[str] = Counter()
        self.torch_on_commands = 0
        # Fault injection: replies built while stalled are never sent.
        self.stall_replies_until_us = 0
        self.decoder = fp.StreamDecoder(on_error=self._on_bad_frame)
        # Instruments (the process's --latency-log); None, and never called, otherwise.
        self.on_zvelocity: Callable[[fp.ZVelocity], None] | None = None
        self.on_samples: Callable[[fp.Samples], None] | None = None

    # --- receive ---------------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        for msg in self.decoder.feed(data):
            self._renew_lease()
            self._handle(msg)

    def _renew_lease(self) -> None:
        if self.session and not self.lease_expired:
            self.last_rx_us = self.t_us
            self.lease_lapsed_idle = False  # an idle lapse ends here: no re-arm (§4)

    def _on_bad_frame(self, error: fp.DecodeError) -> None:
        # A frame with a valid CRC but unknown type or wrong length still renews the lease
        # and, when sequenced, gets a NAK (PROTOCOL.md §7).
        if isinstance(error, fp.UnknownMessageType | fp.BadLength) and len(error.raw) >= 4:
            self._renew_lease()
            seq = error.raw[1]
            if seq:
                code = (
                    NakCode.UNKNOWN_TYPE
                    if isinstance(error, fp.UnknownMessageType)
                    else NakCode.BAD_LENGTH
                )
                self._send(fp.Nak(seq, self.boot_id, code, 0))

    def _encode(self, msg: fp.Message) -> bytes:
        return fp.encode(msg)

    def _send(self, msg: fp.Message) -> bytes:
        data = self._encode(msg)
        if self.t_us >= self.stall_replies_until_us or isinstance(
            msg, fp.Samples | fp.Event | fp.Fault
        ):
            self.write(data)
        return data

    def _reply(self, seq: int, msg: fp.Message) -> None:
        """Send the reply of a side-effecting command and remember it for duplicates."""
        data = self._send(msg)
        self.replies[seq] = data
        self.replies.move_to_end(seq)
        while len(self.replies) > fp.HOST_WINDOW:
            self.replies.popitem(last=False)

    def _ack(self, seq: int) -> None:
        self._reply(seq, fp.Ack(seq, self.boot_id))

    def _nak(self, seq: int, code: int, detail: int = 0) -> None:
        self._reply(seq, fp.Nak(seq, self.boot_id, code, detail))

    def _handle(self, msg: fp.Message) -> None:
        if isinstance(msg, fp.Hello):
            self._hello(msg)
        elif isinstance(msg, fp.Query):
            self._query(msg)
        elif isinstance(msg, fp.ClockQuery):
            self._send(fp.Clock(msg.seq, self.t_us))
        elif isinstance(msg, fp.ZVelocity):
            self._z_velocity(msg)
            if self.on_zvelocity is not None:
                self.on_zvelocity(msg)
        elif not self.session:
            if msg.seq:
                self._send(fp.Nak(msg.seq, self.boot_id, NakCode.NO_SESSION, 0))
        elif msg.seq in self.replies:
            # A retransmission of a command already executed: answer again, act once.
            self.rx_duplicates += 1
            self.write(self.replies[msg.seq])
        else:
            self._command(msg)

    def _hello(self, msg: fp.Hello) -> None:
        self._send(self._hello_info(msg.seq))
        if msg.proto_major != self.identity.proto_major:
            self.session = False
            return
        self.session = True
        self.replies.clear()
        self.zvel_applied = False
        self.last_rx_us = self.t_us
        self.lease_lapsed_idle = False

    def _hello_info(self, seq: int) -> fp.HelloInfo:
        ident = self.identity
        z = self.plant.zaxis
        return fp.HelloInfo(
            seq, ident.proto_major, ident.proto_minor, *ident.fw_version, self.reset_reason,
            self.boot_id, ident.serial, self.sampling.rate_hz, self.sampling.batch_size,
            ident.capabilities, _um(z.min_mm), _um(z.max_mm), fp.MAX_FRAME, self.lease_ms,
        )  # fmt: skip

    def _query(self, msg: fp.Query) -> None:
        seq = msg.seq
        if msg.what == fp.QueryWhat.STATUS:
            self._send(self.status(seq))
        elif msg.what == fp.QueryWhat.HELLO_INFO:
            self._send(self._hello_info(seq))
        elif msg.what == fp.QueryWhat.PROBE_RESULT and self.last_probe_result is not None:
            self._send(self.last_probe_result._replace(seq=seq))
        elif msg.what == fp.QueryWhat.MOTION_DONE and self.last_motion_done is not None:
            self._send(self.last_motion_done._replace(seq=seq))
        else:
            self._send(fp.Nak(seq, self.boot_id, NakCode.OUT_OF_RANGE, 0))

    def status(self, seq: int = 0) -> fp.Status:
        dec = self.decoder.stats
        return fp.Status(
            seq, self.boot_id, self.t_us & 0xFFFFFFFF, self.faults, self.inputs,
            self.status_bits(), self.lease_ms, self.event_counter & 0xFFFFFFFF,
            self.sample_seq, self.zvel_seq, _um(self.plant.zaxis.position_mm), self.current_da,
            min(dec.crc_errors, 0xFFFF), min(dec.framing_errors, 0xFFFF),
            min(self.rx_duplicates, 0xFFFF),
        )  # fmt: skip

    def status_bits(self) -> int:
        bits = 0
        if self.torch_on:
            bits |= StatusBit.TORCH_ON
        if self.ohmic_sense:
            bits |= StatusBit.OHMIC_SENSE
        if self.faults:
            bits |= StatusBit.FAULT_LATCHED
        if not self.plant.zaxis.is_idle:
            bits |= StatusBit.Z_BUSY
        if self.session:
            bits |= StatusBit.SESSION
        return int(bits)

    def _lowest_fault(self) -> int:
        return (self.faults & -self.faults).bit_length() - 1

    def _command(self, msg: fp.Message) -> None:
        seq = msg.seq
        self.executed[type(msg).__name__] += 1
        if isinstance(msg, fp.Heartbeat):
            self._ack(seq)
        elif isinstance(msg, fp.SetLease):
            if not fp.LEASE_MIN_MS <= msg.lease_ms <= fp.LEASE_MAX_MS:
                self._nak(seq, NakCode.OUT_OF_RANGE, 0)
            else:
                self.lease_ms = msg.lease_ms
                self._ack(seq)
        elif isinstance(msg, fp.Torch):
            if msg.on and self.faults:
                self._nak(seq, NakCode.FAULT_LATCHED, self._lowest_fault())
            else:
                self.torch_on_commands += msg.on
                self._set_torch(msg.on)
                self._ack(seq)
        elif isinstance(msg, fp.OhmicSense):
            self.ohmic_sense = msg.on
            self.plant.set_ohmic_sense(msg.on)
            self._ack(seq)
        elif isinstance(msg, fp.ZMove):
            self._z_move(msg)
        elif isinstance(msg, fp.ZProbeAway) and self.identity.proto_minor < PROBE_AWAY_MINOR:
            self._nak(seq, NakCode.UNKNOWN_TYPE, 0)  # as a board of protocol 1.1 or older
        elif isinstance(msg, fp.ZProbe | fp.ZProbeAway):
            self._z_probe(msg)
        elif isinstance(msg, fp.ZStop):
            self._end_motion(fp.MotionResult.STOPPED, fp.ProbeOutcome.ABORTED)
            self.plant.zaxis.stop()
            self._ack(seq)
        elif isinstance(msg, fp.SetCurrent):
            self.current_da = msg.current_da
            self.plant.set_current_a(msg.current_da / 10.0)
            self._ack(seq)
        elif isinstance(msg, fp.Configure):
            self._configure(msg)
        elif isinstance(msg, fp.FaultReset):
            self._fault_reset(msg)
        else:  # a board message sent to the board
            self._nak(seq, NakCode.UNKNOWN_TYPE, 0)

    def _set_torch(self, on: bool) -> None:
        self.torch_on = on
        self.plant.set_torch(on)
        self.arc_ok_seen = False
        self.arc_off_since_us = None

    def _z_move(self, msg: fp.ZMove) -> None:
        z = self.plant.zaxis
        if not _um(z.min_mm) <= msg.target_um <= _um(z.max_mm):
            self._nak(msg.seq, NakCode.OUT_OF_RANGE, 0)
            return
        if not msg.feed_um_s > 0:
            self._nak(msg.seq, NakCode.OUT_OF_RANGE, 1)
            return
        if self.faults and msg.target_um <= _um(z.position_mm):
            self._nak(msg.seq, NakCode.FAULT_LATCHED, self._lowest_fault())
            return
        self._end_motion(fp.MotionResult.SUPERSEDED, fp.ProbeOutcome.ABORTED)
        feed_um_s = min(msg.feed_um_s, self.identity.max_feed_um_s)
        z.move_to(msg.target_um / 1000.0, feed_um_s / 1000.0)
        self.move_seq = msg.seq
        self._ack(msg.seq)

    def _z_probe(self, msg: fp.ZProbe | fp.ZProbeAway) -> None:
        """Z_PROBE: down until a sensor of the set is active; Z_PROBE_AWAY: up until every
        one is released. The same refusals and rules either way (PROTOCOL.md §6.1)."""
        if self.faults:
            self._nak(msg.seq, NakCode.FAULT_LATCHED, self._lowest_fault())
            return
        for index, ok in enumerate(
            (msg.feed_um_s > 0, msg.max_travel_um > 0, msg.sensors & CONTACT_SENSORS)
        ):
            if not ok:
                self._nak(msg.seq, NakCode.OUT_OF_RANGE, index)
                return
        self._end_motion(fp.MotionResult.SUPERSEDED, fp.ProbeOutcome.ABORTED)
        z = self.plant.zaxis
        z_um = _um(z.position_mm)
        away = isinstance(msg, fp.ZProbeAway)
        probe = _Probe(msg.seq, msg.sensors & CONTACT_SENSORS, z_um, msg.max_travel_um, away=away)
        self.probe = probe
        self._ack(msg.seq)
        probe.fired = self.inputs & probe.sensors
        if bool(probe.fired) != away:  # already in contact (away: released): zero travel
            probe.contact_z_um = z_um
            probe.outcome = fp.ProbeOutcome.RELEASED if away else fp.ProbeOutcome.CONTACT
        else:
            feed_mm_s = min(msg.feed_um_s, self.identity.max_feed_um_s) / 1000.0
            z.jog(feed_mm_s if away else -feed_mm_s)

    def _z_velocity(self, msg: fp.ZVelocity) -> None:
        if not self.session or self.faults:
            return
        delta = (msg.stream_seq - self.zvel_seq) & 0xFFFF
        if self.zvel_applied and not 0 < delta < 0x8000:
            return  # not newer than what was applied: a late or duplicated frame
        if not 0 < msg.expiry_ms <= fp.ZVEL_EXPIRY_MAX_MS:
            return
        self.zvel_seq = msg.stream_seq
        self.zvel_applied = True
        if self.probe is not None or self.move_seq is not None:
            self._end_motion(fp.MotionResult.SUPERSEDED, fp.ProbeOutcome.ABORTED)
        self.plant.zaxis.jog(msg.velocity_um_s / 1000.0)
        self.zvel_velocity_um_s = msg.velocity_um_s
        self.zvel_expiry_us = self.t_us + msg.expiry_ms * 1000

    def _configure(self, msg: fp.Configure) -> None:
        checks = (
            100 <= msg.sample_rate_hz <= 20_000,
            1 <= msg.batch_size <= fp.MAX_BATCH_SIZE,
            msg.filter_kind in set(fp.FilterKind),
            msg.filter_kind != fp.FilterKind.MOVING_AVERAGE or 1 <= msg.filter_param <= 32,
            msg.arc_lost_ms <= 1000,
            True,
            msg.cal_scale > 0.0 and msg.cal_scale != float("inf"),
        )
        if msg.filter_kind == fp.FilterKind.LOW_PASS and not 1 <= msg.filter_param <= 500:
            self._nak(msg.seq, NakCode.OUT_OF_RANGE, 3)
            return
        for index, ok in enumerate(checks):
            if not ok:
                self._nak(msg.seq, NakCode.OUT_OF_RANGE, index)
                return
        s = self.sampling
        s.rate_hz, s.batch_size = msg.sample_rate_hz, msg.batch_size
        s.filter_kind, s.filter_param = msg.filter_kind, msg.filter_param
        s.arc_lost_ms, s.cal_offset, s.cal_scale = msg.arc_lost_ms, msg.cal_offset, msg.cal_scale
        s.history.clear()
        s.lowpass_v = None
        self.batch.clear()
        self._ack(msg.seq)

    def _fault_reset(self, msg: fp.FaultReset) -> None:
        mask = msg.mask & self.faults
        still = {
            FaultCode.BREAKAWAY: bool(self.inputs & InputMask.BREAKAWAY),
            FaultCode.ESTOP: bool(self.inputs & InputMask.ESTOP),
        }
        if mask & (1 << FaultCode.BREAKAWAY) and self.plant.reset_breakaway():
            still[FaultCode.BREAKAWAY] = True
        for code, active in still.items():
            if active and mask & (1 << code):
                self._nak(msg.seq, NakCode.FAULT_ACTIVE, code)
                return
        self.faults &= ~mask
        for latched in list(self.fault_counter_of):
            if mask & (1 << latched):
                del self.fault_counter_of[latched]
        if mask & (1 << FaultCode.LEASE_EXPIRED):
            self.lease_expired = False
            self.last_rx_us = self.t_us
        self._ack(msg.seq)

    # --- one sample period -----------------------------------------------------------------

    def tick(self) -> None:
        period_us = self.sampling.period_us
        self.t_us += period_us
        plant = self.plant
        plant.step(period_us / 1e6)
        self._inputs_changed(plant.input_bits())
        self._check_safety()
        self._audit_lease()
        self._check_motion()
        self._sample()
        if self.faults and self.t_us - self.last_fault_report_us >= FAULT_REPORT_PERIOD_US:
            self._report_faults()

    def _inputs_changed(self, now: int) -> None:
        changed = now ^ self.inputs
        self.inputs = now
        while changed:
            bit = (changed & -changed).bit_length() - 1
            changed &= changed - 1
            self.event_counter += 1
            self._send(
                fp.Event(
                    0, self.event_counter & 0xFFFFFFFF, self.t_us & 0xFFFFFFFF, bit,
                    (now >> bit) & 1, now, _um(self.plant.zaxis.position_mm),
                )
            )  # fmt: skip

    def _lease_overdue(self) -> bool:
        return self.session and self.t_us - self.last_rx_us > self.lease_ms * 1000

    def at_rest(self) -> bool:
        """Nothing lit, nothing moving (PROTOCOL.md §4): torch and ohmic sensing off, no
        move, probe or velocity in force, and Z still (not decelerating)."""
        return (
            not self.torch_on
            and not self.ohmic_sense
            and self.move_seq is None
            and self.probe is None
            and self.zvel_expiry_us is None
            and self.plant.zaxis.is_idle
        )

    def _check_lease(self) -> None:
        """In use: LEASE_EXPIRED latched, outputs off, Z stopped, until FAULT_RESET. At rest:
        one FAULT LEASE_EXPIRED detail IDLE with the next event counter and the fault set as
        it is, nothing latched; the next valid frame renews the lease. Nothing can leave the
        rest state while the host stays silent: only host frames start the torch, ohmic
        sensing or Z, and each valid frame renews the lease before it is executed."""
        if self.lease_expired or self.lease_lapsed_idle or not self._lease_overdue():
            return
        if self.at_rest():
            self.lease_lapsed_idle = True
            self.event_counter += 1
            self._send(
                fp.Fault(
                    0, self.event_counter & 0xFFFFFFFF, self.t_us & 0xFFFFFFFF,
                    FaultCode.LEASE_EXPIRED, fp.LEASE_DETAIL_IDLE, self.faults,
                    _um(self.plant.zaxis.position_mm),
                )
            )  # fmt: skip
            return
        self.lease_expired = True
        self._latch(FaultCode.LEASE_EXPIRED, fp.LEASE_DETAIL_LATCHED)

    def _audit_lease(self) -> None:
        """Ground truth, independent of the firmware's own lease logic (which a faulty variant
        may break): the torch must be off one sample period after the lease ran out."""
        grace_us = self.lease_ms * 1000 + self.sampling.period_us
        late = self.session and self.t_us - self.last_rx_us > grace_us
        if not late:
            self.lease_violation_counted = False
        elif self.torch_on:
            self.unsafe_torch_us += self.sampling.period_us
            if not self.lease_violation_counted:
                self.lease_violation_counted = True  # once per episode
                self.plant.count_violation("torch_on_after_lease_expiry")

    def _check_safety(self) -> None:
        inputs = self.inputs
        self._check_lease()
        if inputs & InputMask.BREAKAWAY:
            self._latch(FaultCode.BREAKAWAY)
        if inputs & InputMask.ESTOP:
            self._latch(FaultCode.ESTOP)
        # A velocity stream driving Z into a soft limit latches Z_LIMIT (PROTOCOL.md §6.1);
        # a probe reaching Z min ends with result LIMIT instead, and a move is clamped.
        hit = self.plant.zaxis.limit_hit
        into_limit = hit is not None and (hit == "min") == (self.zvel_velocity_um_s < 0)
        if into_limit and self.zvel_expiry_us is not None:
            self._latch(FaultCode.Z_LIMIT, 0 if hit == "min" else 1)
        if self.torch_on and self.sampling.arc_lost_ms:
            if inputs & InputMask.ARC_OK:
                self.arc_ok_seen = True
                self.arc_off_since_us = None
            elif self.arc_ok_seen:
                if self.arc_off_since_us is None:
                    self.arc_off_since_us = self.t_us
                elif self.t_us - self.arc_off_since_us >= self.sampling.arc_lost_ms * 1000:
                    self._latch(FaultCode.ARC_LOST)

    def _latch(self, code: FaultCode, detail: int = 0) -> None:
        if self.faults & (1 << code):
            return
        self.faults |= 1 << code
        if self.torch_on:
            self._set_torch(False)
        if self.ohmic_sense:
            self.ohmic_sense = False
            self.plant.set_ohmic_sense(False)
        self._end_motion(fp.MotionResult.FAULT, fp.ProbeOutcome.ABORTED)
        self.zvel_expiry_us = None
        self.plant.zaxis.stop()
        self.event_counter += 1
        self.fault_counter_of[code] = self.event_counter
        self._send_fault(code, detail)

    def _send_fault(self, code: int, detail: int) -> None:
        self.last_fault_report_us = self.t_us
        self._send(
            fp.Fault(
                0, self.fault_counter_of[code] & 0xFFFFFFFF, self.t_us & 0xFFFFFFFF, code, detail,
                self.faults, _um(self.plant.zaxis.position_mm),
            )
        )  # fmt: skip

    def _report_faults(self) -> None:
        for code in sorted(self.fault_counter_of):
            self._send_fault(code, 0)

    def _end_motion(self, move_result: int, probe_result: int) -> None:
        """End a running move or probe early, reporting it."""
        z_um = _um(self.plant.zaxis.position_mm)
        if self.move_seq is not None:
            self._motion_done(self.move_seq, move_result, z_um)
        if self.probe is not None:
            self.probe.outcome = probe_result
            self._probe_done(z_um)
        self.zvel_expiry_us = None

    def _motion_done(self, seq: int, result: int, z_um: int) -> None:
        self.move_seq = None
        self.last_motion_done = fp.MotionDone(seq, result, z_um, self.t_us & 0xFFFFFFFF)
        self._send(self.last_motion_done)

    def _probe_done(self, z_um: int) -> None:
        probe = self.probe
        assert probe is not None
        assert probe.outcome is not None
        self.probe = None
        contact = probe.contact_z_um if probe.contact_z_um is not None else z_um
        self.last_probe_result = fp.ProbeResult(
            probe.seq, probe.outcome, probe.fired, contact, z_um, self.t_us & 0xFFFFFFFF
        )
        self._send(self.last_probe_result)

    def _check_motion(self) -> None:
        z = self.plant.zaxis
        z_um = _um(z.position_mm)
        probe = self.probe
        if probe is not None:
            if probe.outcome is None:
                self._probe_tick(probe, z_um)
            if probe.outcome is not None and z.is_idle:
                self._probe_done(z_um)
        elif self.move_seq is not None and z.is_idle:
            reached = z.limit_hit is None or abs(z.position_mm * 1000 - z_um) < 1
            result = fp.MotionResult.REACHED if reached else fp.MotionResult.LIMIT
            self._motion_done(self.move_seq, result, z_um)
        if self.zvel_expiry_us is not None and self.t_us >= self.zvel_expiry_us:
            self.zvel_expiry_us = None
            z.stop()

    def _probe_tick(self, probe: _Probe, z_um: int) -> None:
        """Down until a sensor is active, or (away) up until every one is released."""
        z = self.plant.zaxis
        away = probe.away
        active = self.inputs & probe.sensors
        if active:
            probe.fired = active  # away: the last seen active, the last to let go
        travelled_um = z_um - probe.start_z_um if away else probe.start_z_um - z_um
        if bool(active) != away:
            # The stop happens here, in the sample tick: no host round trip.
            probe.contact_z_um = z_um
            probe.outcome = fp.ProbeOutcome.RELEASED if away else fp.ProbeOutcome.CONTACT
        elif travelled_um >= probe.max_travel_um:
            probe.outcome = fp.ProbeOutcome.NO_RELEASE if away else fp.ProbeOutcome.NO_CONTACT
        elif z.limit_hit == ("max" if away else "min"):
            probe.outcome = fp.ProbeOutcome.LIMIT
        else:
            return
        z.stop()

    def _sample(self) -> None:
        s = self.sampling
        raw = round(self.plant.measured_voltage_v() * ADC_COUNTS_PER_VOLT)
        volts = self._filter((raw - s.cal_offset) * s.cal_scale)
        if not self.batch:
            self.batch_t0_us = self.t_us
        self.batch.append(min(max(round(volts * 100.0), 0), 0xFFFF))
        if len(self.batch) >= s.batch_size:
            self._send_batch()

    def _filter(self, volts: float) -> float:
        s = self.sampling
        kind = s.filter_kind
        if kind == fp.FilterKind.NONE:
            return volts
        s.history.append(volts)
        if kind == fp.FilterKind.MEDIAN3:
            return statistics.median(list(s.history)[-3:])
        if kind == fp.FilterKind.MOVING_AVERAGE:
            window = list(s.history)[-s.filter_param :]
            return sum(window) / len(window)
        # First-order low-pass: alpha from the cut-off and the sample period.
        dt = s.period_us / 1e6
        rc = 1.0 / (2.0 * 3.141592653589793 * s.filter_param)
        alpha = dt / (rc + dt)
        prev = volts if s.lowpass_v is None else s.lowpass_v
        s.lowpass_v = prev + alpha * (volts - prev)
        return s.lowpass_v

    def _send_batch(self) -> None:
        s = self.sampling
        speed = self.plant.xy_speed_mm_s
        xy = (
            min(round(speed * 10.0), 0xFFFE)
            if self.identity.capabilities & fp.Capability.XY_SPEED
            else fp.XY_SPEED_UNKNOWN
        )
        msg = fp.Samples(
            0, self.sample_seq, self.batch_t0_us & 0xFFFFFFFF, s.period_us,
            _um(self.plant.zaxis.position_mm), self.inputs, self.zvel_seq, xy,
            self.status_bits(), tuple(self.batch),
        )  # fmt: skip
        self._send(msg)
        if self.on_samples is not None:
            self.on_samples(msg)
        self.sample_seq = (self.sample_seq + 1) & 0xFFFF
        self.batch.clear()
