"""Board firmware behaviour of PROTOCOL.md, in simulated time against the plant."""

from __future__ import annotations

import itertools

import pytest

import firmware_protocol as fp
from firmware_protocol import FaultCode, InputBit, InputMask, NakCode
from mock_device.sim import SimulatedBoard
from mock_device.sim_host import SimHost


@pytest.fixture
def host() -> SimHost:
    return SimHost(SimulatedBoard("flat_clean", seed=3))


def test_handshake_reports_identity_and_opens_a_session(host: SimHost) -> None:
    """HELLO is answered by HELLO_INFO with a random boot id; commands before it are refused."""
    refused = host.request(fp.Torch(0, True))
    assert isinstance(refused, fp.Nak)
    assert refused.code == NakCode.NO_SESSION
    info = host.open_session()
    assert info.proto_major == fp.PROTOCOL_MAJOR
    assert info.serial == "MOCK-0001"
    assert info.boot_id == host.board.firmware.boot_id
    assert info.sample_rate_hz == 1000
    assert info.capabilities & fp.Capability.XY_SPEED
    assert info.z_max_um > info.z_min_um
    assert isinstance(host.request(fp.Torch(0, True)), fp.Ack)
    assert host.board.plant.torch_on


def test_other_major_version_gets_hello_info_but_no_session(host: SimHost) -> None:
    """A host of another major version learns the board's version and cannot command it."""
    info = host.request(fp.Hello(0, fp.PROTOCOL_MAJOR + 1, 0, 7))
    assert isinstance(info, fp.HelloInfo)
    assert info.proto_major == fp.PROTOCOL_MAJOR
    nak = host.request(fp.Heartbeat(0))
    assert isinstance(nak, fp.Nak)
    assert nak.code == NakCode.NO_SESSION


def test_boot_id_is_fresh_at_each_start() -> None:
    """Two boards (or one rebooted) never share a boot id; a reboot ends the session."""
    board = SimulatedBoard("flat_clean", seed=3)
    host = SimHost(board)
    first = host.open_session().boot_id
    board.reboot()
    assert board.firmware.boot_id != first
    nak = host.request(fp.Heartbeat(0))
    assert isinstance(nak, fp.Nak)
    assert nak.code == NakCode.NO_SESSION
    assert SimulatedBoard("flat_clean", seed=4).firmware.boot_id != first


def test_lease_expiry_turns_the_torch_off_within_one_sample_period(host: SimHost) -> None:
    """With no host frame for lease_ms the torch goes off at the next tick and a fault latches."""
    host.open_session(lease_ms=100)
    host.request(fp.Torch(0, True))
    last_rx_us = host.board.firmware.t_us
    torch_off_at_us = None
    for _ in range(200):
        host.pump(1)
        if not host.board.plant.torch_on:
            torch_off_at_us = host.board.firmware.t_us
            break
    assert torch_off_at_us is not None
    assert 100_000 < torch_off_at_us - last_rx_us <= 100_000 + 1_000
    faults = host.of_type(fp.Fault)
    assert faults
    assert faults[0].code == FaultCode.LEASE_EXPIRED
    assert host.board.plant.truth.violations == {} or not any(
        host.board.plant.truth.violations.values()
    )


def test_lease_fault_is_repeated_and_blocks_the_torch_until_reset(host: SimHost) -> None:
    """The lease runs out in use (ohmic sensing on): frames after expiry do not revive it,
    TORCH on is refused until FAULT_RESET."""
    host.open_session(lease_ms=50)
    host.request(fp.OhmicSense(0, True))
    host.pump(120)
    host.pump(600)
    reports = host.of_type(fp.Fault)
    assert len(reports) >= 3  # latched, then every 250 ms
    assert len({r.counter for r in reports}) == 1  # re-reports repeat the counter
    nak = host.request(fp.Torch(0, True))
    assert isinstance(nak, fp.Nak)
    assert nak.code == NakCode.FAULT_LATCHED
    assert nak.detail == FaultCode.LEASE_EXPIRED
    assert isinstance(host.request(fp.FaultReset(0, 0xFFFF)), fp.Ack)
    assert isinstance(host.request(fp.Torch(0, True)), fp.Ack)


