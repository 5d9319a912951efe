"""Whole programs through the parser, the controller and the closed loop (simulated time)."""

from __future__ import annotations

from pathlib import Path

import pytest

from dthc_bridge.config import ControllerSettings
from dthc_bridge.controller.commands import CommandError
from dthc_bridge.controller.gcode import parse_line
from dthc_bridge.controller.plasma import PlasmaController
from dthc_bridge.controller.sequence import State
from dthc_tools.sim.closed_loop import ClosedLoop, Reply

PROGRAMS = Path(__file__).parents[2] / "dthc_tools" / "demo" / "programs"


class Sender:
    """What a G-code sender does: plasma lines to the controller, motion to the machine."""

    def __init__(self, loop: ClosedLoop) -> None:
        self.loop = loop
        self.errors: list[str] = []

    def run(self, lines: list[str]) -> None:
        loop = self.loop
        for number, line in enumerate(lines, start=1):
            parsed = parse_line(line, line_number=number)
            if parsed.commands:
                # Plasma words act in program order: after the motion queued before them.
                loop.run_until(lambda: loop.plant.gantry.idle, 60)
                reply = loop.gcode(line, number)
                if not reply.ok:
                    self.errors.append(reply.error)
                    return
            if parsed.motion and not parsed.motion.startswith(("G21", "G17", "G90", "G80", "G94")):
                loop.plant.gantry.feed_line(parsed.motion)
                if not parsed.commands:
                    loop.submit(line, number)  # the daemon reads the feed (anti-dive)
        loop.run_until(lambda: loop.plant.gantry.idle, 60)


def masso_sample() -> list[str]:
    return (PROGRAMS / "masso_sample.ngc").read_text().splitlines()


def test_the_masso_sample_program_runs_from_start_to_end() -> None:
    """The seed's sample program on a warped sheet: every cut pierces, holds height, ends safe."""
    loop = ClosedLoop("masso_warped", seed=3)
    sender = Sender(loop)
    sender.run(masso_sample())
    assert sender.errors == []
    assert loop.sequence.state is State.IDLE
    assert loop.sequence.params.cut_height_mm == pytest.approx(3.5)
    assert loop.sequence.params.cut_voltage_v == 116.0
    m3 = [r for r in loop.replies if r.command == "M3"]
    m5 = [r for r in loop.replies if r.command == "M5"]
    assert len(m3) == len(m5) >= 2
    assert all(r.ok for r in m3 + m5)
    summary = loop.plant.truth.summary()
    assert len(summary.cuts) == len(m3)
    assert all(c.dives == 0 for c in summary.cuts)
    assert all(c.height_rms_error_mm < 0.15 for c in summary.cuts)
    assert all(c.height_max_error_mm < 0.5 for c in summary.cuts)
    assert not loop.plant.torch_on
    assert summary.violations == {}


def test_rosetta_g100_program_probes_starts_and_enables_the_comparator() -> None:
    """G100 P5 A0 B125, P6 probe-and-start, P7 A1 comparator on, P0 resume points."""
    loop = ClosedLoop("flat_clean", seed=4)
    sender = Sender(loop)
    sender.run([
        "T112 M6", "G100 P0", "G0 X50 Y50", "G100 P5 A0 B125",
        "G100 P6 A600 B0 C300 D3.8 E0.3 F3 H1.5", "G100 P7 A1",
        "G1 X300 Y50 F5500", "G1 X300 Y120", "G100 P7 A0", "M5", "G100 P0",
    ])  # fmt: skip
    assert sender.errors == []
    assert [p.index for p in loop.service.controller.resume_points] == [0, 1]
    assert loop.sequence.thc.target_v == pytest.approx(125.0)
    cut = loop.plant.truth.summary().cuts[0]
    assert cut.dives == 0
    assert cut.height_rms_error_mm < 0.15  # includes the THC delay at the float-probed height


def test_plasmac_thc_and_velocity_reduction_lines() -> None:
    """M65 P2 enables THC at once, M64 P2 disables; M67 E3 (the velocity reduction, the
    sender's to apply to its motion) is accepted and changes nothing in the controller."""
    controller = PlasmaController()
    for line in ("M65 P2", "M67 E3 Q60"):
        for command in parse_line(line).commands:
            assert controller.handle(command, 0.0).data == {}
    assert controller.sequence.thc_enabled
    for command in parse_line("M64 P2").commands:
        controller.handle(command, 0.0)
    assert not controller.sequence.thc_enabled


def test_refusals_change_nothing() -> None:
    """Leaving plasma mode mid-cut (a table with other tools), or re-arming with nothing to
    re-arm, is refused cleanly."""
    loop = ClosedLoop("flat_clean", seed=5, settings=ControllerSettings(plasma_mode_at_start=False))
    controller = loop.service.controller
    for line in ("T112 M6", "G200 F300 P3.8 D300 C1.5 V125 A90 O1 S0"):
        for command in parse_line(line).commands:
            controller.handle(command, loop.now)
    assert loop.m3().ok
    with pytest.raises(CommandError, match="plasma mode"):
        controller.handle(parse_line("T1 M6").commands[0], loop.now)
    assert loop.sequence.plasma_mode
    assert loop.sequence.state is State.CUTTING
    from dthc_bridge.controller.commands import Rearm

    with pytest.raises(CommandError, match="re-arm"):
        controller.handle(Rearm(), loop.now)
    assert isinstance(loop.m5(), Reply)
