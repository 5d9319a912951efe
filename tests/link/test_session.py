"""The daemon's link layer against the simulated board, over clean and hostile memory links."""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import AsyncIterator

import pytest

import firmware_protocol as fp
from dthc_bridge.board import Batch, BoardClient
from dthc_bridge.link import (
    BoardRebooted,
    LinkDown,
    LinkState,
    LinkSupervisor,
    LinkTiming,
    NegativeAck,
)
from mock_device.board_logic import BoardIdentity
from mock_device.sim import SimulatedBoard
from tests.transport.memory import LinkFaults

from .board_harness import RealtimeSimBoard

FAST = LinkTiming(
    ack_timeout_s=0.03, lease_ms=200, backoff_initial_s=0.02, backoff_max_s=0.1,
    handshake_timeout_s=0.1,
)  # fmt: skip


class Rig:
    def __init__(self, sim: RealtimeSimBoard, timing: LinkTiming = FAST) -> None:
        self.sim = sim
        self.states: list[tuple[LinkState, str]] = []
        self.supervisor = LinkSupervisor("sim://board", timing, opener=sim.opener)
        self.supervisor.add_state_listener(lambda c: self.states.append((c.state, c.reason)))
        self.client = BoardClient(self.supervisor)


@pytest.fixture
async def rig(request: pytest.FixtureRequest) -> AsyncIterator[Rig]:
    params = getattr(request, "param", {})
    board = SimulatedBoard(
        params.get("scenario", "flat_clean"), seed=7, identity=params.get("identity")
    )
    sim = RealtimeSimBoard(board, to_host=params.get("to_host"), to_board=params.get("to_board"))
    rig = Rig(sim)
    async with sim.running():
        task = asyncio.create_task(rig.supervisor.run(), name="supervisor")
        try:
            yield rig
        finally:
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task


async def test_handshake_brings_the_link_online(rig: Rig) -> None:
    """The supervisor connects, handshakes, sets the lease and learns the board's time."""
    session = await rig.supervisor.wait_online(2.0)
    assert session.info is not None
    assert session.boot_id == rig.sim.board.firmware.boot_id
    assert rig.sim.board.firmware.lease_ms == FAST.lease_ms
    assert rig.supervisor.stats.handshakes == 1


HOSTILE = {
    "clean": {},
    "one_byte_at_a_time": {
        "to_host": LinkFaults(one_byte_at_a_time=True),
        "to_board": LinkFaults(one_byte_at_a_time=True),
    },
    "one_percent_frame_loss": {
        "to_host": LinkFaults(loss_rate=0.01, seed=1),
        "to_board": LinkFaults(loss_rate=0.01, seed=2),
    },
    "bit_flips": {
        "to_host": LinkFaults(bit_flip_rate=2e-4, seed=3),
        "to_board": LinkFaults(bit_flip_rate=2e-4, seed=4),
    },
    "delayed_2ms": {
        "to_host": LinkFaults(delay_s=0.002),
        "to_board": LinkFaults(delay_s=0.002),
    },
}


@pytest.mark.parametrize("rig", list(HOSTILE.values()), ids=list(HOSTILE), indirect=True)
async def test_the_same_command_sequence_completes_over_hostile_links(rig: Rig) -> None:
    """Torch, ohmic, status, a Z move and a probe complete the same way on every link."""
    await rig.supervisor.wait_online(3.0)
    client = rig.client
    fw = rig.sim.board.firmware
    await client.ohmic_sense(True)
    moved = await client.move_z(40.0, 50.0)
    assert moved.reached
    assert moved.z_mm == 40.0
    probe = await client.probe(feed_mm_s=10.0, max_travel_mm=30.0)
    assert probe.result == fp.ProbeOutcome.CONTACT
    assert abs(probe.contact_z_mm - rig.sim.board.plant.surface_z_mm) < 0.3
    await client.torch(True)
    assert fw.torch_on
    status = await client.status()
    assert status.status & fp.StatusBit.TORCH_ON
    await client.torch(False)
    assert not fw.torch_on
    assert fw.faults == 0  # the lease held throughout
    for _ in range(20):
        await client.status()
    stats = rig.supervisor.stats
    assert stats.timeouts == 0


async def test_idle_link_keeps_the_lease_with_heartbeats(rig: Rig) -> None:
    """Half a second with no commands: heartbeats renew the lease, no fault latches."""
    await rig.supervisor.wait_online(2.0)
    await asyncio.sleep(0.6)
    assert rig.sim.board.firmware.faults == 0
    assert rig.supervisor.stats.frames_out > 5


async def test_nak_raises_negative_ack_with_the_code(rig: Rig) -> None:
    """A refused command raises NegativeAck naming the code; the link stays up."""
    await rig.supervisor.wait_online(2.0)
    with pytest.raises(NegativeAck) as info:
        await rig.client.configure(batch_size=0)
    assert info.value.code == fp.NakCode.OUT_OF_RANGE
    assert info.value.detail == 1
    assert "OUT_OF_RANGE" in str(info.value)
    assert rig.supervisor.state is LinkState.ONLINE


async def test_stalled_acks_are_retransmitted_and_acted_on_once(rig: Rig) -> None:
    """The board stops answering for 60 ms: the host retransmits, the board re-acks, acts once."""
    await rig.supervisor.wait_online(2.0)
    fw = rig.sim.board.firmware
    fw.stall_replies_until_us = fw.t_us + 60_000
    await rig.client.torch(True)
    assert fw.torch_on
    assert rig.supervisor.stats.retransmits >= 1
    assert fw.rx_duplicates >= 1


