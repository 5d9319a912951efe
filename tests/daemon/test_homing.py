"""The daemon's Z homing ([board.homing], protocol 1.3): the service homes Z when the board
comes online unhomed, keeps a home the board still holds, and with ``required`` refuses
cuts until Z is homed. Against the mock (the C board logic), ticking in real time behind a
memory link."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import pytest

import firmware_protocol as fp
from dthc_bridge.board import BoardClient, HomingPlan
from dthc_bridge.controller.commands import JogZ
from dthc_bridge.controller.plasma import PlasmaController
from dthc_bridge.link import LinkState, LinkStateChange, LinkSupervisor, LinkTiming
from dthc_bridge.service import ControllerService
from mock_device.board_logic import BoardIdentity
from mock_device.sim import SimulatedBoard
from tests.link.board_harness import RealtimeSimBoard

pytestmark = pytest.mark.timeout(40)

TIMING = LinkTiming(ack_timeout_s=0.03, lease_ms=250, backoff_initial_s=0.02, backoff_max_s=0.1)
FAST = {"seek_mm_s": 40.0, "locate_mm_s": 4.0, "backoff_mm": 2.0, "timeout_s": 15.0}


@asynccontextmanager
async def _daemon(sim: RealtimeSimBoard, plan: HomingPlan) -> AsyncIterator[ControllerService]:
    supervisor = LinkSupervisor("sim://board", TIMING, opener=sim.opener)
    service = ControllerService(
        PlasmaController(), supervisor, BoardClient(supervisor), homing=plan
    )
    tasks = [asyncio.create_task(supervisor.run()), asyncio.create_task(service.run())]
    try:
        await supervisor.wait_online(3.0)
        yield service
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def _settled(service: ControllerService, timeout_s: float = 20.0) -> None:
    """Until the homing the service started has ended (cuts no longer wait for it)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    await asyncio.sleep(0.2)
    while service.sequence.homing:
        assert loop.time() < end, "homing did not end"
        await asyncio.sleep(0.05)


async def test_at_start_homes_a_board_whose_z_is_wrong_and_a_restart_keeps_the_home() -> None:
    """The board boots taking Z as 45 mm with the carriage at 60: homed at start, its Z is
    the plant's (parked at Z max, 2 mm under the switch), cuts no longer wait; a daemon
    restart finds the board homed and does not home again."""
    board = SimulatedBoard("flat_clean", seed=2, identity=BoardIdentity(boot_z_mm=45.0))
    sim = RealtimeSimBoard(board)
    async with sim.running():
        async with _daemon(sim, HomingPlan(mode="at_start", **FAST)) as service:
            await _settled(service)
            assert service.sequence.unhomed == ""
            status = await service.client.status()
            assert status.status & fp.StatusBit.HOMED
            zaxis = board.plant.zaxis
            assert status.z_um == round(zaxis.max_mm * 1000)
            assert zaxis.position_mm == pytest.approx(zaxis.max_mm, abs=0.01)
            assert status.faults == 0
        homings = board.firmware.executed["ZHome"]
        assert homings == 1
        async with _daemon(sim, HomingPlan(mode="at_start", **FAST)) as service:
            await asyncio.sleep(0.5)
            assert service.sequence.unhomed == ""
        assert board.firmware.executed["ZHome"] == homings


async def test_required_refuses_the_cut_naming_why_when_homing_fails() -> None:
    """No switch within the travel (held open): homing ends not found, and with
    ``required`` an M3 is refused with that error; ``at_start`` lets the cut run unhomed."""
    board = SimulatedBoard("flat_clean", seed=2)
    board.plant.force_input(fp.InputMask.Z_LIMIT_MAX, False)
    sim = RealtimeSimBoard(board)
    plan = HomingPlan(mode="required", max_travel_mm=3.0, **FAST)
    async with sim.running():
        async with _daemon(sim, plan) as service:
            await _settled(service)
            refused = await service.execute_gcode("M3")
            assert not refused.ok
            assert "Z homing failed: not found" in refused.error
            assert '"required"' in refused.error
        async with _daemon(sim, HomingPlan(mode="at_start", max_travel_mm=3.0, **FAST)) as svc:
            await _settled(svc)
            assert svc.sequence.unhomed == ""


