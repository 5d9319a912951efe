"""The THC's height window: a wrong cut voltage ends the cut before the plate, not at it."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from dthc_bridge.config import ControllerSettings
from dthc_bridge.controller.height_window import HeightWindow
from dthc_bridge.controller.sequence import SequenceConfig, State
from dthc_tools.sim.closed_loop import ClosedLoop

from .test_sequence import ready

WINDOW = HeightWindow(below_mm=1.0, above_mm=4.0, slope_v_per_mm=7.5)


def test_the_offset_is_the_arc_voltage_against_cut_height_through_the_slope() -> None:
    """7.5 V under the voltage measured at cut height is 1 mm below it."""
    assert WINDOW.offset_mm(117.5, 125.0) == pytest.approx(-1.0)
    assert WINDOW.offset_mm(140.0, 125.0) == pytest.approx(2.0)


def test_the_speed_toward_an_edge_is_what_still_stops_there() -> None:
    """Far from the edge the command passes; near it, only v with v*dt + v^2/2a = room."""
    assert WINDOW.limit(-20.0, 0.0, 0.005, 500.0) == -20.0
    near = WINDOW.limit(-20.0, -0.99, 0.005, 500.0)
    assert -20.0 < near < 0.0
    room = 0.01
    assert abs(near) * 0.005 + near * near / 1000.0 == pytest.approx(room, rel=1e-6)
    assert WINDOW.limit(-20.0, -1.2, 0.005, 500.0) == 0.0  # past it: no further
    assert WINDOW.limit(20.0, -1.2, 0.005, 500.0) == 20.0  # away from it: free
    assert WINDOW.limit(20.0, 3.99, 0.005, 500.0) < 20.0


def test_an_edge_is_a_breach_only_while_the_thc_drives_past_it() -> None:
    """At the edge and commanding further: a reason naming the window and its distance."""
    reason = WINDOW.breach(-1.0, -0.5)
    assert reason is not None
    assert "height window" in reason
    assert "1 mm" in reason
    assert "thc_window_below_mm" in reason
    assert WINDOW.breach(-1.0, 0.5) is None  # the THC is raising it again
    assert WINDOW.breach(-1.0, 0.0) is None  # locked: not the THC's doing
    assert WINDOW.breach(-0.9, -5.0) is None
    above = WINDOW.breach(4.0, 1.0)
    assert above is not None
    assert "4 mm" in above
    assert "thc_window_above_mm" in above


def _lowest_mm(loop: ClosedLoop) -> float:
    """The torch's lowest true height over the plate during the cut (the plant's truth)."""
    return min(c.min_height_mm for c in loop.plant.truth.summary().cuts)


def test_a_cut_voltage_far_too_low_ends_at_the_window_before_the_plate() -> None:
    """G200 V 15 V under the arc's voltage at cut height (2 mm lower) on a flat plate: the
    THC takes the torch down to 1 mm below cut height and the cut ends there through the
    fault path (torch off, paused, Z up), with an error naming the window; the torch never
    touches the plate (without the window the float switch stops it, test_sequence)."""
    loop = ready(cut_voltage_v=110.0)
    assert loop.m3().ok
    assert not loop.move("G1 X400 Y50 F5500", max_s=10)
    assert loop.sequence.state is State.FAULTED
    error = loop.sequence.error
    assert "THC height window" in error
    assert "1 mm" in error
    assert "below cut height" in error
    assert _lowest_mm(loop) > 0.3  # 1.5 mm cut height less the 1 mm window, little overrun
    assert loop.plant.truth.violations.get("torch_touching_plate_while_cutting", 0) == 0
    assert not loop.plant.torch_on
    assert any(error in p for p in loop.pauses)
    loop.run_until(lambda: loop.plant.zaxis.is_idle, 5.0)
    assert loop.plant.true_height_mm > 10.0  # raised to safe height
    assert loop.sequence.probe_required


def test_a_narrower_window_stops_sooner() -> None:
    """The configured distance is the one applied: 0.5 mm stops the same dive higher."""
    loop = ready(cut_voltage_v=110.0, config=SequenceConfig(thc_window_below_mm=0.5))
    assert loop.m3().ok
    assert not loop.move("G1 X400 Y50 F5500", max_s=10)
    assert "0.5 mm" in loop.sequence.error
    assert _lowest_mm(loop) > 0.8


def test_a_cut_voltage_far_too_high_ends_at_the_window_before_the_arc_is_lost() -> None:
    """G200 V 40 V over the arc's (5.3 mm higher): the THC lifts the torch to 4 mm above cut
    height and the cut ends there with the window's error, not with an arc loss."""
    loop = ready(cut_voltage_v=165.0)
    assert loop.m3().ok
    assert not loop.move("G1 X400 Y50 F5500", max_s=10)
    error = loop.sequence.error
    assert "THC height window" in error
    assert "above cut height" in error
    assert "4 mm" in error
    assert not loop.plant.torch_on
    assert any("height window" in p for p in loop.pauses)


def test_the_right_cut_voltage_on_a_warped_plate_never_trips_the_window() -> None:
    """The torch follows a warped sheet millimetres down and up in Z: inside the window,
    which is the arc's height, not Z."""
    loop = ready("warped_sheet", cut_voltage_v=122.0)
    reply = loop.m3()
    assert reply.ok
    assert loop.move("G1 X1100 Y100 F6000", "G1 X1100 Y600", max_s=30)
    assert loop.sequence.state is State.CUTTING, loop.sequence.error
    assert loop.m5().ok


def test_the_window_setting_is_validated_with_its_key_named() -> None:
    """A window of 0 (or beyond the bounds) is refused by the configuration."""
    with pytest.raises(ValidationError, match="thc_window_below_mm"):
        ControllerSettings(thc_window_below_mm=0.0)
    with pytest.raises(ValidationError, match="thc_window_above_mm"):
        ControllerSettings(thc_window_above_mm=50.0)
    configured = ControllerSettings(thc_window_below_mm=0.8).sequence()
    assert configured.thc_window_below_mm == 0.8
    assert SequenceConfig().thc_window_below_mm == 1.0
    assert SequenceConfig().thc_window_above_mm == 4.0
