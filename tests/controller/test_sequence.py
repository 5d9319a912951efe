"""The cut sequence closing the loop over the simulated board, in simulated time."""

from __future__ import annotations

from dataclasses import replace

import pytest

from dthc_bridge.controller import actions as act
from dthc_bridge.controller.commands import CutParams
from dthc_bridge.controller.sequence import SequenceConfig, State
from dthc_tools.sim.closed_loop import ClosedLoop
from mock_device.plant import load_scenario

SQUARE = ("G1 X250 Y50 F5500", "G1 X250 Y150", "G1 X50 Y150", "G1 X50 Y50")


def ready(
    scenario: str = "flat_clean",
    *,
    seed: int = 1,
    config: SequenceConfig | None = None,
    **params: object,
) -> ClosedLoop:
    """Plasma mode, G200 from the scenario's material, THC on, torch over the plate."""
    loop = ClosedLoop(scenario, seed=seed, config=config)
    material = load_scenario(scenario).material
    base: dict[str, object] = {
        "touch_feed_mm_min": 300.0,
        "pierce_height_mm": material.pierce_height_mm,
        "pierce_delay_ms": 300.0,
        "cut_height_mm": material.cut_height_mm,
        "cut_voltage_v": material.cut_voltage_v,
        "ohmic": True,
    }
    base.update(params)
    loop.sequence.plasma_mode = True
    loop.sequence.set_params(CutParams(**base))  # type: ignore[arg-type]  # keyword test data
    loop.sequence.set_thc(True, 3000)
    loop.plant.gantry.feed_line("G0 X50 Y50")
    assert loop.run_until(lambda: loop.plant.gantry.idle, 10)
    return loop


def test_a_full_cut_probes_pierces_cuts_and_returns_to_safe_height() -> None:
    """M3 is answered once at cut height; the cut holds height; M5 ends at safe height."""
    loop = ready()
    started, ok, ended = loop.cut(*SQUARE)
    assert started.ok
    assert ok
    assert ended.ok
    assert loop.sequence.state is State.IDLE
    assert not loop.plant.torch_on
    assert loop.sequence.cut is not None
    assert loop.sequence.cut.zero_mm == pytest.approx(loop.plant.surface_z_mm, abs=0.05)
    assert loop.plant.zaxis.position_mm == pytest.approx(loop.sequence.safe_z_mm, abs=0.01)
    cut = loop.plant.truth.summary().cuts[0]
    assert cut.height_rms_error_mm < 0.1
    assert cut.dives == 0
    assert loop.plant.truth.violations == {}


def test_m3_is_answered_only_when_the_torch_is_at_cut_height() -> None:
    """At the moment M3 is answered the arc is on and the torch within 0.1 mm of cut height."""
    loop = ready()
    reply = loop.m3()
    assert reply.ok
    assert loop.plant.arc_ok
    assert loop.plant.true_height_mm == pytest.approx(1.5, abs=0.1)


def test_painted_plate_retries_ohmic_then_falls_back_to_the_float_switch() -> None:
    """Ohmic never contacts on paint: one retry, then the float switch's travel-corrected zero."""
    loop = ready("painted_plate")
    assert loop.m3().ok
    cut = loop.sequence.cut
    assert cut is not None
    assert cut.ohmic_failed == 1
    assert cut.zero_mm == pytest.approx(loop.plant.surface_z_mm, abs=0.15)


def test_no_arc_after_three_attempts_faults_and_pauses_the_sender() -> None:
    """A pilot that never transfers (pierce too high): 3 attempts, then the fault path."""
    loop = ready(pierce_height_mm=9.5, cut_height_mm=1.5)
    loop.sequence.config = replace(
        loop.sequence.config, arc_ok_timeout_s=0.5, arc_retry_delay_s=0.2
    )
    reply = loop.m3(max_s=30)
    assert not reply.ok
    assert "no arc OK after 3" in reply.error
    assert loop.sequence.state is State.FAULTED
    assert loop.pauses
    assert not loop.plant.torch_on
    assert loop.sequence.probe_required


def assert_arc_lost_fault_path(loop: ClosedLoop) -> None:
    """Invariant 3 after an arc loss: torch off, pause requested, Z up, re-arm required."""
    assert_fault_path(loop, "arc lost")


