"""Numbers and code tables of the DTHC wire protocol (see PROTOCOL.md).

Every table here is normative: the C reference codec in ``c/dthc_protocol.h`` mirrors it,
and the golden vectors pin its values.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag
from typing import Final

__all__ = [
    "CRC_CHECK_VALUE",
    "CRC_INIT",
    "DEFAULT_BATCH_SIZE",
    "DEFAULT_LEASE_MS",
    "DEFAULT_SAMPLE_RATE_HZ",
    "DEFAULT_ZVEL_EXPIRY_MS",
    "DELIMITER",
    "HOST_WINDOW",
    "LEASE_DETAIL_IDLE",
    "LEASE_DETAIL_LATCHED",
    "LEASE_MAX_MS",
    "LEASE_MIN_MS",
    "MAX_BATCH_SIZE",
    "MAX_ENCODED_FRAME",
    "MAX_FRAME",
    "MAX_PAYLOAD",
    "PROTOCOL_MAJOR",
    "PROTOCOL_MINOR",
    "XY_SPEED_UNKNOWN",
    "ZVEL_EXPIRY_MAX_MS",
    "Capability",
    "FaultCode",
    "FilterKind",
    "InputBit",
    "InputMask",
    "MotionResult",
    "MsgType",
    "NakCode",
    "ProbeOutcome",
    "QueryWhat",
    "ResetReason",
    "StatusBit",
]

PROTOCOL_MAJOR: Final = 1
PROTOCOL_MINOR: Final = 2  # 1.1: the idle lease lapse (§4); 1.2: Z_PROBE_AWAY (§6.1)

DELIMITER: Final = 0x00
# Decoded frame = type(1) seq(1) payload(0..MAX_PAYLOAD) crc(2).
MAX_FRAME: Final = 256
MAX_PAYLOAD: Final = MAX_FRAME - 4
# COBS adds one code byte per started 254-byte block: 256 bytes need 2.
MAX_ENCODED_FRAME: Final = MAX_FRAME + 2

# CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0x0000.
CRC_INIT: Final = 0xFFFF
CRC_CHECK_VALUE: Final = 0x29B1  # CRC of b"123456789"

DEFAULT_SAMPLE_RATE_HZ: Final = 1000
DEFAULT_BATCH_SIZE: Final = 5
MAX_BATCH_SIZE: Final = 100
DEFAULT_LEASE_MS: Final = 250
LEASE_MIN_MS: Final = 20
LEASE_MAX_MS: Final = 2000
# FAULT(LEASE_EXPIRED).detail (PROTOCOL.md §4-§5): the lease ran out with the torch, ohmic
# sensing or Z in use, the fault latched (until FAULT_RESET); or it ran out with the board
# at rest: reported once per lapse, nothing latched, the next valid host frame renews it.
LEASE_DETAIL_LATCHED: Final = 0
LEASE_DETAIL_IDLE: Final = 1
DEFAULT_ZVEL_EXPIRY_MS: Final = 20
ZVEL_EXPIRY_MAX_MS: Final = 200
# The host keeps at most this many sequenced commands unacknowledged; the board remembers
# the outcome of at least this many recent sequence numbers to recognise duplicates.
HOST_WINDOW: Final = 8
# SAMPLES.xy_speed_dmm_s when the board does not measure XY speed.
XY_SPEED_UNKNOWN: Final = 0xFFFF


class MsgType(IntEnum):
    """First byte of every decoded frame. Host to board below 0x80, board to host above."""

    HELLO = 0x01
    HEARTBEAT = 0x02
    SET_LEASE = 0x03
    TORCH = 0x04
    OHMIC_SENSE = 0x05
    Z_MOVE = 0x06
    Z_PROBE = 0x07
    Z_VELOCITY = 0x08
    Z_STOP = 0x09
    SET_CURRENT = 0x0A
    CONFIGURE = 0x0B
    QUERY = 0x0C
    CLOCK_QUERY = 0x0D
    FAULT_RESET = 0x0E
    Z_PROBE_AWAY = 0x0F  # since 1.2

    ACK = 0x80
    NAK = 0x81
    HELLO_INFO = 0x82
    SAMPLES = 0x83
    EVENT = 0x84
    FAULT = 0x85
    MOTION_DONE = 0x86
    PROBE_RESULT = 0x87
    STATUS = 0x88
    CLOCK = 0x89


class InputBit(IntEnum):
    """Bit positions of the 16-bit input snapshot (raw levels, 1 = active)."""

    ARC_OK = 0
    OHMIC = 1
    FLOAT = 2
    BREAKAWAY = 3
    THC_UP = 4
    THC_DOWN = 5
    ESTOP = 6
    Z_LIMIT_MIN = 7
    Z_LIMIT_MAX = 8


class InputMask(IntFlag):
    """The same inputs as masks over the snapshot (``1 << InputBit``), and as sensor sets
    (ZProbe's and ZProbeAway's ``sensors``)."""

    ARC_OK = 1 << InputBit.ARC_OK
    OHMIC = 1 << InputBit.OHMIC
    FLOAT = 1 << InputBit.FLOAT
    BREAKAWAY = 1 << InputBit.BREAKAWAY
    THC_UP = 1 << InputBit.THC_UP
    THC_DOWN = 1 << InputBit.THC_DOWN
    ESTOP = 1 << InputBit.ESTOP
    Z_LIMIT_MIN = 1 << InputBit.Z_LIMIT_MIN
    Z_LIMIT_MAX = 1 << InputBit.Z_LIMIT_MAX


class StatusBit(IntFlag):
    """The 8-bit board status carried in SAMPLES and STATUS."""

    TORCH_ON = 1 << 0
    OHMIC_SENSE = 1 << 1
    FAULT_LATCHED = 1 << 2
    Z_BUSY = 1 << 3
    SAMPLE_OVERFLOW = 1 << 4
    SESSION = 1 << 5


class Capability(IntFlag):
    """HELLO_INFO capability bits."""

    XY_SPEED = 1 << 0
    OHMIC = 1 << 1
    FLOAT = 1 << 2
    BREAKAWAY = 1 << 3
    THC_UPDOWN = 1 << 4
    CURRENT_OUT = 1 << 5
    ESTOP = 1 << 6
    Z_LIMITS = 1 << 7
    FILTERS = 1 << 8


class FaultCode(IntEnum):
    """Latched board faults. Bit ``1 << code`` in the 16-bit fault set."""

    LEASE_EXPIRED = 0
    Z_LIMIT = 1
    BREAKAWAY = 2
    ESTOP = 3
    ARC_LOST = 4
    INTERNAL = 5


class NakCode(IntEnum):
    UNKNOWN_TYPE = 1
    BAD_LENGTH = 2
    OUT_OF_RANGE = 3  # detail: index of the offending payload field
    FAULT_LATCHED = 4  # detail: lowest latched fault code
    BUSY = 5
    NO_SESSION = 6
    UNSUPPORTED = 7  # detail: capability bit index
    VERSION = 8  # detail: the board's protocol major
    FAULT_ACTIVE = 9  # detail: the fault whose cause is still present


class ResetReason(IntEnum):
    POWER_ON = 0
    WATCHDOG = 1
    SOFTWARE = 2
    BROWNOUT = 3
    EXTERNAL = 4
    UNKNOWN = 5


class ProbeOutcome(IntEnum):
    """PROBE_RESULT.result. CONTACT/NO_CONTACT end a Z_PROBE (down, until a sensor is
    active), RELEASED/NO_RELEASE a Z_PROBE_AWAY (up, until every sensor is inactive; 1.2)."""

    CONTACT = 0
    NO_CONTACT = 1  # max travel reached
    ABORTED = 2  # Z_STOP, fault or lease expiry
    LIMIT = 3  # Z soft limit reached before contact (release) or max travel
    RELEASED = 4  # Z_PROBE_AWAY: every sensor of the set inactive
    NO_RELEASE = 5  # Z_PROBE_AWAY: max travel reached with a sensor still active


class MotionResult(IntEnum):
    REACHED = 0
    STOPPED = 1
    LIMIT = 2
    FAULT = 3
    SUPERSEDED = 4


class FilterKind(IntEnum):
    NONE = 0
    MOVING_AVERAGE = 1  # param: window in samples, 1..32
    LOW_PASS = 2  # param: first-order cut-off in Hz, 1..500
    MEDIAN3 = 3  # param: ignored; removes one- and two-sample spikes


class QueryWhat(IntEnum):
    STATUS = 0
    PROBE_RESULT = 1
    HELLO_INFO = 2
    MOTION_DONE = 3
