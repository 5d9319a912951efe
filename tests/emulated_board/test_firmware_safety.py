"""DESIGN.md's safety promises of a board, measured on the firmware's own ELF on the emulated
Mega 2560 at its pins (the harness's record, simulated time): E-stop and breakaway latch the
torch relay off within one sample period and keep it off until released and reset; lease
expiry drops the relay and stops Z (and at rest is reported, not latched); a velocity
stream into the soft limit stops there and latches Z_LIMIT.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

import firmware_protocol as fp
from dthc_bridge.conformance.options import LEASE_TOLERANCE_US
from dthc_tools.emulated_board import EmulatedBoard, HarnessOptions, read_record
from dthc_tools.emulated_board.harness import RecordEvent, relay_off_after_last_host_byte_us
from firmware_protocol import FaultCode, MotionResult, NakCode

from .frame_link import FrameLink

pytestmark = pytest.mark.slow

SAMPLE_PERIOD_US = 1000
# The board's axis (firmware/avr/pins.h): soft limit, speed limits.
Z_MAX_UM = 100_000
Z_ACCEL_MM_S2 = 650.0


@pytest.fixture(scope="module")
def board(built: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[EmulatedBoard]:
    """One Mega board for the module, the torch far above the plate (a pilot only)."""
    tmp = tmp_path_factory.mktemp("safety")
    options = HarnessOptions(record=tmp / "record.csv", stderr=tmp / "host.log")
    with EmulatedBoard(tmp / "board.pty", options) as emulated:
        yield emulated


@pytest.fixture
def link(board: EmulatedBoard) -> Iterator[FrameLink]:
    """A fresh session, faults cleared, a long lease; torch off and Z stopped after."""
    link = FrameLink(board.pty)
    link.hello()
    link.expect(lambda s: fp.SetLease(s, 2000), fp.Ack)
    if faults := link.status().faults:
        link.expect(lambda s: fp.FaultReset(s, faults), fp.Ack)
    try:
        yield link
    finally:
        link.request(lambda s: fp.Torch(s, False))
        link.request(fp.ZStop)
        link.close()


def record(board: EmulatedBoard) -> list[RecordEvent]:
    assert board.options.record is not None
    return read_record(board.options.record)


def last_edge(events: list[RecordEvent], event: str, *fields: str) -> RecordEvent:
    found = [e for e in events if e.event == event and e.fields[: len(fields)] == fields]
    assert found, f"no {event} {fields} in the record"
    return found[-1]


@pytest.mark.parametrize(
    ("name", "code"), [("estop", FaultCode.ESTOP), ("breakaway", FaultCode.BREAKAWAY)]
)
def test_estop_and_breakaway_latch_the_relay_off_within_a_sample_period(
    board: EmulatedBoard, link: FrameLink, name: str, code: FaultCode
) -> None:
    """Torch on, the input goes active: the relay pin falls within one sample period (and
    the tick's run time) of the input's edge, FAULT names it, TORCH on is refused while
    latched, FAULT_RESET is refused while the input stays active and accepted once it is
    released."""
    link.expect(lambda s: fp.Torch(s, True), fp.Ack)
    mark = len(link.received)
    board.set_input(name, True)
    try:
        link.run_for(0.05)
        events = record(board)
        edge = last_edge(events, "input", name, "1")
        off = last_edge(events, "torch", "0")
        # The next tick reads the input and latches: one sample period, plus the tick's own
        # run time up to the latch (the conformance suite's allowance for it).
        assert 0 <= off.t_us - edge.t_us <= SAMPLE_PERIOD_US + LEASE_TOLERANCE_US, (edge, off)
        assert any(f.code == code for f in link.reports(fp.Fault, mark))
        nak = link.expect(lambda s: fp.Torch(s, True), fp.Nak)
        assert (nak.code, nak.detail) == (NakCode.FAULT_LATCHED, code)
        nak = link.expect(lambda s: fp.FaultReset(s, 1 << code), fp.Nak)
        assert (nak.code, nak.detail) == (NakCode.FAULT_ACTIVE, code)
        assert not board.status().torch
    finally:
        board.set_input(name, None)
    link.run_for(0.01)
    link.expect(lambda s: fp.FaultReset(s, 1 << code), fp.Ack)
    assert link.status().faults == 0
    print({name: {"relay_off_after_input_us": off.t_us - edge.t_us}})


def test_lease_expiry_drops_the_relay_and_stops_z_moving_at_its_deceleration(
    board: EmulatedBoard, link: FrameLink
) -> None:
    """Torch on and Z moving up at 10 mm/s, then the host falls silent (100 ms lease): the
    relay falls within the lease and one sample period of the last frame's arrival, the move
    ends with MOTION_DONE FAULT, and Z comes to rest within its braking distance and holds."""
    feed_mm_s = 10.0
    z0 = board.status().z_um
    link.expect(lambda s: fp.SetLease(s, 100), fp.Ack)
    link.expect(lambda s: fp.Torch(s, True), fp.Ack)
    mark = len(link.received)
    link.expect(lambda s: fp.ZMove(s, z0 + 30_000, round(feed_mm_s * 1000)), fp.Ack)
    link.run_for(0.6)  # silence: the lease runs out mid-move
    events = record(board)
    off = last_edge(events, "torch", "0")
    after_us = relay_off_after_last_host_byte_us(events)
    assert after_us is not None
    assert 100_000 <= after_us <= 100_000 + SAMPLE_PERIOD_US + LEASE_TOLERANCE_US, after_us
    done = link.reports(fp.MotionDone, mark)
    assert [d.result for d in done] == [MotionResult.FAULT]
    z = [
        (e.t_us, int(e.fields[0])) for e in events if e.event == "z" and e.t_us >= off.t_us - 10_000
    ]
    z_at_off, z_rest = z[0][1], z[-1][1]
    braking_um = 1000 * feed_mm_s**2 / (2 * Z_ACCEL_MM_S2)  # 77 um
    # The record's Z is every 10 ms: at most 10 ms of travel before the edge, plus braking.
    assert 0 <= z_rest - z_at_off <= braking_um + feed_mm_s * 10 + 10, (z_at_off, z_rest)
    resting = [t for t, um in z if um == z_rest]
    assert resting[0] - off.t_us <= 40_000  # at rest 40 ms after the relay fell at the latest
    assert z[-1][0] - resting[0] >= 300_000  # and held there
    assert z_rest - z0 < 30_000  # the move was abandoned
    print({"lease_100ms": {"relay_off_after_last_frame_us": after_us,
                           "z_after_relay_off_um": z_rest - z_at_off,
                           "at_rest_after_us": resting[0] - off.t_us}})  # fmt: skip


def test_a_velocity_stream_into_the_soft_limit_stops_there_and_latches_z_limit(
    board: EmulatedBoard, link: FrameLink
) -> None:
    """Z a millimetre below its top soft limit, a Z_VELOCITY stream upwards: Z stops at the
    limit (never past it, counted from the STEP pulses) and the board latches Z_LIMIT (max);
    FAULT_RESET clears it there, and Z can leave downwards."""
    link.expect(lambda s: fp.ZMove(s, Z_MAX_UM - 1000, 50_000), fp.Ack)
    link.run_for(1.0)
    assert board.status().z_um == Z_MAX_UM - 1000
    mark = len(link.received)
    for stream_seq in range(1, 9):
        link.send(fp.ZVelocity(0, stream_seq, 10_000, 100))
        link.run_for(0.05)
    link.run_for(0.1)
    z_max = max(int(e.fields[0]) for e in record(board) if e.event == "z")
    assert z_max <= Z_MAX_UM
    assert board.status().z_um >= Z_MAX_UM - 50  # it got there
    limit = [f for f in link.reports(fp.Fault, mark) if f.code == FaultCode.Z_LIMIT]
    assert limit
    assert limit[0].detail == 1  # the max side
    link.expect(lambda s: fp.FaultReset(s, 1 << FaultCode.Z_LIMIT), fp.Ack)
    link.expect(lambda s: fp.ZMove(s, 60_000, 50_000), fp.Ack)
    link.run_for(1.0)
    assert board.status().z_um == 60_000


def test_an_idle_lease_lapse_is_reported_once_and_the_next_frame_goes_on(
    board: EmulatedBoard, link: FrameLink
) -> None:
    """Relay and ohmic sensing off, Z still, then the host falls silent (100 ms lease):
    one FAULT LEASE_EXPIRED detail IDLE with no fault bit, not repeated in 0.6 s of
    silence; nothing latched, so the host's next frame, a TORCH on, is accepted without
    FAULT_RESET and the relay rises (PROTOCOL.md §4)."""
    link.expect(lambda s: fp.SetLease(s, 100), fp.Ack)
    mark = len(link.received)
    link.run_for(0.6)  # silence: the lease runs out with nothing lit and Z at rest
    lapses = [f for f in link.reports(fp.Fault, mark) if f.code == FaultCode.LEASE_EXPIRED]
    assert [(f.detail, f.faults) for f in lapses] == [(fp.LEASE_DETAIL_IDLE, 0)]
    assert not board.status().torch
    link.expect(lambda s: fp.Torch(s, True), fp.Ack)
    link.run_for(0.01)
    assert board.status().torch
    status = link.status()
    assert status.faults == 0
    assert status.status & fp.StatusBit.TORCH_ON
    link.expect(lambda s: fp.Torch(s, False), fp.Ack)


def test_a_burst_of_valid_frames_latches_no_internal_fault(
    board: EmulatedBoard, link: FrameLink
) -> None:
    """A host writing frames back to back: 30 Z_VELOCITY frames (420 bytes without a gap at
    1 Mbaud, Z set moving), later 100 HEARTBEATs (600 bytes): no self-check latches
    INTERNAL. Before the receive interrupt stamped delimiters without a call (which made it
    save every call-clobbered register for every byte), the 30 frames slowed the tick to
    1.8 ms and latched tick overrun; before a late tick stopped judging the ADC burst it
    had only just started, 30 heartbeats latched ADC incomplete. (A longer burst while Z
    moves and replies go out still overruns the tick: firmware/README.md, limits.)"""
    bursts = (
        b"".join(fp.encode(fp.ZVelocity(0, n, 1_000 if n % 2 else -1_000, 50))
                 for n in range(1, 31)),
        b"".join(fp.encode(fp.Heartbeat(1 + n)) for n in range(100)),
    )  # fmt: skip
    for burst in bursts:
        mark = len(link.received)
        os.write(link.fd, burst)
        link.run_for(0.5)
        internal = [f for f in link.reports(fp.Fault, mark) if f.code == FaultCode.INTERNAL]
        assert internal == [], internal
    assert link.status().faults == 0