def assert_fault_path(loop: ClosedLoop, reason: str) -> None:
    """Invariant 3: torch off, pause requested, Z up, re-arm required, naming ``reason``."""
    assert loop.sequence.error == reason
    assert loop.pauses == [reason]
    loop.run_until(lambda: loop.plant.zaxis.is_idle, 5)
    assert not loop.plant.torch_on
    assert loop.plant.zaxis.position_mm >= loop.sequence.safe_z_mm - 0.01
    refused = loop.m3()
    assert not refused.ok
    assert "re-arm" in refused.error


def test_arc_lost_mid_cut_turns_the_torch_off_and_raises_z() -> None:
    """The arc goes out mid-cut: torch off, pause requested, Z up, re-arm required."""
    loop = ready("arc_lost_midcut")
    assert loop.m3().ok
    assert not loop.move("G1 X1000 Y50 F4000", max_s=30)
    assert_arc_lost_fault_path(loop)
    assert loop.request("rearm").ok
    assert loop.sequence.state is State.IDLE


def test_the_operators_stop_mid_cut_takes_the_fault_path() -> None:
    """``abort`` (the console's stop): the cut ends as a fault does, never silently."""
    loop = ready()
    assert loop.m3().ok
    loop.plant.gantry.feed_line("G1 X400 Y50 F5500")
    loop.run_until(lambda: False, 0.3)
    assert loop.plant.torch_on
    stopped = loop.request("abort")
    assert stopped.ok
    assert stopped.data == {"aborted": True}
    assert_fault_path(loop, "stopped by the operator")


def test_the_operators_stop_during_the_start_answers_the_pending_m3() -> None:
    """A stop while M3 is still piercing: that M3 gets the error as its one answer."""
    loop = ready()
    m3 = loop.submit("M3")
    assert loop.run_until(lambda: loop.plant.torch_on, 20)
    assert not m3.done()
    assert loop.request("abort").ok
    assert loop.run_until(m3.done, 5)
    assert not m3.result().ok
    assert m3.result().error == "stopped by the operator"
    assert not loop.plant.torch_on
    assert loop.sequence.state is State.FAULTED


def test_a_stop_with_no_cut_running_changes_nothing() -> None:
    loop = ready()
    assert loop.request("abort").data == {"aborted": False}
    assert loop.sequence.state is State.IDLE
    assert loop.pauses == []


def test_breakaway_mid_cut_faults() -> None:
    """A tripped breakaway during the cut ends it safely."""
    loop = ready()
    assert loop.m3().ok
    loop.plant.gantry.feed_line("G1 X400 Y50 F5500")
    loop.run_until(lambda: False, 0.3)
    loop.plant.head.trip_breakaway()
    loop.run_until(lambda: loop.sequence.state is State.FAULTED, 1.0)
    assert "breakaway" in loop.sequence.error.lower()
    assert not loop.plant.torch_on


def test_float_contact_mid_cut_faults_before_a_crash() -> None:
    """A target voltage far too low, with the height window opened to its widest, drives
    the torch down: the float switch ends the cut (the window's own test:
    tests/controller/test_height_window.py)."""
    loop = ready(cut_voltage_v=95.0, config=SequenceConfig(thc_window_below_mm=10.0))
    assert loop.m3().ok
    assert not loop.move("G1 X400 Y50 F5500", max_s=10)
    assert "float switch during the cut" in loop.sequence.error
    assert not loop.plant.torch_on
    assert loop.plant.truth.violations.get("torch_touching_plate_while_cutting", 0) <= 1


def test_z_min_limit_during_thc_faults_before_the_plate() -> None:
    """With a Z min just under the surface, THC driving down stops at the limit with a fault."""
    loop = ready(cut_voltage_v=100.0)
    surface = loop.plant.surface_z_mm
    assert loop.m3().ok
    loop.sequence.config = replace(loop.sequence.config, z_min_mm=surface + 0.8)
    assert not loop.move("G1 X400 Y50 F5500", max_s=10)
    assert "Z min limit" in loop.sequence.error
    assert loop.plant.true_height_mm > 0.5


def test_stop_after_pierce_waits_for_cycle_start_then_relights() -> None:
    """S1: pierce, torch off, Z up, pause; cycle start lowers, relights and answers M3."""
    loop = ready(stop_after_pierce=True)
    loop.submit("M3")
    assert loop.run_until(lambda: loop.sequence.state is State.S1_WAIT, 20)
    assert not loop.plant.torch_on
    assert loop.pauses
    assert not loop.replies  # M3 still pending
    loop.run_until(lambda: False, 0.5)
    assert loop.sequence.state is State.S1_WAIT
    loop.submit_request("cycle_start")
    assert loop.run_until(lambda: bool(loop.replies), 10)
    assert loop.replies[0].ok
    assert loop.plant.arc_ok
    assert loop.sequence.pierce_count == 2


