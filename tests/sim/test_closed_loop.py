"""The closed-loop simulation is the daemon: its defaults, its service, board time."""

from __future__ import annotations

import dataclasses

import pytest

import firmware_protocol as fp
from dthc_bridge.board import Telemetry
from dthc_bridge.config import DaemonConfig
from dthc_bridge.daemon import build_service
from dthc_bridge.service import ControllerService
from dthc_tools.bench.control import BenchLoop, make_thc
from dthc_tools.bench.reference import ReferenceConfig
from dthc_tools.sim.closed_loop import BATCH_S, ClosedLoop

BOARD_LIMITS = ("z_min_mm", "z_max_mm")  # set from the board's HELLO when the link is up


def _without_board_limits(config: object) -> dict[str, object]:
    fields = dataclasses.asdict(config)  # type: ignore[call-overload]
    return {k: v for k, v in fields.items() if k not in BOARD_LIMITS}


async def _daemon_service() -> ControllerService:
    _, service = build_service(DaemonConfig())
    return service


def test_the_benchmark_and_the_simulation_run_the_daemons_defaults() -> None:
    """What ``dthc-bridge run`` builds with no configuration is what the closed loop and the
    control benchmark's ``ours`` run: sequence config, THC config and mode."""
    import asyncio

    daemon = asyncio.run(_daemon_service()).sequence
    loop = ClosedLoop("flat_clean", seed=1)
    bench = BenchLoop("flat_clean", 1, make_thc("ours", ReferenceConfig()))
    for simulated in (loop.sequence, bench.sequence):
        assert _without_board_limits(simulated.config) == _without_board_limits(daemon.config)
        assert simulated.thc.config == daemon.thc.config
        assert simulated.mode is daemon.mode
    assert type(loop.service) is ControllerService
    loop.close()
    bench.close()


def test_two_batches_read_together_keep_their_board_spacing() -> None:
    """Two SAMPLES frames handed to the daemon in one read are handled 5 ms apart in the
    sequence's time (board time), not at the same instant."""
    loop = ClosedLoop("flat_clean", seed=2)
    seen: list[float] = []

    def note(item: Telemetry, _t_s: float) -> None:
        if isinstance(item, fp.Samples):
            seen.append(loop.sequence.now)  # after the service's listener handled it

    loop.client.add_listener(note)
    loop.step()
    seen.clear()
    loop.board.advance_ms(2 * BATCH_S * 1000)  # two batches wait in the board's output
    link = loop._runtime.link
    assert link is not None
    link.deliver()
    assert len(seen) == 2
    assert seen[1] - seen[0] == pytest.approx(BATCH_S, abs=1e-6)
    assert seen[1] == pytest.approx(loop.board.t_s, abs=1e-6)  # the last sample's time
    loop.close()


def test_the_simulation_goes_through_the_wire_protocol() -> None:
    """An M3 in the simulation is the daemon's: board requests over the simulated cable
    (the board's lease renewed, Z velocities streamed), the board's ground truth cutting."""
    loop = ClosedLoop("flat_clean", seed=3)
    for line in ("T112 M6", "G200 F300 P3.8 D300 C1.5 V125 A90 O1 S0", "M667 F3000"):
        assert loop.gcode(line).ok
    loop.plant.gantry.feed_line("G0 X50 Y50")
    assert loop.run_until(lambda: loop.plant.gantry.idle, 10)
    assert loop.m3().ok
    assert loop.plant.torch_on
    assert loop.board.firmware.lease_ms == DaemonConfig().board.lease_ms
    assert loop.supervisor.stats.requests > 5
    assert loop.move("G1 X200 Y50 F5500")
    assert loop.velocities
    assert loop.m5().ok
    assert not loop.plant.torch_on
    loop.close()
