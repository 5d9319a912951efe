"""Every message of the DTHC wire protocol, declared once: type, name, fields, wire types, units.

STYLE 21: this table is the one place a payload layout is written. From it
``python -m firmware_protocol.codegen`` generates

- ``firmware_protocol/messages.py``: the Python message classes and their ``struct`` layouts;
- the ``MsgType`` block of ``firmware_protocol/constants.py``;
- ``firmware_protocol/c/dthc_messages.h``: the C message structs, payload sizes, field
  accessors (``dthc_fault_put_code(p, v)``: the offset and the wire type come from here),
  whole-message pack/unpack and the codec's dispatch.

The generated files are committed; ``tests/firmware_protocol/test_codegen.py`` fails when
regenerating would change them, and checks PROTOCOL.md's message tables (section 6) against
this declaration.

Why a Python module and not a TOML or JSON file: it needs no parser and no new dependency,
mypy checks it, and the generator and the tests import it directly. It is plain data: no
logic beyond the frozen dataclasses that hold it.

Wire types (PROTOCOL.md section 1): ``u8 u16 u32 u64 i32 f32 bool``, ``char[16]`` (ASCII,
NUL-padded) and ``u16[N]`` (the sample tail of SAMPLES: as many as the frame holds, last).
Units are in the field names (``_um``, ``_um_s``, ``_ms``, ``_us``, ``_cv``, ``_da``,
``_dmm_s``, ``_hz``); ``unit`` says the same for a reader (and the tests check they agree).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["BOARD", "HOST", "MESSAGES", "WIRE_TYPES", "Field", "MessageDecl"]

# Wire type -> (bytes, struct code, C type). char[16] and u16[N] are handled apart.
WIRE_TYPES: dict[str, tuple[int, str, str]] = {
    "u8": (1, "B", "uint8_t"),
    "u16": (2, "H", "uint16_t"),
    "u32": (4, "I", "uint32_t"),
    "u64": (8, "Q", "uint64_t"),
    "i32": (4, "i", "int32_t"),
    "f32": (4, "f", "float"),
    "bool": (1, "?", "bool"),
    "char[16]": (16, "16s", "char"),
    "u16[N]": (2, "H", "uint16_t"),
}

HOST = "host"  # host to board
BOARD = "board"  # board to host


@dataclass(frozen=True)
class Field:
    name: str
    wire: str  # a key of WIRE_TYPES
    unit: str = ""  # the unit its name's suffix stands for; "" for counts, codes, masks
    doc: str = ""  # one line: a comment beside the field in Python and C


@dataclass(frozen=True)
class MessageDecl:
    type: int
    name: str  # PROTOCOL.md's name, the MsgType member
    cls: str  # the Python class
    direction: str  # HOST or BOARD
    fields: tuple[Field, ...] = ()
    doc: str = ""  # the Python docstring and the C comment
    reply: str = ""  # PROTOCOL.md 6.1's reply column (host messages)
    note: str = ""  # what PROTOCOL.md's table adds after the payload (a range, a code list)
    since: str = ""  # protocol version that added it, when later than 1.0
    same_as: str = ""  # C: shares this message's struct and union member
    seq_doc: str = ""  # comment beside the Python ``seq`` field
    py_extra: str = ""  # Python methods of the class, verbatim (indented by 4)


_PROBE_FIELDS = (
    Field("feed_um_s", "u32", "µm/s"),
    Field("max_travel_um", "u32", "µm"),
    Field("sensors", "u16", doc="input bit mask"),
)

MESSAGES: tuple[MessageDecl, ...] = (
    # --- host to board (PROTOCOL.md 6.1) --------------------------------------------------
    MessageDecl(
        0x01,
        "HELLO",
        "Hello",
        HOST,
        (
            Field("proto_major", "u8"),
            Field("proto_minor", "u8"),
            Field("host_nonce", "u32"),
        ),
        doc="Opens a session; the board answers HELLO_INFO and clears its duplicate memory.",
        reply="HELLO_INFO",
    ),
    MessageDecl(
        0x02,
        "HEARTBEAT",
        "Heartbeat",
        HOST,
        doc="Renews the host lease when nothing else was sent; answered by ACK.",
        reply="ACK",
    ),
    MessageDecl(
        0x03,
        "SET_LEASE",
        "SetLease",
        HOST,
        (Field("lease_ms", "u16", "ms"),),
        reply="ACK / NAK OUT_OF_RANGE",
        note="20..2000",
    ),
    MessageDecl(
        0x04, "TORCH", "Torch", HOST, (Field("on", "bool"),), reply="ACK / NAK FAULT_LATCHED"
    ),
    MessageDecl(
        0x05,
        "OHMIC_SENSE",
        "OhmicSense",
        HOST,
        (Field("on", "bool"),),
        reply="ACK / NAK UNSUPPORTED",
    ),
    MessageDecl(
        0x06,
        "Z_MOVE",
        "ZMove",
        HOST,
        (Field("target_um", "i32", "µm"), Field("feed_um_s", "u32", "µm/s")),
        doc="Move Z to an absolute position; ACK on acceptance, MOTION_DONE when it ends.",
        reply="ACK, later MOTION_DONE",
        note="feed 1..board max",
    ),
    MessageDecl(
        0x07,
        "Z_PROBE",
        "ZProbe",
        HOST,
        _PROBE_FIELDS,
        doc="Move Z down until a sensor in ``sensors`` (input bits) closes; PROBE_RESULT follows.",
        reply="ACK, later PROBE_RESULT",
    ),
    MessageDecl(
        0x08,
        "Z_VELOCITY",
        "ZVelocity",
        HOST,
        (
            Field("stream_seq", "u16"),
            Field("velocity_um_s", "i32", "µm/s", doc="positive up"),
            Field("expiry_ms", "u16", "ms"),
        ),
        doc="THC output: a setpoint stream, unacknowledged; expires unless renewed.",
        reply="none (stream)",
        note="1..200",
    ),
    MessageDecl(0x09, "Z_STOP", "ZStop", HOST, reply="ACK"),
    MessageDecl(
        0x0A,
        "SET_CURRENT",
        "SetCurrent",
        HOST,
        (Field("current_da", "u16", "dA", doc="deci-amperes"),),
        reply="ACK / NAK UNSUPPORTED",
    ),
    MessageDecl(
        0x0B,
        "CONFIGURE",
        "Configure",
        HOST,
        (
            Field("sample_rate_hz", "u16", "Hz"),
            Field("batch_size", "u8"),
            Field("filter_kind", "u8"),
            Field("filter_param", "u16"),
            Field("arc_lost_ms", "u16", "ms", doc="0: the board never latches ARC_LOST by itself"),
            Field("cal_offset", "i32", doc="raw counts"),
            Field("cal_scale", "f32", doc="volts per raw count (IEEE-754 binary32)"),
        ),
        reply="ACK / NAK OUT_OF_RANGE",
    ),
    MessageDecl(
        0x0C,
        "QUERY",
        "Query",
        HOST,
        (Field("what", "u8"),),
        doc="Ask the board to (re)send one of its reports, chosen by ``what`` (QueryWhat).",
        reply="the report asked for",
        note="0 STATUS, 1 PROBE_RESULT, 2 HELLO_INFO, 3 MOTION_DONE, 4 HOME_RESULT",
    ),
    MessageDecl(0x0D, "CLOCK_QUERY", "ClockQuery", HOST, reply="CLOCK"),
    MessageDecl(
        0x0E,
        "FAULT_RESET",
        "FaultReset",
        HOST,
        (Field("mask", "u16"),),
        reply="ACK / NAK FAULT_ACTIVE",
    ),
    MessageDecl(
        0x0F,
        "Z_PROBE_AWAY",
        "ZProbeAway",
        HOST,
        _PROBE_FIELDS,
        doc="Move Z up until every sensor in ``sensors`` is inactive (released), for at most\n"
        "``max_travel_um`` (LinuxCNC's G38.4/G38.5 on Z; protocol 1.2); PROBE_RESULT follows.",
        reply="ACK, later PROBE_RESULT",
        since="1.2",
        same_as="Z_PROBE",
    ),
    MessageDecl(
        0x10,
        "Z_HOME",
        "ZHome",
        HOST,
        (
            Field("seek_um_s", "u32", "µm/s", doc="up to the switch, fast"),
            Field("locate_um_s", "u32", "µm/s", doc="the slow re-seek that sets the position"),
            Field("backoff_um", "u32", "µm", doc="off the switch before the re-seek, and after"),
            Field("max_travel_um", "u32", "µm", doc="the seek's longest travel"),
            Field("timeout_ms", "u16", "ms"),
        ),
        doc="Home Z on its home switch (Z_LIMIT_MAX, up, away from the plate): seek, back\n"
        "off, re-seek slowly, back off (protocol 1.3); HOME_RESULT follows.",
        reply="ACK, later HOME_RESULT",
        note="every field > 0; the home position less backoff_um within the soft limits",
        since="1.3",
    ),
    # --- board to host (PROTOCOL.md 6.2) --------------------------------------------------
    MessageDecl(0x80, "ACK", "Ack", BOARD, (Field("boot_id", "u32"),)),
    MessageDecl(
        0x81,
        "NAK",
        "Nak",
        BOARD,
        (Field("boot_id", "u32"), Field("code", "u8"), Field("detail", "u8")),
    ),
    MessageDecl(
        0x82,
        "HELLO_INFO",
        "HelloInfo",
        BOARD,
        (
            Field("proto_major", "u8"),
            Field("proto_minor", "u8"),
            Field("fw_major", "u8"),
            Field("fw_minor", "u8"),
            Field("fw_patch", "u8"),
            Field("reset_reason", "u8"),
            Field("boot_id", "u32"),
            Field("serial", "char[16]", doc="ASCII, at most 16 characters"),
            Field("sample_rate_hz", "u16", "Hz"),
            Field("batch_size", "u8"),
            Field("capabilities", "u32"),
            Field("z_min_um", "i32", "µm"),
            Field("z_max_um", "i32", "µm"),
            Field("max_frame", "u16"),
            Field("lease_ms", "u16", "ms"),
        ),
    ),
    MessageDecl(
        0x83,
        "SAMPLES",
        "Samples",
        BOARD,
        (
            Field("stream_seq", "u16"),
            Field("t0_us", "u32", "µs", doc="board time of samples_cv[0]"),
            Field("period_us", "u16", "µs"),
            Field("z_um", "i32", "µm"),
            Field("inputs", "u16"),
            Field("zvel_seq", "u16", doc="stream_seq of the last Z_VELOCITY the board applied"),
            Field(
                "xy_speed_dmm_s",
                "u16",
                "0.1 mm/s",
                doc="0.1 mm/s; XY_SPEED_UNKNOWN if not measured",
            ),
            Field("status", "u8"),
            Field("samples_cv", "u16[N]", "cV", doc="centivolts, calibrated and filtered"),
        ),
        doc="A batch of arc-voltage samples; unreliable, counted by ``stream_seq``.",
        py_extra='''@property
def has_xy_speed(self) -> bool:
    return self.xy_speed_dmm_s != XY_SPEED_UNKNOWN

@property
def t_last_us(self) -> int:
    """Board time of the last sample (32-bit arithmetic, as ``t0_us``)."""
    return (self.t0_us + self.period_us * (len(self.samples_cv) - 1)) & 0xFFFFFFFF''',
    ),
    MessageDecl(
        0x84,
        "EVENT",
        "Event",
        BOARD,
        (
            Field("counter", "u32"),
            Field("t_us", "u32", "µs"),
            Field("input", "u8", doc="InputBit that changed"),
            Field("level", "u8"),
            Field("inputs", "u16", doc="snapshot after the change"),
            Field("z_um", "i32", "µm"),
        ),
        doc="An input edge. ``counter`` is shared with FAULT; a gap means a lost event.",
    ),
    MessageDecl(
        0x85,
        "FAULT",
        "Fault",
        BOARD,
        (
            Field("counter", "u32"),
            Field("t_us", "u32", "µs"),
            Field("code", "u8"),
            Field("detail", "u8"),
            Field("faults", "u16", doc="the whole latched set, bit 1 << FaultCode"),
            Field("z_um", "i32", "µm"),
        ),
        doc="A latched fault; repeated with the same counter every 250 ms until reset.",
    ),
    MessageDecl(
        0x86,
        "MOTION_DONE",
        "MotionDone",
        BOARD,
        (Field("result", "u8"), Field("z_um", "i32", "µm"), Field("t_us", "u32", "µs")),
        seq_doc="the Z_MOVE it ends",
    ),
    MessageDecl(
        0x87,
        "PROBE_RESULT",
        "ProbeResult",
        BOARD,
        (
            Field("result", "u8"),
            Field("sensor", "u16", doc="input bits that ended the probe (PROTOCOL.md §6.2)"),
            Field(
                "contact_z_um",
                "i32",
                "µm",
                doc="Z at contact (Z_PROBE) or release (Z_PROBE_AWAY), else stop_z_um",
            ),
            Field("stop_z_um", "i32", "µm"),
            Field("t_us", "u32", "µs"),
        ),
        seq_doc="the Z_PROBE or Z_PROBE_AWAY it ends",
    ),
    MessageDecl(
        0x88,
        "STATUS",
        "Status",
        BOARD,
        (
            Field("boot_id", "u32"),
            Field("t_us", "u32", "µs"),
            Field("faults", "u16"),
            Field("inputs", "u16"),
            Field("status", "u8"),
            Field("lease_ms", "u16", "ms"),
            Field("event_counter", "u32"),
            Field("sample_seq", "u16"),
            Field("zvel_seq", "u16"),
            Field("z_um", "i32", "µm"),
            Field("current_da", "u16", "dA"),
            Field("rx_crc_errors", "u16"),
            Field("rx_framing_errors", "u16"),
            Field("rx_duplicates", "u16"),
        ),
    ),
    MessageDecl(
        0x89,
        "CLOCK",
        "Clock",
        BOARD,
        (Field("t_us", "u64", "µs", doc="64-bit board clock when the reply was built"),),
    ),
    MessageDecl(
        0x8A,
        "HOME_RESULT",
        "HomeResult",
        BOARD,
        (
            Field("result", "u8"),
            Field("z_um", "i32", "µm", doc="where Z came to rest"),
            Field(
                "shift_um",
                "i32",
                "µm",
                doc="how far homing moved the board's Z (0: its count was right)",
            ),
            Field("t_us", "u32", "µs"),
        ),
        seq_doc="the Z_HOME it ends",
        since="1.3",
    ),
)