def test_link_down_mid_cut_faults() -> None:
    """A board link loss during the cut takes the fault path (the board drops the torch)."""
    loop = ready()
    assert loop.m3().ok
    loop.sequence.on_link_down("usb unplugged")
    actions = loop.sequence.drain()
    assert act.SwitchTorch(False) in actions
    assert any(isinstance(a, act.PauseProgram) for a in actions)
    assert loop.sequence.state is State.FAULTED


def test_ihs_skip_when_the_next_cut_starts_close_by() -> None:
    """With skip distance 50 mm and no error, a cut starting 10 mm away does not probe."""
    loop = ready(config=SequenceConfig(ihs_skip_distance_mm=50.0, ihs_skip_type=1))
    assert loop.cut("G1 X60 Y50 F5500")[1]
    probes_before = sum(1 for s in loop.trace.state if s == "probing")
    loop.plant.gantry.feed_line("G0 X55 Y52")
    loop.run_until(lambda: loop.plant.gantry.idle, 5)
    started, ok, _ = loop.cut("G1 X90 Y52 F5500")
    assert started.ok
    assert ok
    assert sum(1 for s in loop.trace.state if s == "probing") == probes_before


def test_an_error_forces_touch_off_even_when_skip_would_apply() -> None:
    """After a fault and re-arm, the next cut probes again although it is close by."""
    loop = ready(config=SequenceConfig(ihs_skip_distance_mm=50.0, ihs_skip_type=1))
    assert loop.m3().ok
    loop.move("G1 X60 Y50 F5500")
    loop.sequence.on_link_down("blip")
    loop.pump()
    assert loop.sequence.state is State.FAULTED
    loop.run_until(lambda: loop.plant.zaxis.is_idle, 5)
    assert loop.request("rearm").ok
    before = sum(1 for s in loop.trace.state if s == "probing")
    assert loop.m3().ok
    assert sum(1 for s in loop.trace.state if s == "probing") > before


def test_dry_run_runs_everything_but_the_arc() -> None:
    """Dry run: probe, heights and M3 answer without the torch ever firing."""
    loop = ready(config=SequenceConfig(dry_run=True))
    reply = loop.m3()
    assert reply.ok
    assert not loop.plant.torch_on
    assert loop.plant.true_height_mm == pytest.approx(1.5, abs=0.1)


def test_ohmic_test_detects_a_shorted_torch() -> None:
    """Ohmic sense on with the shield touching the plate is reported as a short."""
    loop = ready()
    loop.complete(loop.client.move_z(loop.plant.surface_z_mm - 0.2, 10.0))
    loop.run_until(lambda: loop.plant.zaxis.is_idle, 5)
    loop.submit_request("ohmic_test")
    loop.run_until(lambda: loop.sequence.state is not State.OHMIC_TEST, 1)
    assert "shorted torch" in loop.sequence.error


def test_ohmic_test_in_the_air_passes() -> None:
    """With the torch clear of the plate the ohmic test ends quietly."""
    loop = ready()
    loop.submit_request("ohmic_test")
    loop.run_until(lambda: loop.sequence.state is not State.OHMIC_TEST, 1)
    assert loop.sequence.state is State.IDLE
    assert loop.sequence.error == ""


def test_m3_outside_plasma_mode_is_refused() -> None:
    """M3 without T112 M6 gets a clear error and changes nothing."""
    loop = ready()
    loop.sequence.plasma_mode = False
    assert "T112 M6" in loop.m3().error
    assert loop.sequence.state is State.IDLE


def test_safe_height_is_raised_by_what_thc_lifted() -> None:
    """On a plate that rises under the cut, the safe height grows with the THC lift."""
    loop = ready("warped_sheet", cut_voltage_v=122.0)
    assert loop.m3().ok
    before = loop.sequence.safe_z_mm
    assert loop.move("G1 X600 Y100 F6000", max_s=30)
    loop.m5()
    cut = loop.sequence.cut
    assert cut is not None
    assert cut.thc_lift_mm > 0.3
    assert loop.sequence.safe_z_mm == pytest.approx(before + cut.thc_lift_mm, abs=0.05)


def test_auto_voltage_samples_the_target_at_speed() -> None:
    """G200 V0: the target is sampled once at speed, near the true value."""
    loop = ready(cut_voltage_v=None)
    started, ok, _ = loop.cut(*SQUARE)
    assert started.ok
    assert ok
    target = loop.sequence.thc.target_v
    assert target is not None
    assert target == pytest.approx(125.0, abs=1.0)  # flat_clean: 125 V at 1.5 mm
    assert loop.plant.truth.summary().cuts[0].height_rms_error_mm < 0.1