async def test_off_never_homes_and_required_without_a_switch_input_refuses() -> None:
    """``off`` sends no Z_HOME; ``required`` with a board that has no HOMING capability
    refuses cuts, saying the board has no home switch input."""
    identity = BoardIdentity(capabilities=int(BoardIdentity().capabilities & ~fp.Capability.HOMING))
    board = SimulatedBoard("flat_clean", seed=2, identity=identity)
    sim = RealtimeSimBoard(board)
    async with sim.running():
        async with _daemon(sim, HomingPlan(mode="off")) as service:
            await asyncio.sleep(0.3)
            assert service.sequence.unhomed == ""
        async with _daemon(sim, HomingPlan(mode="required")) as service:
            await asyncio.sleep(0.3)
            refused = await service.execute_gcode("M3")
            assert not refused.ok
            assert "no home switch input" in refused.error
    assert board.firmware.executed["ZHome"] == 0


async def test_from_the_moment_the_board_is_online_cuts_and_z_commands_wait_for_homing() -> None:
    """The service decides to home inside its ONLINE handler, not in the task it spawns: a
    listener called right after it (as an M3 already queued would run) finds cuts refused
    and homing on; a Z jog meanwhile is refused (it would end the board's cycle ABORTED),
    and the cycle still ends homed."""
    board = SimulatedBoard("flat_clean", seed=2, identity=BoardIdentity(boot_z_mm=45.0))
    sim = RealtimeSimBoard(board)
    seen: list[tuple[str, bool]] = []
    async with sim.running():
        supervisor = LinkSupervisor("sim://board", TIMING, opener=sim.opener)
        plan = HomingPlan(mode="required", **FAST)
        service = ControllerService(
            PlasmaController(), supervisor, BoardClient(supervisor), homing=plan
        )

        def after_the_service(change: LinkStateChange) -> None:
            if change.state is LinkState.ONLINE:
                seen.append((service.sequence.unhomed, service.sequence.homing))

        supervisor.add_state_listener(after_the_service)
        tasks = [asyncio.create_task(supervisor.run()), asyncio.create_task(service.run())]
        try:
            await supervisor.wait_online(3.0)
            assert seen
            unhomed, homing = seen[0]
            assert unhomed.startswith("Z is homing")
            assert homing
            jog = await service.execute_command(JogZ(-1.0))
            assert not jog.ok
            assert "Z is homing" in jog.error
            await _settled(service)
            assert service.sequence.unhomed == ""
            assert board.firmware.executed["ZHome"] == 1
            assert (await service.client.status()).status & fp.StatusBit.HOMED
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)


async def test_a_board_online_with_a_fault_latched_homes_once_re_armed() -> None:
    """An E-stop held at power-up latches ESTOP, and the board refuses Z_HOME while a fault
    is latched: the cut is refused, the operator releases the E-stop and re-arms, and then
    Z homes (before, it stayed unhomed until the service restarted)."""
    board = SimulatedBoard("flat_clean", seed=2, identity=BoardIdentity(boot_z_mm=45.0))
    board.plant.force_input(fp.InputMask.ESTOP, True)
    sim = RealtimeSimBoard(board)
    async with sim.running(), _daemon(sim, HomingPlan(mode="required", **FAST)) as service:
        await asyncio.sleep(0.3)
        assert not (await service.execute_gcode("M3")).ok
        assert board.firmware.executed["ZHome"] == 0
        board.plant.force_input(fp.InputMask.ESTOP, None)
        await asyncio.sleep(0.1)
        rearmed = await service.execute_request("rearm", {})
        assert rearmed.ok, rearmed.error
        await _settled(service)
        assert service.sequence.unhomed == ""
        assert board.firmware.executed["ZHome"] == 1
        assert (await service.client.status()).status & fp.StatusBit.HOMED