def _lease_reports(host: SimHost, since: int) -> list[fp.Fault]:
    return [
        m
        for m in host.received[since:]
        if isinstance(m, fp.Fault) and m.code == FaultCode.LEASE_EXPIRED
    ]


def test_idle_lease_lapse_is_reported_once_and_latches_nothing(host: SimHost) -> None:
    """At rest (torch and ohmic sensing off, Z still) the lease running out is one FAULT
    LEASE_EXPIRED detail IDLE in the first tick past it, with the next event counter and no
    fault bit, not repeated while the host stays silent; the next frame renews the lease
    and TORCH on is accepted without FAULT_RESET."""
    host.open_session(lease_ms=100)
    status = host.request(fp.Query(0, fp.QueryWhat.STATUS))
    assert isinstance(status, fp.Status)
    last_rx_us = host.board.firmware.t_us
    mark = len(host.received)
    host.pump(100)
    assert not _lease_reports(host, mark)
    host.pump(1)
    (lapse,) = _lease_reports(host, mark)
    assert lapse.detail == fp.LEASE_DETAIL_IDLE
    assert lapse.faults == 0
    assert lapse.counter == status.event_counter + 1
    assert 100_000 < lapse.t_us - last_rx_us <= 101_000
    host.pump(800)  # silent on: no re-report every 250 ms
    assert len(_lease_reports(host, mark)) == 1
    after = host.request(fp.Query(0, fp.QueryWhat.STATUS))
    assert isinstance(after, fp.Status)
    assert after.faults == 0
    assert not after.status & fp.StatusBit.FAULT_LATCHED
    assert isinstance(host.request(fp.Torch(0, True)), fp.Ack)
    host.pump(90)
    assert host.board.plant.torch_on  # the renewed lease runs from that frame


def test_idle_lease_lapse_is_reported_again_after_a_renewal(host: SimHost) -> None:
    """Once per lapse: the host comes back, falls silent again, and the new lapse is
    reported again with a newer counter; a new session's HELLO also ends a lapse."""
    host.open_session(lease_ms=100)
    mark = len(host.received)
    host.pump(150)
    (first,) = _lease_reports(host, mark)
    assert isinstance(host.request(fp.Heartbeat(0)), fp.Ack)
    mark = len(host.received)
    host.pump(100)
    assert not _lease_reports(host, mark)  # renewed by the heartbeat
    host.pump(1)
    (second,) = _lease_reports(host, mark)
    assert second.detail == fp.LEASE_DETAIL_IDLE
    assert second.counter > first.counter
    host.open_session(lease_ms=100)
    mark = len(host.received)
    host.pump(101)
    assert len(_lease_reports(host, mark)) == 1
    assert host.board.firmware.faults == 0


@pytest.mark.parametrize("case", ["move", "probe", "velocity", "ohmic", "decelerating"])
def test_lease_latches_when_the_board_is_not_at_rest(host: SimHost, case: str) -> None:
    """Torch off but Z moving (a move, a probe, a velocity in force, or still decelerating
    from a stop) or ohmic sensing on: the lease latches LEASE_EXPIRED (detail LATCHED),
    ends the motion, stops Z and re-reports until FAULT_RESET."""
    host.open_session(lease_ms=100)
    lease_ms = 100
    if case == "move":
        host.request(fp.ZMove(0, 80_000, 5_000))
    elif case == "probe":
        host.request(fp.ZProbe(0, 5_000, 30_000, InputMask.FLOAT))
    elif case == "velocity":
        host.send(fp.ZVelocity(0, 1, 5_000, 200))
    elif case == "ohmic":
        host.request(fp.OhmicSense(0, True))
    else:
        host.request(fp.ZMove(0, 80_000, 60_000))
        host.pump(60)
        lease_ms = 30
        host.request(fp.SetLease(0, lease_ms))
        host.request(fp.ZStop(0))
        assert not host.board.plant.zaxis.is_idle  # still braking
    mark = len(host.received)
    host.pump(lease_ms + 1)
    (fault,) = _lease_reports(host, mark)
    assert fault.detail == fp.LEASE_DETAIL_LATCHED
    assert fault.faults & (1 << FaultCode.LEASE_EXPIRED)
    assert not host.board.firmware.ohmic_sense
    if case == "move":
        (done,) = [m for m in host.received[mark:] if isinstance(m, fp.MotionDone)]
        assert done.result == fp.MotionResult.FAULT
    if case == "probe":
        (probe,) = [m for m in host.received[mark:] if isinstance(m, fp.ProbeResult)]
        assert probe.result == fp.ProbeOutcome.ABORTED
    host.pump(300)
    assert host.board.plant.zaxis.is_idle
    assert len(_lease_reports(host, mark)) >= 2
    assert host.board.firmware.faults & (1 << FaultCode.LEASE_EXPIRED)


