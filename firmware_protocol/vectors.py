"""Golden vectors: ``vectors/frames.json`` pins the bytes of every message type.

``python -m firmware_protocol.vectors --write`` regenerates the file; the test suite checks
that the codec still produces exactly the stored bytes, so a layout change cannot slip in
unnoticed, and runs the C reference codec against the same file.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from . import messages as m
from .codec import encode, encode_frame, encode_message
from .constants import (
    CRC_CHECK_VALUE,
    LEASE_DETAIL_IDLE,
    LEASE_DETAIL_LATCHED,
    PROTOCOL_MAJOR,
    PROTOCOL_MINOR,
    XY_SPEED_UNKNOWN,
    Capability,
    FaultCode,
    FilterKind,
    HomeOutcome,
    InputBit,
    InputMask,
    MotionResult,
    NakCode,
    ProbeOutcome,
    QueryWhat,
    ResetReason,
)

__all__ = ["VECTORS_PATH", "corrupt_cases", "load", "message_cases", "render"]

VECTORS_PATH = Path(__file__).with_name("vectors") / "frames.json"

_BOOT_ID = 0x5EED1234
_PLATE = InputMask.OHMIC


def message_cases() -> list[tuple[str, m.Message]]:
    """One or more examples per message type, including edge values."""
    return [
        ("hello", m.Hello(1, PROTOCOL_MAJOR, PROTOCOL_MINOR, 0xA1B2C3D4)),
        ("heartbeat", m.Heartbeat(2)),
        ("heartbeat_seq0_all_zero", m.Heartbeat(0)),
        ("set_lease_250ms", m.SetLease(3, 250)),
        ("torch_on", m.Torch(4, True)),
        ("torch_off", m.Torch(5, False)),
        ("ohmic_sense_on", m.OhmicSense(6, True)),
        ("z_move_up_to_25mm", m.ZMove(7, 25_000, 50_000)),
        ("z_move_negative_target", m.ZMove(8, -1_500, 1_000)),
        ("z_probe_float_or_ohmic", m.ZProbe(9, 5_000, 30_000, _PLATE | InputMask.FLOAT)),
        ("z_velocity_down", m.ZVelocity(0, 1234, -2_500, 20)),
        ("z_velocity_stream_wrap", m.ZVelocity(0, 0xFFFF, 60_000, 200)),
        ("z_stop", m.ZStop(10)),
        ("set_current_45a", m.SetCurrent(11, 450)),
        (
            "configure_thcad",
            m.Configure(12, 1000, 5, FilterKind.MEDIAN3, 0, 0, 121_000, 2.0**-12),
        ),
        ("configure_iir", m.Configure(13, 2000, 10, FilterKind.LOW_PASS, 200, 50, -12, 0.25)),
        ("query_status", m.Query(14, QueryWhat.STATUS)),
        ("query_probe_result", m.Query(15, QueryWhat.PROBE_RESULT)),
        ("clock_query", m.ClockQuery(16)),
        ("fault_reset_all", m.FaultReset(17, 0xFFFF)),
        # 1.2: lift off the float switch, 0.5 mm at most, at 20 mm/min (G38.4 Z0.5 F20).
        ("z_probe_away_float", m.ZProbeAway(18, 333, 500, InputMask.FLOAT)),
        # 1.3: home Z at 20 mm/s, re-seek at 2 mm/s, back off 2 mm, 150 mm at most, in 15 s.
        ("z_home", m.ZHome(19, 20_000, 2_000, 2_000, 150_000, 15_000)),
        ("ack", m.Ack(4, _BOOT_ID)),
        ("nak_fault_latched", m.Nak(4, _BOOT_ID, NakCode.FAULT_LATCHED, FaultCode.LEASE_EXPIRED)),
        ("nak_out_of_range", m.Nak(3, _BOOT_ID, NakCode.OUT_OF_RANGE, 0)),
        (
            "hello_info",
            m.HelloInfo(
                1,
                PROTOCOL_MAJOR,
                PROTOCOL_MINOR,
                0,
                3,
                1,
                ResetReason.POWER_ON,
                _BOOT_ID,
                "DTHC-000042",
                1000,
                5,
                int(Capability(0x3FF)),
                0,
                100_000,
                256,
                250,
            ),
        ),
        (
            "hello_info_full_serial",
            m.HelloInfo(
                0,
                PROTOCOL_MAJOR,
                PROTOCOL_MINOR,
                255,
                255,
                255,
                ResetReason.WATCHDOG,
                0xFFFFFFFF,
                "ABCDEFGHIJKLMNOP",
                20000,
                100,
                0,
                -50_000,
                150_000,
                256,
                2000,
            ),
        ),
        (
            "samples_batch5",
            m.Samples(
                0,
                42,
                1_000_000,
                1000,
                21_500,
                InputMask.ARC_OK,
                1233,
                XY_SPEED_UNKNOWN,
                0x01,
                (12_500, 12_510, 12_490, 12_500, 12_505),
            ),
        ),
        (
            "samples_with_xy_speed",
            m.Samples(
                0,
                43,
                1_005_000,
                1000,
                21_480,
                1,
                1234,
                833,
                0x01,
                (12_480, 12_470, 12_510, 12_530, 12_490),
            ),
        ),
        ("samples_empty_batch", m.Samples(0, 0, 0, 1000, 0, 0, 0, XY_SPEED_UNKNOWN, 0, ())),
        (
            "samples_max_batch_zeros",
            m.Samples(
                0,
                0xFFFF,
                0xFFFFFFFF,
                50,
                -2_000,
                0x1FF,
                0,
                0,
                0x3F,
                tuple((i * 257) & 0xFFFF for i in range(100)),
            ),
        ),
        ("event_arc_ok_on", m.Event(0, 7, 2_000_123, InputBit.ARC_OK, 1, 1, 23_300)),
        ("event_ohmic_off", m.Event(0, 8, 2_000_500, InputBit.OHMIC, 0, 1, 23_300)),
        (
            "fault_lease_expired",
            m.Fault(
                0,
                9,
                3_000_000,
                FaultCode.LEASE_EXPIRED,
                LEASE_DETAIL_LATCHED,
                1 << FaultCode.LEASE_EXPIRED,
                21_500,
            ),
        ),
        (
            # The lease ran out with the board at rest: reported, nothing latched (faults 0).
            "fault_lease_idle_lapse",
            m.Fault(0, 10, 4_000_000, FaultCode.LEASE_EXPIRED, LEASE_DETAIL_IDLE, 0, 60_000),
        ),
        ("motion_done_reached", m.MotionDone(7, MotionResult.REACHED, 25_000, 4_000_000)),
        (
            "probe_result_float",
            m.ProbeResult(9, ProbeOutcome.CONTACT, InputMask.FLOAT, 18_500, 18_430, 5_000_000),
        ),
        (
            "probe_result_released",
            m.ProbeResult(18, ProbeOutcome.RELEASED, InputMask.FLOAT, 18_620, 18_624, 5_500_000),
        ),
        (
            "status",
            m.Status(14, _BOOT_ID, 6_000_000, 0, 1, 0x21, 250, 9, 42, 1234, 21_500, 450, 1, 2, 3),
        ),
        ("clock", m.Clock(16, 0x0123456789ABCDEF)),
        ("home_result_homed", m.HomeResult(19, HomeOutcome.HOMED, 99_000, -21_337, 7_000_000)),
    ]


def corrupt_cases() -> list[tuple[str, bytes, dict[str, Any]]]:
    """Byte streams with damage, and what a correct streaming decoder reports for each."""
    ack = encode(m.Ack(4, _BOOT_ID))
    samples = encode(dict(message_cases())["samples_with_xy_speed"])
    torch_body = encode_message(m.Torch(4, True))
    bad_crc = bytearray(encode_frame(torch_body))
    bad_crc[3] ^= 0x02  # payload byte 01 -> 03: no new zero, CRC fails
    wrong_len = encode_frame(torch_body + b"\x01")  # TORCH with a 2-byte payload
    unknown = encode_frame(b"\x7f\x01")
    bad_cobs = b"\x09\x01\x02\x00"  # code byte promises 8 more bytes, only 2 follow
    return [
        ("crc_error_then_valid", bytes(bad_crc) + ack, {"messages": ["ack"], "crc_errors": 1}),
        ("invalid_cobs_then_valid", bad_cobs + ack, {"messages": ["ack"], "framing_errors": 1}),
        ("unknown_type_then_valid", unknown + ack, {"messages": ["ack"], "unknown_type": 1}),
        ("bad_length_then_valid", wrong_len + ack, {"messages": ["ack"], "length_errors": 1}),
        (
            "garbage_then_valid",
            b"\xde\xad\xbe\xef\x00" + samples,
            {"messages": ["samples_with_xy_speed"], "framing_errors": 1},
        ),
        ("idle_delimiters", b"\x00\x00" + ack + b"\x00\x00", {"messages": ["ack"]}),
        (
            "overlong_run_then_valid",
            b"\x01" * 300 + b"\x00" + ack,
            {"messages": ["ack"], "framing_errors": 1},
        ),
        (
            "lost_delimiter_merges_two",
            ack[:-1] + ack,
            {"messages": [], "crc_errors": 1},
        ),
        ("too_short", encode_frame(b"") + ack, {"messages": ["ack"], "framing_errors": 1}),
    ]


def render() -> dict[str, Any]:
    frames = []
    for name, msg in message_cases():
        fields = msg._asdict()
        if isinstance(msg, m.Samples):
            fields["samples_cv"] = list(msg.samples_cv)
        frames.append(
            {
                "name": name,
                "message": type(msg).__name__,
                "fields": fields,
                "body_hex": encode_message(msg).hex(),
                "frame_hex": encode(msg).hex(),
            }
        )
    corrupt = []
    for name, stream, expect in corrupt_cases():
        corrupt.append({"name": name, "stream_hex": stream.hex(), "expect": expect})
    return {
        "protocol": f"{PROTOCOL_MAJOR}.{PROTOCOL_MINOR}",
        "crc": {
            "name": "CRC-16/CCITT-FALSE",
            "input_hex": b"123456789".hex(),
            "check": f"0x{CRC_CHECK_VALUE:04X}",
        },
        "frames": frames,
        "corrupt": corrupt,
    }


def load() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(VECTORS_PATH.read_text())
    return data


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m firmware_protocol.vectors")
    parser.add_argument("--write", action="store_true", help=f"rewrite {VECTORS_PATH.name}")
    args = parser.parse_args(argv)
    text = json.dumps(render(), indent=1) + "\n"
    if args.write:
        VECTORS_PATH.write_text(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
