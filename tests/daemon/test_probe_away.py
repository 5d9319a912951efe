"""The daemon's probe away (G38.4/G38.5 on Z, protocol 1.2): BoardClient and the service's
ProbeZ(away=True) against the mock (the C board logic), ticking in real time behind a memory
link."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from dataclasses import dataclass

import pytest

import firmware_protocol as fp
from dthc_bridge.board import BoardClient, ProbeEnded
from dthc_bridge.controller import actions as act
from dthc_bridge.controller.plasma import PlasmaController
from dthc_bridge.link import BoardTooOld, LinkSupervisor, LinkTiming, NegativeAck
from dthc_bridge.service import ControllerService
from mock_device.board_logic import BoardIdentity
from mock_device.sim import SimulatedBoard
from tests.link.board_harness import RealtimeSimBoard

pytestmark = pytest.mark.timeout(30)

TIMING = LinkTiming(ack_timeout_s=0.03, lease_ms=250, backoff_initial_s=0.02, backoff_max_s=0.1)
FLOAT = fp.InputMask.FLOAT


@dataclass
class Rig:
    sim: RealtimeSimBoard
    supervisor: LinkSupervisor
    client: BoardClient


@pytest.fixture
async def rig(request: pytest.FixtureRequest) -> AsyncIterator[Rig]:
    identity: BoardIdentity | None = getattr(request, "param", None)
    sim = RealtimeSimBoard(SimulatedBoard("flat_clean", seed=7, identity=identity))
    supervisor = LinkSupervisor("sim://board", TIMING, opener=sim.opener)
    async with sim.running():
        task = asyncio.create_task(supervisor.run(), name="supervisor")
        try:
            await supervisor.wait_online(3.0)
            yield Rig(sim, supervisor, BoardClient(supervisor))
        finally:
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task


async def _touch_off(rig: Rig) -> ProbeEnded:
    """Z 3 mm above the plate, then down onto the float switch."""
    surface_mm = rig.sim.board.plant.surface_z_mm
    await rig.client.move_z(surface_mm + 3.0, 50.0)
    touch = await rig.client.probe(10.0, 10.0, FLOAT)
    assert touch.result == fp.ProbeOutcome.CONTACT
    return touch


async def test_start_probe_away_lifts_off_the_float_switch_and_reports_the_release(
    rig: Rig,
) -> None:
    """start_probe(away=True) sends Z_PROBE_AWAY: the board moves up, stops itself when the
    float switch opens and reports RELEASED with the release's Z, above the touch-off's
    rest and at most the float's travel above its contact."""
    touch = await _touch_off(rig)
    fw = rig.sim.board.firmware
    seq = await rig.client.start_probe(1.0, 5.0, FLOAT, away=True)
    away = await rig.client.wait_probe(seq, 10.0)
    assert fw.executed["ZProbeAway"] == 1
    assert away.result == fp.ProbeOutcome.RELEASED
    assert away.sensor == FLOAT
    eps = 1e-9  # µm on the wire, mm here: a bound met exactly stays met
    assert touch.stop_z_mm < away.contact_z_mm <= touch.contact_z_mm + 0.3 + eps
    assert away.contact_z_mm <= away.stop_z_mm <= away.contact_z_mm + 0.05 + eps
    assert not fw.inputs & FLOAT
    assert fw.faults == 0


@pytest.mark.parametrize("rig", [BoardIdentity(proto_minor=1)], indirect=True)
async def test_a_1_1_board_is_refused_the_probe_away_before_anything_is_sent(rig: Rig) -> None:
    """A board announcing 1.1: BoardTooOld naming both versions, no frame sent; sent anyway,
    the board itself answers NAK UNKNOWN_TYPE and Z stays where it was."""
    fw = rig.sim.board.firmware
    with pytest.raises(BoardTooOld, match=r"needs protocol 1\.2, the board speaks 1\.1"):
        await rig.client.start_probe(1.0, 5.0, FLOAT, away=True)
    assert fw.executed["ZProbeAway"] == 0
    z_before = rig.sim.board.plant.zaxis.position_mm
    with pytest.raises(NegativeAck) as refused:
        await rig.supervisor.current().request(fp.ZProbeAway(0, 1_000, 5_000, FLOAT))
    assert refused.value.code == fp.NakCode.UNKNOWN_TYPE
    await asyncio.sleep(0.05)
    assert rig.sim.board.plant.zaxis.position_mm == z_before


async def test_the_service_performs_probe_z_away_and_reports_the_release(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ProbeZ(..., away=True) through the service's _perform: the sequence hears
    on_probe_done(contact=True, ohmic=False, contact_z = the release's Z, stop_z)."""
    touch = await _touch_off(rig)
    service = ControllerService(PlasmaController(), rig.supervisor, rig.client)
    heard: list[tuple[bool, bool, float, float]] = []
    done = asyncio.Event()

    def on_probe_done(contact: bool, ohmic: bool, contact_z: float, stop_z: float) -> None:
        heard.append((contact, ohmic, contact_z, stop_z))
        done.set()

    monkeypatch.setattr(service.sequence, "on_probe_done", on_probe_done)
    await service._perform(act.ProbeZ(1.0, 5.0, False, away=True))
    await asyncio.wait_for(done.wait(), 10.0)
    ((contact, ohmic, contact_z, stop_z),) = heard
    assert (contact, ohmic) == (True, False)
    assert touch.stop_z_mm < contact_z <= stop_z
    assert rig.sim.board.firmware.executed["ZProbeAway"] == 1
