"""Typed, immutable messages of the DTHC wire protocol.

Each message is a ``NamedTuple`` whose first field is ``seq``, the frame header's sequence
number: a host command's own sequence number (1..255; 0 = unsequenced), and for a board
reply the sequence number of the command it answers (0 when unsolicited). The remaining
fields follow the payload layout in PROTOCOL.md, in wire order, with units in their names.
NamedTuples decode fast (one ``struct`` unpack straight into the tuple) and are immutable.
"""

from __future__ import annotations

from typing import NamedTuple

from .constants import XY_SPEED_UNKNOWN

__all__ = [
    "BOARD_MESSAGES",
    "HOST_MESSAGES",
    "Ack",
    "BoardMessage",
    "Clock",
    "ClockQuery",
    "Configure",
    "Event",
    "Fault",
    "FaultReset",
    "Heartbeat",
    "Hello",
    "HelloInfo",
    "HostMessage",
    "Message",
    "MotionDone",
    "Nak",
    "OhmicSense",
    "ProbeResult",
    "Query",
    "Report",
    "Samples",
    "SetCurrent",
    "SetLease",
    "Status",
    "Torch",
    "ZMove",
    "ZProbe",
    "ZProbeAway",
    "ZStop",
    "ZVelocity",
]


# --- host to board -------------------------------------------------------------------------


class Hello(NamedTuple):
    """Opens a session; the board answers HELLO_INFO and clears its duplicate memory."""

    seq: int
    proto_major: int
    proto_minor: int
    host_nonce: int


class Heartbeat(NamedTuple):
    """Renews the host lease when nothing else was sent; answered by ACK."""

    seq: int


class SetLease(NamedTuple):
    seq: int
    lease_ms: int


class Torch(NamedTuple):
    seq: int
    on: bool


class OhmicSense(NamedTuple):
    seq: int
    on: bool


class ZMove(NamedTuple):
    """Move Z to an absolute position; ACK on acceptance, MOTION_DONE when it ends."""

    seq: int
    target_um: int
    feed_um_s: int


class ZProbe(NamedTuple):
    """Move Z down until a sensor in ``sensors`` (input bits) closes; PROBE_RESULT follows."""

    seq: int
    feed_um_s: int
    max_travel_um: int
    sensors: int


class ZProbeAway(NamedTuple):
    """Move Z up until every sensor in ``sensors`` is inactive (released), for at most
    ``max_travel_um`` (LinuxCNC's G38.4/G38.5 on Z; protocol 1.2); PROBE_RESULT follows."""

    seq: int
    feed_um_s: int
    max_travel_um: int
    sensors: int


class ZVelocity(NamedTuple):
    """THC output: a setpoint stream, unacknowledged; expires unless renewed."""

    seq: int
    stream_seq: int
    velocity_um_s: int
    expiry_ms: int


class ZStop(NamedTuple):
    seq: int


class SetCurrent(NamedTuple):
    seq: int
    current_da: int  # deci-amperes


class Configure(NamedTuple):
    seq: int
    sample_rate_hz: int
    batch_size: int
    filter_kind: int
    filter_param: int
    arc_lost_ms: int  # 0: the board never latches ARC_LOST by itself
    cal_offset: int  # raw counts
    cal_scale: float  # volts per raw count (IEEE-754 binary32)


class Query(NamedTuple):
    """Ask the board to (re)send one of its reports, chosen by ``what`` (QueryWhat)."""

    seq: int
    what: int


class ClockQuery(NamedTuple):
    seq: int


class FaultReset(NamedTuple):
    seq: int
    mask: int


# --- board to host -------------------------------------------------------------------------


class Ack(NamedTuple):
    seq: int
    boot_id: int


class Nak(NamedTuple):
    seq: int
    boot_id: int
    code: int
    detail: int