def test_duplicate_command_is_acknowledged_again_and_not_acted_on_twice(host: SimHost) -> None:
    """A retransmitted TORCH on arriving after TORCH off gets its ACK again; the torch stays off."""
    host.open_session()
    on_seq = host.send(fp.Torch(0, True))
    host.collect()
    host.request(fp.Torch(0, False))
    host.received.clear()
    again = host.request(fp.Torch(0, True), seq=on_seq)
    assert isinstance(again, fp.Ack)
    assert not host.board.plant.torch_on
    assert host.board.firmware.rx_duplicates == 1
    status = host.request(fp.Query(0, fp.QueryWhat.STATUS))
    assert isinstance(status, fp.Status)
    assert status.rx_duplicates == 1


@pytest.mark.parametrize(
    ("scenario", "sensor", "offset_mm"),
    [("flat_clean", InputBit.OHMIC, 0.0), ("painted_plate", InputBit.FLOAT, 1.5)],
)
def test_probe_stops_on_contact_in_the_board(scenario: str, sensor: int, offset_mm: float) -> None:
    """The probe stops itself on contact; ohmic fires at the surface, float after its travel."""
    host = SimHost(SimulatedBoard(scenario, seed=5))
    host.open_session()
    if sensor == InputBit.OHMIC:
        host.request(fp.OhmicSense(0, True))
    plant = host.board.plant
    surface_mm = plant.surface_z_mm
    start_mm = plant.zaxis.position_mm
    ack = host.request(fp.ZProbe(0, 5_000, round((start_mm - surface_mm + 10) * 1000), 0b110))
    assert isinstance(ack, fp.Ack)
    result = None
    for _ in range(400):
        host.keep_alive_for(50)
        done = host.of_type(fp.ProbeResult)
        if done:
            result = done[0]
            break
    assert isinstance(result, fp.ProbeResult)
    assert result.seq == ack.seq
    assert result.result == fp.ProbeOutcome.CONTACT
    assert result.sensor & (1 << sensor)
    # contact where the physics says it is (5 mm/s: under 0.1 mm of travel per tick)
    expected_um = (surface_mm - offset_mm) * 1000
    assert abs(result.contact_z_um - expected_um) < 150
    assert result.stop_z_um <= result.contact_z_um
    assert not host.board.plant.zaxis.is_idle or plant.zaxis.position_mm * 1000 == pytest.approx(
        result.stop_z_um, abs=1
    )


def test_z_velocity_expires_unless_renewed(host: SimHost) -> None:
    """A Z velocity setpoint moves Z only for its expiry; a stale stream_seq is ignored."""
    host.open_session()
    z = host.board.plant.zaxis
    start = z.position_mm
    host.send(fp.ZVelocity(0, 1, 10_000, 20), seq=0)
    host.pump(15)
    assert z.position_mm > start
    host.pump(200)
    assert z.is_idle
    moved = z.position_mm - start
    assert 0.1 < moved < 1.0  # 20 ms at up to 10 mm/s, plus deceleration
    host.send(fp.ZVelocity(0, 1, 10_000, 20), seq=0)  # same stream_seq: not newer
    host.pump(50)
    assert z.position_mm == pytest.approx(start + moved)
    assert host.board.firmware.zvel_seq == 1


