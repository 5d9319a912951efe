"""Z_PROBE_AWAY on the mock board (protocol 1.2, PROTOCOL.md §6.1): up until every sensor
of the set is released, stopped by the board on the release; as the reference firmware."""

from __future__ import annotations

import pytest

import firmware_protocol as fp
from firmware_protocol import FaultCode, InputMask, NakCode
from mock_device.board_logic import BoardIdentity
from mock_device.sim import SimulatedBoard
from mock_device.sim_host import SimHost


def _result(host: SimHost, seq: int, ms: int = 20_000) -> fp.ProbeResult:
    for _ in range(ms // 50):
        host.keep_alive_for(50)
        done = [m for m in host.of_type(fp.ProbeResult) if m.seq == seq]
        if done:
            return done[0]
    raise AssertionError(f"no PROBE_RESULT for seq {seq} within {ms} ms")


def test_probe_away_lifts_off_the_float_switch_and_reports_the_release() -> None:
    """Down to the float switch, then up at a slow feed: RELEASED by FLOAT where the switch
    opened (near where it closed), Z at rest just above it, nothing latched."""
    host = SimHost(SimulatedBoard("flat_clean", seed=5))
    host.open_session()
    plant = host.board.plant
    travel_um = round((plant.zaxis.position_mm - plant.surface_z_mm + 10) * 1000)
    down = host.request(fp.ZProbe(0, 5_000, travel_um, InputMask.FLOAT))
    touched = _result(host, down.seq)
    assert touched.result == fp.ProbeOutcome.CONTACT
    assert host.board.firmware.inputs & InputMask.FLOAT
    ack = host.request(fp.ZProbeAway(0, 1_000, 5_000, InputMask.FLOAT))
    assert isinstance(ack, fp.Ack)
    result = _result(host, ack.seq)
    assert result.result == fp.ProbeOutcome.RELEASED
    assert result.sensor == InputMask.FLOAT
    assert touched.stop_z_um < result.contact_z_um <= touched.contact_z_um + 300
    assert result.contact_z_um <= result.stop_z_um <= result.contact_z_um + 50
    assert plant.zaxis.is_idle
    assert plant.zaxis.position_mm * 1000 == pytest.approx(result.stop_z_um, abs=1)
    assert not host.board.firmware.inputs & InputMask.FLOAT
    assert host.board.firmware.faults == 0


def test_probe_away_ends_no_release_at_its_travel_and_limit_at_z_max() -> None:
    """A switch that never opens: NO_RELEASE after max travel (the sensor still active),
    LIMIT at the soft limit; released at once (zero travel) when nothing is active."""
    host = SimHost(SimulatedBoard("flat_clean", seed=5))
    info = host.open_session()
    z = host.board.plant.zaxis
    host.board.plant.force_input(InputMask.FLOAT, True)
    host.pump(2)
    start_um = round(z.position_mm * 1000)
    ack = host.request(fp.ZProbeAway(0, 10_000, 2_000, InputMask.FLOAT))
    result = _result(host, ack.seq)
    assert result.result == fp.ProbeOutcome.NO_RELEASE
    assert result.sensor == InputMask.FLOAT
    assert abs(result.stop_z_um - (start_um + 2_000)) < 200
    ack = host.request(fp.ZProbeAway(0, 60_000, 500_000, InputMask.FLOAT))
    result = _result(host, ack.seq)
    assert result.result == fp.ProbeOutcome.LIMIT
    assert abs(result.stop_z_um - info.z_max_um) < 200
    assert host.board.firmware.faults == 0
    host.board.plant.force_input(InputMask.FLOAT, False)
    host.pump(2)
    at_um = round(z.position_mm * 1000)
    ack = host.request(fp.ZProbeAway(0, 10_000, 2_000, InputMask.FLOAT | InputMask.OHMIC))
    result = _result(host, ack.seq)
    assert (result.result, result.sensor) == (fp.ProbeOutcome.RELEASED, 0)
    assert result.contact_z_um == result.stop_z_um == at_um


def test_probe_away_has_the_probes_refusals_and_is_aborted_by_a_fault() -> None:
    """Zero feed, zero travel, no contact sensor: OUT_OF_RANGE with the field; a latched
    fault refuses it; an E-stop while it runs ends it ABORTED."""
    host = SimHost(SimulatedBoard("flat_clean", seed=5))
    host.open_session()
    plant = host.board.plant
    for command, detail in (
        (fp.ZProbeAway(0, 0, 1_000, InputMask.FLOAT), 0),
        (fp.ZProbeAway(0, 1_000, 0, InputMask.FLOAT), 1),
        (fp.ZProbeAway(0, 1_000, 1_000, InputMask.ARC_OK), 2),
    ):
        nak = host.request(command)
        assert isinstance(nak, fp.Nak)
        assert (nak.code, nak.detail) == (NakCode.OUT_OF_RANGE, detail)
    plant.force_input(InputMask.FLOAT, True)
    host.pump(2)
    ack = host.request(fp.ZProbeAway(0, 5_000, 20_000, InputMask.FLOAT))
    host.keep_alive_for(100)
    plant.force_input(InputMask.ESTOP, True)
    result = _result(host, ack.seq)
    assert result.result == fp.ProbeOutcome.ABORTED
    nak = host.request(fp.ZProbeAway(0, 5_000, 20_000, InputMask.FLOAT))
    assert isinstance(nak, fp.Nak)
    assert (nak.code, nak.detail) == (NakCode.FAULT_LATCHED, FaultCode.ESTOP)


def test_a_board_of_protocol_1_1_refuses_probe_away_with_unknown_type() -> None:
    """A board announcing 1.1 answers Z_PROBE_AWAY as one that never heard of it: NAK
    UNKNOWN_TYPE, Z still, so a 1.2 host can tell."""
    board = SimulatedBoard("flat_clean", seed=5, identity=BoardIdentity(proto_minor=1))
    host = SimHost(board)
    assert host.open_session().proto_minor == 1
    board.plant.force_input(InputMask.FLOAT, True)
    host.pump(2)
    before = board.plant.zaxis.position_mm
    nak = host.request(fp.ZProbeAway(0, 5_000, 20_000, InputMask.FLOAT))
    assert isinstance(nak, fp.Nak)
    assert nak.code == NakCode.UNKNOWN_TYPE
    host.pump(100)
    assert board.plant.zaxis.position_mm == before
    assert board.plant.zaxis.is_idle


def test_the_lease_latches_while_a_probe_away_runs() -> None:
    """A probe away is Z in use: a silent host latches LEASE_EXPIRED and it ends ABORTED."""
    host = SimHost(SimulatedBoard("flat_clean", seed=5))
    host.open_session(lease_ms=100)
    host.board.plant.force_input(InputMask.FLOAT, True)
    host.pump(2)
    host.request(fp.ZProbeAway(0, 500, 30_000, InputMask.FLOAT))
    mark = len(host.received)
    host.pump(101)
    faults = [m for m in host.received[mark:] if isinstance(m, fp.Fault)]
    assert faults
    assert faults[0].detail == fp.LEASE_DETAIL_LATCHED
    (probe,) = [m for m in host.received[mark:] if isinstance(m, fp.ProbeResult)]
    assert probe.result == fp.ProbeOutcome.ABORTED
