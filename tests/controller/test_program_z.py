"""Z words of the program, relay cuts and the over-cut's torch disable, over the simulated
board: the safety rules (docs/DESIGN.md invariants 2 and 3) hold on these paths too."""

from __future__ import annotations

import pytest

from dthc_bridge.controller.sequence import State
from dthc_tools.sim.closed_loop import ClosedLoop

from .test_sequence import SQUARE, assert_arc_lost_fault_path, ready


def relay_ready(scenario: str = "flat_clean") -> ClosedLoop:
    """MASSO legacy mode (bare G200): the program probes, sets Z and moves Z itself."""
    loop = ready(scenario)
    assert loop.gcode("G200").ok
    assert loop.gcode("G38.2 Z-50 F300").ok  # the board stops on contact (invariant 2)
    assert loop.gcode("G92 Z-1.5").ok  # the float switch trips 1.5 mm after contact
    assert loop.gcode("G0 Z3.8").ok
    return loop


def test_a_program_probe_stops_on_contact_and_its_origin_sets_work_z() -> None:
    loop = ready()
    assert loop.gcode("G200").ok
    assert loop.gcode("G38.2 Z-50 F300").ok
    stopped = loop.plant.zaxis.position_mm
    assert stopped == pytest.approx(loop.plant.surface_z_mm, abs=2.0)  # stopped at the plate
    assert loop.gcode("G92 Z-1.5").ok
    assert loop.sequence.work_zero_mm == pytest.approx(stopped + 1.5, abs=0.01)
    assert loop.gcode("G0 Z3.8").ok
    assert loop.plant.zaxis.position_mm == pytest.approx(stopped + 5.3, abs=0.05)
    assert loop.sequence.state is State.IDLE


def test_a_relay_m3_lights_the_torch_without_a_sequence_and_m5_only_puts_it_out() -> None:
    loop = relay_ready()
    z_before = loop.plant.zaxis.position_mm
    started = loop.m3()
    assert started.ok
    assert loop.plant.torch_on
    assert loop.sequence.state is State.CUTTING
    assert loop.plant.zaxis.position_mm == pytest.approx(z_before, abs=0.05)  # no probe
    assert loop.gcode("G1 Z1.5 F600").ok  # the program's own cut height
    assert loop.move(*SQUARE)
    assert loop.m5().ok
    assert not loop.plant.torch_on
    assert loop.sequence.state is State.IDLE
    assert loop.plant.truth.violations == {}


def test_arc_lost_in_a_relay_cut_takes_the_fault_path() -> None:
    """Invariant 3 holds in a relay cut: torch off, pause, Z to safe height, re-arm."""
    loop = relay_ready("arc_lost_midcut")
    assert loop.m3().ok
    assert loop.gcode("G1 Z1.5 F600").ok
    assert not loop.move("G1 X1000 Y50 F4000", max_s=30)
    assert_arc_lost_fault_path(loop)


def test_program_z_moves_are_ignored_during_an_automatic_cut_with_one_warning() -> None:
    loop = ready()
    assert loop.m3().ok
    height = loop.plant.zaxis.position_mm
    first = loop.gcode("G0 Z20")
    second = loop.gcode("G0 Z25")
    assert first.ok
    assert second.ok
    assert "ignored" in str(first.data.get("ignored"))
    assert loop.plant.zaxis.position_mm == pytest.approx(height, abs=0.3)
    assert sum("Z move ignored" in w for w in loop.sequence.warnings) == 1
    assert loop.m5().ok


def test_the_over_cut_turns_the_torch_off_and_motion_goes_on_without_a_fault() -> None:
    """M62 P3 mid-cut: torch off at once, THC frozen, the missing arc is no arc loss; M63 P3
    does not relight the cut."""
    loop = ready()
    assert loop.m3().ok
    assert loop.move("G1 X150 Y50 F4000")
    assert loop.gcode("M64 P3").ok
    loop.run_until(lambda: False, 0.2)
    assert not loop.plant.torch_on
    assert loop.move("G1 X200 Y50 F4000")
    assert loop.sequence.state is State.CUTTING  # no fault: the arc is out on purpose
    assert loop.gcode("M65 P3").ok
    loop.run_until(lambda: False, 0.2)
    assert not loop.plant.torch_on
    assert loop.m5().ok
    assert loop.pauses == []


def test_a_fire_control_lift_off_the_float_switch_with_g38_4_then_g92() -> None:
    """FireControl's touch-off: G38.2 down to the plate, G38.4 up until the float switch
    opens (the board probes away), then G92 Z sets the origin there, as with G38.2."""
    loop = ready()
    assert loop.gcode("G200").ok
    assert loop.gcode("G38.2 Z-50 F300").ok
    touched = loop.plant.zaxis.position_mm
    lifted = loop.gcode("G38.4 Z0.5 F20")
    assert lifted.ok, lifted.error
    released = loop.plant.zaxis.position_mm
    assert touched < released < touched + 2.0  # off the switch, not up to the target
    assert loop.gcode("G92 Z0").ok
    assert loop.sequence.work_zero_mm == pytest.approx(released, abs=0.01)
    assert loop.sequence.state is State.IDLE
    # Off the switch now: a probe away must start in contact (as LinuxCNC's).
    for code in ("G38.4", "G38.5"):
        assert "already released" in loop.gcode(f"{code} Z3 F20").error
    assert "not above the torch" in loop.gcode("G38.4 Z-5 F20").error
