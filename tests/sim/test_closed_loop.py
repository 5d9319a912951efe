"""The closed-loop simulation is the daemon: its defaults, its service, board time."""

from __future__ import annotations

import dataclasses

import pytest
import structlog

from dthc_bridge.board import Batch
from dthc_bridge.config import DaemonConfig
from dthc_bridge.controller.sequence import State
from dthc_bridge.daemon import build_service
from dthc_bridge.events import ArcLost, BoardRestarted, ProgramPaused
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

    def note(_batch: Batch) -> None:
        seen.append(loop.sequence.now)  # after the service's listener handled it

    loop.client.add_samples_listener(note)
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


def _cutting(scenario: str = "flat_clean", seed: int = 4) -> ClosedLoop:
    loop = ClosedLoop(scenario, seed=seed)
    for line in ("T112 M6", "G200 F300 P3.8 D300 C1.5 V125 A90 O1 S0", "M667 F3000"):
        assert loop.gcode(line).ok
    loop.plant.gantry.feed_line("G0 X50 Y50")
    assert loop.run_until(lambda: loop.plant.gantry.idle, 10)
    assert loop.m3().ok
    return loop


def test_a_reboot_no_reply_has_shown_ends_the_cut_at_once() -> None:
    """While cutting only unacknowledged Z velocities go out, so no reply carries the new
    boot id: the board's clock going back is the reboot. The cut faults within a batch or
    two, the sender is paused, the board's restart is reported, and the sequence's clock
    never runs backwards."""
    loop = _cutting()
    loop.plant.gantry.feed_line("G1 X300 Y50 F5500")
    loop.run_until(lambda: False, 1.0)
    times: list[float] = []
    loop.client.add_samples_listener(lambda _batch: times.append(loop.sequence.now))
    loop.client.add_report_listener(lambda _report: times.append(loop.sequence.now))
    loop.board.reboot()
    assert loop.run_until(lambda: loop.sequence.state is State.FAULTED, 0.02)
    assert any(isinstance(e, BoardRestarted) for e in loop.events)
    assert loop.pauses
    assert times == sorted(times)
    loop.close()


def test_a_bug_on_every_batch_is_one_traceback_and_one_torch_off() -> None:
    """A THC that raises on every batch for a second of board time: every failure is
    counted, the cut ends once, one traceback is logged (the rest counted) and direct
    torch-off requests go out ten times a second, not 200."""
    loop = _cutting(seed=5)
    requests_before = loop.supervisor.stats.requests

    def broken(*_args: object) -> float:
        raise ZeroDivisionError("a bug on every batch")

    loop.sequence.thc.filter = broken  # type: ignore[method-assign,assignment]
    with structlog.testing.capture_logs() as logs:
        loop.run_until(lambda: False, 1.0)
    assert loop.service.handler_errors >= 150
    assert loop.sequence.state is State.FAULTED
    assert len([e for e in logs if e["event"] == "board_data_handler_failed"]) == 1
    # torch-offs at 10/s plus the fault path's own requests, not one per batch
    assert loop.supervisor.stats.requests - requests_before < 25
    assert not loop.plant.torch_on
    loop.close()


def test_a_command_takes_effect_at_the_newest_sample() -> None:
    """The sequence's clock for a command is the last sample's board time, so a timer a
    command starts does not begin (n - 1) sample periods in the past."""
    loop = ClosedLoop("flat_clean", seed=6)
    loop.step()
    assert loop.service.now == pytest.approx(loop.board.t_s, abs=1e-9)
    loop.close()


def test_an_arc_lost_mid_cut_is_published_as_arc_lost() -> None:
    """The arc goes out mid-cut: the service publishes ArcLost (MQTT type ``arc_lost``),
    not a plain pause, and no other pause for the same fault."""
    loop = _cutting("arc_lost_midcut", seed=1)
    assert not loop.move("G1 X450 Y50 F5500", max_s=10)
    pauses = [e for e in loop.events if isinstance(e, ArcLost | ProgramPaused)]
    assert [type(e) for e in pauses] == [ArcLost]
    assert pauses[0].as_payload()["type"] == "arc_lost"
    loop.close()