class HelloInfo(NamedTuple):
    seq: int
    proto_major: int
    proto_minor: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    reset_reason: int
    boot_id: int
    serial: str  # ASCII, at most 16 characters
    sample_rate_hz: int
    batch_size: int
    capabilities: int
    z_min_um: int
    z_max_um: int
    max_frame: int
    lease_ms: int


class Samples(NamedTuple):
    """A batch of arc-voltage samples; unreliable, counted by ``stream_seq``."""

    seq: int
    stream_seq: int
    t0_us: int  # board time of samples_cv[0]
    period_us: int
    z_um: int
    inputs: int
    zvel_seq: int  # stream_seq of the last Z_VELOCITY the board applied
    xy_speed_dmm_s: int  # 0.1 mm/s; XY_SPEED_UNKNOWN if not measured
    status: int
    samples_cv: tuple[int, ...]  # centivolts, calibrated and filtered

    @property
    def has_xy_speed(self) -> bool:
        return self.xy_speed_dmm_s != XY_SPEED_UNKNOWN

    @property
    def t_last_us(self) -> int:
        """Board time of the last sample (32-bit arithmetic, as ``t0_us``)."""
        return (self.t0_us + self.period_us * (len(self.samples_cv) - 1)) & 0xFFFFFFFF


class Event(NamedTuple):
    """An input edge. ``counter`` is shared with FAULT; a gap means a lost event."""

    seq: int
    counter: int
    t_us: int
    input: int  # InputBit that changed
    level: int
    inputs: int  # snapshot after the change
    z_um: int


class Fault(NamedTuple):
    """A latched fault; repeated with the same counter every 250 ms until reset."""

    seq: int
    counter: int
    t_us: int
    code: int
    detail: int
    faults: int  # the whole latched set, bit 1 << FaultCode
    z_um: int


class MotionDone(NamedTuple):
    seq: int  # the Z_MOVE it ends
    result: int
    z_um: int
    t_us: int


class ProbeResult(NamedTuple):
    seq: int  # the Z_PROBE or Z_PROBE_AWAY it ends
    result: int
    sensor: int  # input bits that ended the probe (PROTOCOL.md §6.2)
    contact_z_um: int  # Z at contact (Z_PROBE) or release (Z_PROBE_AWAY), else stop_z_um
    stop_z_um: int
    t_us: int


class Status(NamedTuple):
    seq: int
    boot_id: int
    t_us: int
    faults: int
    inputs: int
    status: int
    lease_ms: int
    event_counter: int
    sample_seq: int
    zvel_seq: int
    z_um: int
    current_da: int
    rx_crc_errors: int
    rx_framing_errors: int
    rx_duplicates: int


class Clock(NamedTuple):
    seq: int
    t_us: int  # 64-bit board clock when the reply was built


HostMessage = (
    Hello
    | Heartbeat
    | SetLease
    | Torch
    | OhmicSense
    | ZMove
    | ZProbe
    | ZVelocity
    | ZStop
    | SetCurrent
    | Configure
    | Query
    | ClockQuery
    | FaultReset
    | ZProbeAway
)
BoardMessage = (
    Ack | Nak | HelloInfo | Samples | Event | Fault | MotionDone | ProbeResult | Status | Clock
)
Message = HostMessage | BoardMessage
# What the board reports unasked, each with the board time it happened at.
Report = Event | Fault | MotionDone | ProbeResult

HOST_MESSAGES: tuple[type[HostMessage], ...] = (
    Hello,
    Heartbeat,
    SetLease,
    Torch,
    OhmicSense,
    ZMove,
    ZProbe,
    ZVelocity,
    ZStop,
    SetCurrent,
    Configure,
    Query,
    ClockQuery,
    FaultReset,
    ZProbeAway,
)
BOARD_MESSAGES: tuple[type[BoardMessage], ...] = (
    Ack,
    Nak,
    HelloInfo,
    Samples,
    Event,
    Fault,
    MotionDone,
    ProbeResult,
    Status,
    Clock,
)