def test_auto_voltage_is_taken_before_a_warped_plate_drifts_and_thc_waits_for_the_delay() -> None:
    """G200 V0 on a warped sheet: the target is taken as soon as the machine is at speed
    (about 0.7 s after arc OK, a few centimetres from the probed point), not after the THC
    delay (1 s), by when the plate under the held torch has drifted further: the target is
    nearer the material's 122 V at cut height than the voltage at the end of the delay;
    until the delay is over the THC never lowers the torch (it may raise it)."""
    loop = ready("warped_sheet", cut_voltage_v=None)
    assert loop.m3().ok
    line = "G1 X1100 Y100 F6000"
    loop.plant.gantry.feed_line(line)
    loop.submit(line)
    sequence = loop.sequence
    assert loop.run_until(lambda: sequence.thc.target_v is not None, 3.0)
    cut = sequence.cut
    assert cut is not None
    arc_ok_s = cut.arc_ok_since
    assert arc_ok_s is not None
    assert 0.5 <= sequence.now - arc_ok_s < sequence.config.thc_delay_s
    target = sequence.thc.target_v
    assert target is not None
    assert sequence.thc.frozen  # the THC delay still runs
    z = loop.plant.carriage_z_mm
    delay_end = arc_ok_s + sequence.config.thc_delay_s
    lowest = z
    while sequence.now < delay_end - 0.01:
        loop.step()
        lowest = min(lowest, loop.plant.carriage_z_mm)
    assert lowest >= z - 0.005
    late = sequence.thc.filtered_v
    assert late is not None
    assert abs(target - 122.0) < 2.0
    assert abs(target - 122.0) < abs(late - 122.0)
    loop.run_until(lambda: not sequence.thc.frozen, 0.2)
    assert not sequence.thc.frozen


def test_a_float_switch_probe_sets_the_height_where_the_switch_closed() -> None:
    """painted_plate (no ohmic contact): the zero is the board's latched contact plus the
    float travel, so the switch's 0.1 mm hysteresis (it opens lower than it closes, on the
    creep up) does not raise the torch: the cut starts within 0.03 mm of its height."""
    loop = ready("painted_plate")
    assert loop.m3().ok
    loop.run_until(lambda: loop.plant.zaxis.is_idle, 2)
    assert loop.plant.true_height_mm == pytest.approx(1.5, abs=0.03)


def test_an_ohmic_zero_is_where_the_contact_opened_not_where_its_debounce_ended() -> None:
    """Creeping up at 1 mm/s, the ohmic contact opens at 20.005 mm (the board's input-change
    event carries Z then); its 5 ms debounce is confirmed by a batch with Z at 20.010. The
    plate is where the contact opened: the zero is 20.005, and the pierce height is over it
    (a zero a debounce later kept every cut, and a target measured there, 0.005 mm high)."""
    from dthc_bridge.controller.sequence import CutSequence
    from firmware_protocol.constants import InputMask

    sequence = CutSequence()
    sequence.plasma_mode = True
    sequence.set_params(CutParams(pierce_height_mm=3.8, cut_height_mm=1.5, ohmic=True))
    sequence.on_inputs(0, 60.0, 0.0)
    sequence.start(0.0)
    assert str(sequence.state) == "to_probe_height"
    sequence.on_motion_done(sequence._move_token, True, 25.0)
    assert str(sequence.state) == "probing"
    ohmic = int(InputMask.OHMIC)
    sequence.on_inputs(ohmic, 20.0, 1.0)
    sequence.on_probe_done(True, True, 20.0, 19.98)
    assert str(sequence.state) == "creep_up"
    sequence.on_inputs(ohmic, 19.995, 1.015)
    sequence.on_inputs(0, 20.005, 1.027)  # the contact opens (an input-change event)
    assert str(sequence.state) == "creep_up"  # not yet debounced
    sequence.on_inputs(0, 20.010, 1.035)  # the next batch: the release is confirmed
    assert str(sequence.state) == "to_pierce_height"
    assert sequence.cut is not None
    assert sequence.cut.zero_mm == pytest.approx(20.005)
    moves = [a for a in sequence.drain() if isinstance(a, act.MoveZ)]
    assert moves[-1].target_mm == pytest.approx(20.005 + 3.8)


