"""The reference firmware's board logic, run on the simulated plant.

:class:`BoardLogic` wires one :class:`~mock_device.cboard.CBoard` (firmware/board/ in C,
the code the AVR builds run) to a :class:`~mock_device.plant.Plant` through the hardware
layer: once per sample period the step generator moves the plant's Z, the plant steps, its
inputs, arc voltage and XY speed go to the board's pins and ADC, the board ticks, and its
outputs (torch relay, ohmic enable, current set point) go back to the plant. Host bytes go
to the board's UART the moment they arrive; every byte the board sends goes to ``write``,
frame by frame. The real-time process and the in-process simulated-time harness both drive
this same object.

What stays in Python is the mock's link, never the board's logic: the protocol version a
test asks the board to announce (:class:`BoardIdentity`; an older board refuses
Z_PROBE_AWAY), replies withheld (``stall_replies_until_us``), the operator who re-seats a
tripped breakaway before resetting it, the counters a test reads (``executed``) and the
ground-truth lease audit. mock_device.variants' misbehaving boards are link wrappers too
(or, for protocol 1.0's lease, a build of the same C).
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import firmware_protocol as fp
from firmware_protocol import FaultCode, InputMask, MsgType

from .cboard import CBoard

__all__ = ["UNKNOWN_TYPE", "BoardIdentity", "BoardLogic", "PlantPort", "ZAxisPort", "frame_type"]

ADC_COUNTS_PER_VOLT = 100  # the simulated front end: the board's raw count is a centivolt
PROBE_AWAY_MINOR = 2  # the protocol minor that brought Z_PROBE_AWAY (1.2)
HOMING_MINOR = 3  # ...and Z_HOME with the HOMING capability (1.3)
# Host frames that are commands (executed once per seq); the rest are queries or streamed.
_NOT_COMMANDS = (fp.Hello, fp.Query, fp.ClockQuery, fp.ZVelocity)
_Z_LIMIT_BITS = int(InputMask.Z_LIMIT_MIN | InputMask.Z_LIMIT_MAX)
_Z_LIMIT_MAX = int(InputMask.Z_LIMIT_MAX)
_ALWAYS_SENT = frozenset({MsgType.SAMPLES, MsgType.EVENT, MsgType.FAULT})
# A message type no protocol version defines: what an older board's codec makes of a newer
# message (NAK UNKNOWN_TYPE).
UNKNOWN_TYPE = next(t for t in range(0x7F, 0, -1) if t not in set(MsgType))


class ZAxisPort(Protocol):
    position_mm: float
    min_mm: float
    max_mm: float
    max_velocity_mm_s: float
    step_mm: float
    home_switch_mm: float

    @property
    def accel_mm_s2(self) -> float: ...
    @property
    def home_switch(self) -> bool: ...
    def drive(self, position_mm: float, velocity_mm_s: float) -> None: ...


class PlantPort(Protocol):
    """What the board needs of the machine behind it (see mock_device.plant.Plant)."""

    @property
    def zaxis(self) -> ZAxisPort: ...
    @property
    def xy_speed_mm_s(self) -> float: ...
    @property
    def forced_inputs(self) -> tuple[int, int]: ...
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
    """What the board says it is: its serial, the protocol version it announces (the board
    logic speaks the current one; an older one is emulated at the link) and its
    capabilities (the hardware the plant gives it)."""

    serial: str = "MOCK-0001"
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
        | fp.Capability.HOMING
    )
    max_feed_um_s: int = 60_000
    # The Z the firmware takes at power-on, until it homes (a build constant on a real
    # board: its Z count starts there wherever the carriage stands). None: where the
    # plant's Z stands, a board that never needs homing to be right.
    boot_z_mm: float | None = None


def _um(mm: float) -> int:
    return round(mm * 1000.0)


def frame_type(frame: bytes) -> int:
    """The message type of an encoded frame: its first body byte (never 0, so COBS leaves
    it in place after the code byte)."""
    return frame[1] if len(frame) > 2 and frame[0] != 1 else 0


class BoardLogic:
    """One board: the C board logic on the plant, and the mock's link around it."""

    build = ""  # the library build (mock_device.cboard.LIBRARIES)

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
        self.reset_reason = reset_reason
        z = plant.zaxis
        self._step_mm = z.step_mm
        # Where the plant's Z stands at power-on (the step count's origin), and the Z the
        # board takes for it until it homes (BoardIdentity.boot_z_mm).
        self._boot_mm = z.position_mm
        boot_z_mm = self.identity.boot_z_mm
        board_boot_mm = z.position_mm if boot_z_mm is None else boot_z_mm
        self.c = CBoard(self.build)
        self.c.init(
            serial=self.identity.serial,
            capabilities=self.identity.capabilities,
            z_min_um=_um(z.min_mm),
            z_max_um=_um(z.max_mm),
            z_boot_um=_um(board_boot_mm),
            z_max_speed_um_s=min(self.identity.max_feed_um_s, _um(z.max_velocity_mm_s)),
            z_accel_um_s2=_um(z.accel_mm_s2),
            z_steps_per_mm=round(1.0 / z.step_mm),
            reset_reason=reset_reason,
            z_home_um=_um(z.home_switch_mm),  # homed, the board's Z is the plant's
            entropy=self.rng.getrandbits(32),
        )
        self.hal = self.c.hal
        self._torch = False
        self._ohmic = False
        self._current_da = 0
        self._pending = b""  # host bytes after the last delimiter
        self._held: list[bytes] = []  # host frames waiting for the next tick
        # Ground truth, independent of the board's own lease logic (which a faulty variant
        # may break): the last valid host frame, and torch-on time past the lease.
        self.last_host_frame_us = 0
        self.unsafe_torch_us = 0
        self.lease_violation_counted = False
        # Commands executed (duplicates answered from memory are not): what the host had the
        # board do, for tests that check nothing was done that nobody asked for.
        self.executed: Counter[str] = Counter()
        self.torch_on_commands = 0
        # Fault injection: replies built while stalled are never sent.
        self.stall_replies_until_us = 0
        # Instruments (the process's --latency-log); None, and never called, otherwise.
        self.on_zvelocity: Callable[[fp.ZVelocity], None] | None = None
        self.on_samples: Callable[[fp.Samples], None] | None = None

    # --- the board's state --------------------------------------------------------------------

    @property
    def t_us(self) -> int:
        """Board time: the current tick's."""
        return int(self.hal.now_us)

    @property
    def period_us(self) -> int:
        return int(self.hal.period_us)

    @property
    def batch_size(self) -> int:
        return int(self.c.state().batch_size)

    @property
    def boot_id(self) -> int:
        return int(self.c.state().boot_id)

    @property
    def faults(self) -> int:
        return int(self.c.state().faults)

    @property
    def inputs(self) -> int:
        return int(self.c.state().inputs)

    @property
    def session(self) -> bool:
        return bool(self.c.state().session)

    @property
    def lease_ms(self) -> int:
        return int(self.c.state().lease_ms)

    @property
    def zvel_seq(self) -> int:
        return int(self.c.state().zvel_seq)

    @property
    def zvel_applied(self) -> bool:
        return bool(self.c.state().zvel_applied)

    @property
    def rx_duplicates(self) -> int:
        return int(self.c.state().rx_duplicates)

    @property
    def crc_errors(self) -> int:
        return int(self.c.state().crc_errors)

    @property
    def torch_on(self) -> bool:
        return bool(self.hal.torch)

    @property
    def ohmic_sense(self) -> bool:
        return bool(self.hal.ohmic)

    # --- receive ---------------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        """Host bytes arriving now, handled frame by frame."""
        parts = (self._pending + data).split(b"\x00")
        self._pending = parts.pop()
        for enc in parts:
            self._host_frame(enc)
        if len(self._pending) > 2 * fp.MAX_ENCODED_FRAME:
            self._feed(self._pending)  # no delimiter in sight: the board's codec discards
            self._pending = b""
        self._flush()

    def _host_frame(self, enc: bytes) -> None:
        frame = enc + b"\x00"
        if not enc or self._held:
            self._feed_or_hold(frame)
            return
        msg: fp.Message | None = None
        try:
            msg = fp.decode_frame(enc)
        except (fp.UnknownMessageType, fp.BadLength):
            self.last_host_frame_us = self.t_us  # a valid CRC: the host is alive
        except fp.DecodeError:
            pass
        if msg is None:
            self._feed(frame)
            return
        self.last_host_frame_us = self.t_us
        as_sent = msg
        if (
            isinstance(msg, fp.FaultReset)
            and msg.mask & (1 << FaultCode.BREAKAWAY)
            and self.c.state().inputs & InputMask.BREAKAWAY
            and not self.plant.reset_breakaway()
        ):
            # The operator re-seated the torch, then reset: the board sees the switch
            # released at its next tick, and the reset after it.
            self._held.append(self._incoming(msg, frame))
            return
        before = self.c.state()
        session, duplicates = before.session, before.rx_duplicates
        self._feed(self._incoming(msg, frame))
        if isinstance(as_sent, fp.ZVelocity) and self.on_zvelocity is not None:
            self.on_zvelocity(as_sent)
        executed = session and not isinstance(as_sent, _NOT_COMMANDS)
        if executed and self.c.state().rx_duplicates == duplicates:  # not a duplicate
            self.executed[type(as_sent).__name__] += 1
            if isinstance(as_sent, fp.Torch) and as_sent.on and self.hal.torch:
                self.torch_on_commands += 1

    def _incoming(self, msg: fp.Message, frame: bytes) -> bytes:
        """The frame the board gets for a host message (the announced protocol version)."""
        ident = self.identity
        if (isinstance(msg, fp.ZProbeAway) and ident.proto_minor < PROBE_AWAY_MINOR) or (
            isinstance(msg, fp.ZHome) and ident.proto_minor < HOMING_MINOR
        ):  # a type that version does not know (PROTOCOL.md §7: NAK UNKNOWN_TYPE)
            return fp.encode_frame(bytes((UNKNOWN_TYPE,)) + fp.encode_message(msg)[1:-2])
        if isinstance(msg, fp.Hello) and ident.proto_major != fp.PROTOCOL_MAJOR:
            major = fp.PROTOCOL_MAJOR if msg.proto_major == ident.proto_major else 0xFF
            return fp.encode(msg._replace(proto_major=major))
        return frame

    def _feed_or_hold(self, frame: bytes) -> None:
        if self._held:
            self._held.append(frame)
        else:
            self._feed(frame)

    def _feed(self, frame: bytes) -> None:
        self.c.receive(frame)
        self._apply_outputs()

    # --- send ------------------------------------------------------------------------------

    def _flush(self) -> None:
        data = self.c.take_tx()
        if not data:
            return
        frames = data.split(b"\x00")
        frames.pop()  # the board writes whole frames: nothing after the last delimiter
        for enc in frames:
            out = self._outgoing(enc + b"\x00")
            if out:
                self.write(out)

    def _outgoing(self, frame: bytes) -> bytes | None:
        """What the link carries for one frame the board sent (None: nothing)."""
        kind = frame_type(frame)
        if self.t_us < self.stall_replies_until_us and kind not in _ALWAYS_SENT:
            return None
        if kind == MsgType.HELLO_INFO and self._announces_other_version():
            info = fp.decode_frame(frame)
            assert isinstance(info, fp.HelloInfo)
            ident = self.identity
            capabilities = info.capabilities
            if ident.proto_minor < HOMING_MINOR:  # a capability bit that version lacks
                capabilities &= ~int(fp.Capability.HOMING)
            return fp.encode(info._replace(proto_major=ident.proto_major,
                                           proto_minor=ident.proto_minor,
                                           capabilities=capabilities))  # fmt: skip
        if kind == MsgType.SAMPLES and self.on_samples is not None:
            samples = fp.decode_frame(frame)
            assert isinstance(samples, fp.Samples)
            self.on_samples(samples)
        return frame

    def _announces_other_version(self) -> bool:
        ident = self.identity
        return (ident.proto_major, ident.proto_minor) != (fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR)

    # --- one sample period -----------------------------------------------------------------

    def tick(self) -> None:
        c = self.c
        hal = self.hal
        plant = self.plant
        c.advance()
        plant.zaxis.drive(self._boot_mm + hal.steps * self._step_mm, hal.rate * self._step_mm)
        period_us = hal.period_us
        plant.step(period_us / 1e6)
        hal.inputs = self._input_bits()
        raw = round(plant.measured_voltage_v() * ADC_COUNTS_PER_VOLT)
        hal.arc_raw = min(max(raw, 0), 0xFFFF)
        hal.xy_speed_dmm_s = min(max(round(plant.xy_speed_mm_s * 10.0), 0), 0xFFFE)
        self._before_tick()
        c.tick()
        self._apply_outputs()
        if self._held:
            held, self._held = self._held, []
            for frame in held:
                self._feed(frame)
        self._audit_lease(period_us)
        self._flush()

    def _before_tick(self) -> None:
        """What a misbehaving board's link does before each tick (mock_device.variants)."""

    def _input_bits(self) -> int:
        """The plant's inputs at the board's pins. Its Z limit switches sit on the soft
        limits, where the board's own soft limits already stop Z (a table's switches sit
        beyond them): only a switch held by hand (force_input) reaches the board, and the
        home switch above the soft limits (Z_LIMIT_MAX), which homing seeks."""
        bits = self.plant.input_bits()
        forced_on, forced_off = self.plant.forced_inputs
        bits &= ~(_Z_LIMIT_BITS & ~forced_on)
        if self.plant.zaxis.home_switch and not forced_off & _Z_LIMIT_MAX:
            bits |= _Z_LIMIT_MAX
        return bits

    def _apply_outputs(self) -> None:
        hal = self.hal
        plant = self.plant
        torch = bool(hal.torch)
        if torch != self._torch:
            self._torch = torch
            plant.set_torch(torch)
        ohmic = bool(hal.ohmic)
        if ohmic != self._ohmic:
            self._ohmic = ohmic
            plant.set_ohmic_sense(ohmic)
        current = int(hal.current_da)
        if current != self._current_da:
            self._current_da = current
            plant.set_current_a(current / 10.0)

    def _audit_lease(self, period_us: int) -> None:
        """The torch must be off one sample period after the lease ran out, counted from
        the last valid host frame at the link, whatever the board's lease logic does."""
        if not self._torch and not self.lease_violation_counted:
            return
        state = self.c.state()
        grace_us = state.lease_ms * 1000 + period_us
        late = state.session and self.t_us - self.last_host_frame_us > grace_us
        if not late:
            self.lease_violation_counted = False
        elif self._torch:
            self.unsafe_torch_us += period_us
            if not self.lease_violation_counted:
                self.lease_violation_counted = True  # once per episode
                self.plant.count_violation("torch_on_after_lease_expiry")