def test_configure_out_of_range_names_the_field_and_changes_nothing(host: SimHost) -> None:
    """An invalid CONFIGURE is refused with the field index; the sampling stays as it was."""
    host.open_session()
    nak = host.request(fp.Configure(0, 1000, 0, 0, 0, 0, 0, 0.01))
    assert isinstance(nak, fp.Nak)
    assert (nak.code, nak.detail) == (NakCode.OUT_OF_RANGE, 1)
    assert host.board.firmware.batch_size == fp.DEFAULT_BATCH_SIZE
    assert isinstance(host.request(fp.Configure(0, 2000, 10, 0, 0, 0, 0, 0.01)), fp.Ack)
    host.received.clear()
    host.pump(20)
    batches = host.of_type(fp.Samples)
    assert batches
    assert all(len(b.samples_cv) == 10 and b.period_us == 500 for b in batches)


def test_samples_are_sequenced_and_timestamped(host: SimHost) -> None:
    """SAMPLES batches count up by one and their timestamps advance by batch x period."""
    host.pump(100)
    batches = host.of_type(fp.Samples)
    assert len(batches) == 20
    for a, b in itertools.pairwise(batches):
        assert b.stream_seq == (a.stream_seq + 1) & 0xFFFF
        assert b.t0_us - a.t0_us == 5 * a.period_us


def test_breakaway_latches_the_torch_off(host: SimHost) -> None:
    """A breakaway input turns the torch off and refuses a reset while the head is tripped."""
    host.open_session()
    host.request(fp.Torch(0, True))
    host.board.plant.head.trip_breakaway()
    host.pump(2)
    assert not host.board.plant.torch_on
    assert host.board.firmware.faults & (1 << FaultCode.BREAKAWAY)
    events = [e for e in host.of_type(fp.Event) if e.input == InputBit.BREAKAWAY]
    assert events
    assert events[0].level == 1


def test_same_seed_reproduces_the_same_run() -> None:
    """Two boards with one seed, driven alike, send byte-identical streams."""

    def run(seed: int) -> bytes:
        board = SimulatedBoard("noisy_hf_start", seed=seed)
        host = SimHost(board)
        host.open_session()
        host.request(fp.Torch(0, True))
        out = bytearray()
        for _ in range(20):
            board.advance_ms(25)
            out += board.read()
            host.request(fp.Heartbeat(0))
        return bytes(out)

    assert run(11) == run(11)
    assert run(11) != run(12)


def test_probe_reaching_z_min_reports_limit_without_a_fault(host: SimHost) -> None:
    """A probe that finds nothing above Z min ends with result LIMIT; no Z_LIMIT fault."""
    host.board.plant.zaxis.min_mm = 25.0  # the plate (20 mm) is below the soft limit
    host.board.reboot()  # the board reads its soft limits at power-on
    host.open_session()
    host.request(fp.OhmicSense(0, True))
    ack = host.request(fp.ZProbe(0, 20_000, 60_000, InputMask.OHMIC))
    assert isinstance(ack, fp.Ack)
    for _ in range(100):
        host.keep_alive_for(50)
        if host.of_type(fp.ProbeResult):
            break
    result = host.of_type(fp.ProbeResult)[0]
    assert result.result == fp.ProbeOutcome.LIMIT
    assert host.board.firmware.faults == 0


def test_z_velocity_into_a_soft_limit_latches_z_limit(host: SimHost) -> None:
    """Driving Z up into its max with the THC stream latches Z_LIMIT (detail 1)."""
    host.open_session()
    for stream_seq in range(1, 200):
        host.send(fp.ZVelocity(0, stream_seq, 60_000, 50), seq=0)
        host.pump(5)
        if host.board.firmware.faults:
            break
    assert host.board.firmware.faults & (1 << FaultCode.Z_LIMIT)
    fault = host.of_type(fp.Fault)[0]
    assert (fault.code, fault.detail) == (FaultCode.Z_LIMIT, 1)