def test_puddle_jump_answers_m3_early_and_then_lowers_to_cut_height() -> None:
    """With a puddle jump, XY may start at the puddle height; Z then goes to cut height."""
    loop = ready(config=SequenceConfig(puddle_height_percent=150.0, puddle_delay_s=0.2))
    reply = loop.m3()
    assert reply.ok
    assert str(loop.sequence.state) == "puddle_jump"
    assert loop.run_until(lambda: loop.sequence.state is State.CUTTING, 3)
    loop.run_until(lambda: loop.plant.zaxis.is_idle, 2)
    assert loop.plant.true_height_mm == pytest.approx(1.5, abs=0.1)


def test_mode_0_derives_arc_ok_from_the_voltage() -> None:
    """PlasmaC mode 0: no arc-OK input needed; a stable voltage in the window is arc OK."""
    from dthc_bridge.controller.commands import ThcMode

    loop = ready()
    loop.sequence.mode = ThcMode.VOLTAGE_ONLY
    started, ok, ended = loop.cut(*SQUARE)
    assert started.ok
    assert ok
    assert ended.ok
    assert loop.plant.truth.summary().cuts[0].dives == 0


def test_mode_2_follows_the_external_boxs_up_down_outputs() -> None:
    """PlasmaC mode 2: Z follows the THC box's up/down outputs on a warped sheet."""
    from dthc_bridge.controller.commands import ThcMode

    loop = ready("warped_sheet")
    loop.sequence.mode = ThcMode.ARC_OK_AND_UPDOWN
    loop.plant.gantry.feed_line("G0 X100 Y100")
    loop.run_until(lambda: loop.plant.gantry.idle, 10)
    started, ok, _ = loop.cut("G1 X700 Y100 F6000")
    assert started.ok
    assert ok
    cut = loop.plant.truth.summary().cuts[-1]
    assert cut.dives == 0
    assert cut.height_rms_error_mm < 0.3
    assert any(v != 0.0 for v in loop.velocities)


@pytest.mark.parametrize("cut_height_mm", [1.5, 3.5])
def test_each_cut_limits_slow_down_following_to_half_the_cut_height_down(
    cut_height_mm: float,
) -> None:
    """Below half the cut height is a dive: that is as far down as following a slow-down
    may take the torch in one cut."""
    loop = ready(cut_height_mm=cut_height_mm)
    started = loop.m3()
    assert started.ok
    assert loop.sequence.thc.slow_follow_max_down_mm == pytest.approx(cut_height_mm / 2)
    assert loop.m5().ok


def test_auto_voltage_extrapolates_a_linear_plate_drift_back_to_the_probed_point() -> None:
    """The auto target's fit: voltages sampled 25-55 mm into the cut while the plate drifts
    0.5 mm per 100 mm under the held torch (0.0375 V/mm at 7.5 V/mm), with ripple, give the
    voltage at distance 0 (the probed point, at cut height: 122 V) within 0.3 V, where their
    mean is 1.5 V off; a start transient still decaying (the halves' slopes differ) and a
    plate slope beyond 2 mm per 100 mm give no fit (the mean stays)."""
    from dthc_bridge.controller.auto_voltage import FitLimits, fitted_voltage
    from dthc_bridge.controller.sequence import SequenceConfig
    from dthc_bridge.controller.thc import ThcConfig

    cfg = SequenceConfig()
    limits = FitLimits(
        max_plate_slope_v_per_mm=cfg.auto_voltage_max_plate_slope * ThcConfig().slope_v_per_mm,
        min_span_mm=cfg.auto_voltage_min_span_mm,
        max_residual_v=cfg.auto_voltage_max_residual_v,
        max_slope_change_v_per_mm=cfg.auto_voltage_max_slope_change,
    )
    distances = [25.0 + 0.5 * i for i in range(61)]
    ripple = [0.15 * ((-1) ** i) + 0.1 * ((i * 7) % 5 - 2) / 2 for i in range(61)]
    drift = [122.0 - 0.0375 * d + r for d, r in zip(distances, ripple, strict=True)]
    fitted = fitted_voltage(distances, drift, limits)
    assert fitted is not None
    assert fitted == pytest.approx(122.0, abs=0.3)
    assert abs(sum(drift) / len(drift) - 122.0) > 1.0
    decaying = [122.0 + 6.0 * 0.9 ** (d - 25.0) for d in distances]
    assert fitted_voltage(distances, decaying, limits) is None
    steep = [122.0 - 0.3 * d for d in distances]
    assert fitted_voltage(distances, steep, limits) is None
