"""The controller service wired to a real link: docs/DESIGN.md invariant 3 when the link
goes mid-cut."""

from __future__ import annotations

import asyncio

import pytest

from dthc_bridge.board import BoardClient
from dthc_bridge.controller.plasma import PlasmaController
from dthc_bridge.controller.sequence import State
from dthc_bridge.events import ControllerEvent, ProgramPaused
from dthc_bridge.link import LinkSupervisor, LinkTiming
from dthc_bridge.service import ControllerService
from mock_device.sim import SimulatedBoard
from tests.link.board_harness import RealtimeSimBoard

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]

TIMING = LinkTiming(lease_ms=150, backoff_initial_s=0.05, backoff_max_s=0.2)


async def test_unplug_mid_cut_faults_pauses_the_sender_and_the_lease_drops_the_torch() -> None:
    """Link lost while cutting: FAULTED, a pause event, touch-off required, torch off."""
    sim = RealtimeSimBoard(SimulatedBoard("flat_clean", seed=3))
    supervisor = LinkSupervisor("sim://board", TIMING, opener=sim.opener)
    service = ControllerService(PlasmaController(), supervisor, BoardClient(supervisor))
    events: list[ControllerEvent] = []

    async def collect() -> None:
        async for event in service.subscribe_events():
            events.append(event)

    async with sim.running():
        tasks = [
            asyncio.create_task(supervisor.run()),
            asyncio.create_task(service.run()),
            asyncio.create_task(collect()),
        ]
        try:
            await supervisor.wait_online(3.0)
            for line in ("T112 M6", "G200 F300 P3.8 D300 C1.5 V125 A90 O1 S0", "M3"):
                result = await service.execute_gcode(line)
                assert result.ok, result.error
            assert sim.board.plant.torch_on
            sim.refuse_connections = True
            sim.unplug()
            await asyncio.sleep(0.5)  # well past the 150 ms lease
            assert service.sequence.state is State.FAULTED
            assert "link down" in service.sequence.error
            assert service.sequence.probe_required
            assert any(isinstance(e, ProgramPaused) for e in events)
            assert not sim.board.plant.torch_on
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