async def test_board_reboot_fails_pending_work_and_resyncs(rig: Rig) -> None:
    """A reboot (new boot id) is detected, reported, and followed by a fresh handshake."""
    first = await rig.supervisor.wait_online(2.0)
    old_boot = first.boot_id
    rig.sim.board.reboot()
    error = await asyncio.wait_for(first.lost, 2.0)
    assert isinstance(error, BoardRebooted)
    assert error.old_boot_id == old_boot
    again = await rig.supervisor.wait_online(2.0)
    assert again is not first
    assert again.boot_id == rig.sim.board.firmware.boot_id != old_boot
    assert ("offline", "board_rebooted") in [(str(s), r) for s, r in rig.states]
    assert rig.supervisor.stats.reboots == 1 or rig.supervisor.stats.handshakes == 2


async def test_unplug_fails_pending_requests_and_reconnects(rig: Rig) -> None:
    """Mid-request unplug: the waiter gets LinkDown, the board goes offline, then back online."""
    first = await rig.supervisor.wait_online(2.0)
    fw = rig.sim.board.firmware
    fw.stall_replies_until_us = fw.t_us + 10_000_000  # the request will hang until the unplug
    rig.sim.refuse_connections = True
    pending = asyncio.create_task(rig.client.status())
    await asyncio.sleep(0.02)
    rig.sim.unplug()
    with pytest.raises(LinkDown):
        await pending
    assert rig.supervisor.state is not LinkState.ONLINE
    with pytest.raises(LinkDown):
        await rig.client.torch(True)
    await asyncio.sleep(0.2)
    fw.stall_replies_until_us = 0
    rig.sim.refuse_connections = False
    again = await rig.supervisor.wait_online(3.0)
    assert again is not first
    assert rig.supervisor.stats.reconnects >= 1
    assert rig.sim.connections >= 2


@pytest.mark.parametrize(
    "rig", [{"identity": BoardIdentity(proto_major=fp.PROTOCOL_MAJOR + 1)}], indirect=True
)
async def test_other_protocol_major_is_refused_with_a_clear_error(rig: Rig) -> None:
    """A board speaking protocol 2.x is refused; the state and the error say why."""
    for _ in range(100):
        if rig.supervisor.state is LinkState.INCOMPATIBLE:
            break
        await asyncio.sleep(0.01)
    assert rig.supervisor.state is LinkState.INCOMPATIBLE
    host = f"{fp.PROTOCOL_MAJOR}.{fp.PROTOCOL_MINOR}"
    assert f"protocol {fp.PROTOCOL_MAJOR + 1}.{fp.PROTOCOL_MINOR}" in rig.supervisor.last_error
    assert f"speaks {host}" in rig.supervisor.last_error


@pytest.mark.parametrize("rig", [{"to_host": LinkFaults(loss_rate=0.05, seed=9)}], indirect=True)
async def test_lost_sample_batches_are_counted_as_gaps(rig: Rig) -> None:
    """Telemetry is not retransmitted: lost batches show up as gaps, counted from stream_seq."""
    await rig.supervisor.wait_online(3.0)
    await asyncio.sleep(0.5)
    stats = rig.supervisor.stats
    assert stats.telemetry_batches > 50
    assert stats.telemetry_gaps > 0
    total = stats.telemetry_batches + stats.telemetry_gaps
    assert 0.01 < stats.telemetry_gaps / total < 0.15


async def test_telemetry_stream_yields_samples_with_board_order(rig: Rig) -> None:
    """The async telemetry stream delivers sample batches, in SI units, in board order:
    each a batch's span after the one before."""
    await rig.supervisor.wait_online(2.0)
    batches: list[Batch] = []
    stream = rig.client.telemetry()
    async for item in stream:
        if isinstance(item, Batch):
            batches.append(item)
        if len(batches) == 10:
            break
    await stream.aclose()
    for before, after in itertools.pairwise(batches):
        assert after.t_s - before.t_s == pytest.approx(after.duration_s, abs=1e-6)
    assert all(after.period_s == pytest.approx(0.001) for after in batches)


async def test_a_fault_latched_before_the_session_comes_from_status_not_reports(
    rig: Rig,
) -> None:
    """A lease fault latched while unplugged is seen in the handshake STATUS; its 250 ms
    re-reports are history and are not passed on as new events."""
    board = rig.sim.board
    # A host that went away mid-job: a session, a 20 ms lease, ohmic sensing on (in use: the
    # lapse latches), then silence. Its replies were never read.
    board.send(fp.Hello(1, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 1))
    board.send(fp.SetLease(2, 20))
    board.send(fp.OhmicSense(3, True))
    board.advance_ms(30)
    board.read()
    assert board.firmware.faults & (1 << fp.FaultCode.LEASE_EXPIRED)
    reports: list[fp.Message] = []
    rig.supervisor.add_report_listener(lambda report, _t: reports.append(report))
    session = await rig.supervisor.wait_online(2.0)
    assert session.initial_status is not None
    assert session.initial_status.faults & (1 << fp.FaultCode.LEASE_EXPIRED)
    await asyncio.sleep(0.6)  # two or three re-reports of the same fault
    assert not [m for m in reports if isinstance(m, fp.Fault)]


async def test_a_host_frame_coming_back_is_counted_not_fatal(rig: Rig) -> None:
    """An echoing transceiver returns the host's own frames: each is counted as unexpected
    and dropped; the session stays up and keeps answering."""
    session = await rig.supervisor.wait_online(2.0)
    session._on_bytes(fp.encode(fp.Heartbeat(3)) + fp.encode(fp.Torch(4, False)))
    assert rig.supervisor.stats.unexpected_frames == 2
    assert session.is_up
    assert isinstance(await rig.client.status(), fp.Status)
