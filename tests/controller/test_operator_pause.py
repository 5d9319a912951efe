"""docs/DESIGN.md invariant 7 and the panel's idle tools, on the closed loop (the daemon's
service over the simulated board, in simulated time): a pause ends a lit cut (torch off,
safe height, the sender told), a pause with nothing lit changes nothing, a probe test
touches off and comes back, a Z jog moves within its bounds, a re-arm clears the error."""

from __future__ import annotations

import pytest

import firmware_protocol as fp
from dthc_bridge.board import FaultReport
from dthc_bridge.controller.sequence import State
from dthc_bridge.events import BoardFaulted, ProgramPaused
from tests.controller.test_sequence import SQUARE, ready


def test_a_pause_mid_cut_puts_the_torch_out_and_raises_to_safe_height() -> None:
    loop = ready()
    assert loop.m3().ok
    loop.plant.gantry.feed_line(SQUARE[0])
    loop.run_until(lambda: False, 1.0)  # a second of cutting
    assert loop.plant.torch_on
    held = loop.request("thc_hold", on=True)
    assert held.ok
    assert held.data == {"thc_held": True, "cut_ended": True}
    loop.step()
    assert not loop.plant.torch_on  # at once, not after the raise
    assert loop.run_until(lambda: loop.sequence.state is State.IDLE, 5.0)
    assert loop.plant.zaxis.position_mm >= loop.sequence.safe_z_mm - 0.01
    paused = [e for e in loop.events if isinstance(e, ProgramPaused)]
    assert [(e.reason, e.cause) for e in paused] == [("paused by the operator", "operator_pause")]
    # Not a fault: nothing to re-arm; the resume touches off again where the torch stands.
    assert loop.sequence.error == ""
    assert loop.sequence.probe_required
    assert "nothing to re-arm" in loop.request("rearm").error
    assert loop.m3().ok  # the resume's start sequence
    assert loop.plant.torch_on


def test_a_pause_during_the_pierce_answers_the_waiting_m3_and_ends_the_start() -> None:
    loop = ready(pierce_delay_ms=3000.0)
    task = loop.submit("M3")
    assert loop.run_until(lambda: loop.sequence.state is State.PIERCE_DELAY, 20.0)
    assert loop.plant.torch_on
    assert loop.request("thc_hold", on=True).data["cut_ended"] is True
    assert loop.run_until(task.done, 1.0)
    assert loop.replies[-1].error == "paused: paused by the operator"
    loop.step()
    assert not loop.plant.torch_on
    assert loop.run_until(lambda: loop.sequence.state is State.IDLE, 5.0)


def test_a_pause_with_nothing_lit_holds_the_thc_and_ends_nothing() -> None:
    loop = ready()
    held = loop.request("thc_hold", on=True)
    assert held.data == {"thc_held": True, "cut_ended": False}
    assert loop.sequence.state is State.IDLE
    assert not [e for e in loop.events if isinstance(e, ProgramPaused)]


def test_a_probe_test_touches_off_and_returns_to_where_z_was() -> None:
    loop = ready()
    start = loop.plant.zaxis.position_mm
    reply = loop.request("probe_test")
    assert reply.ok, reply.error
    assert reply.data["surface_z_mm"] == pytest.approx(loop.plant.surface_z_mm, abs=0.15)
    assert loop.sequence.state is State.IDLE
    assert loop.plant.zaxis.position_mm == pytest.approx(start, abs=0.01)
    assert loop.sequence.surface_mm == pytest.approx(loop.plant.surface_z_mm, abs=0.15)
    assert not loop.plant.torch_on


def test_a_z_jog_moves_by_its_step_and_a_bad_one_is_refused_naming_it() -> None:
    loop = ready()
    start = loop.plant.zaxis.position_mm
    assert loop.request("jog_z", mm=-2.5).ok
    assert loop.plant.zaxis.position_mm == pytest.approx(start - 2.5, abs=0.01)
    for args, error in (
        ({"mm": 12}, "jog_z mm: 12 is not a step of 0 < |mm| <= 10"),
        ({"mm": 0}, "jog_z mm: 0 is not a step"),
        ({"mm": "up"}, "jog_z mm: 'up' is not a number"),
        ({}, "jog_z mm: required argument is missing"),
        ({"mm": 1, "speed": 3}, "jog_z speed: unknown argument"),
    ):
        assert error in loop.request("jog_z", **args).error
    assert loop.plant.zaxis.position_mm == pytest.approx(start - 2.5, abs=0.01)


def test_the_idle_tools_are_refused_during_a_cut_and_after_a_fault() -> None:
    loop = ready("arc_lost_midcut")
    assert loop.m3().ok
    for name, args in (("probe_test", {}), ("jog_z", {"mm": 1}), ("ohmic_test", {})):
        assert loop.request(name, **args).error == f"{name}: not during a cut (cutting)"
    assert not loop.move("G1 X1000 Y50 F4000", max_s=30)
    assert loop.sequence.error == "arc lost"
    assert loop.request("jog_z", mm=1).error == "jog_z: re-arm required after: arc lost"
    assert loop.request("rearm").ok
    assert loop.sequence.error == ""  # a re-arm clears the stale error
    assert loop.request("jog_z", mm=1).ok


def test_the_material_selector_chooses_the_next_cuts_material() -> None:
    loop = ready()
    reply = loop.request("material_select", number=0)
    assert reply.ok, reply.error
    missing = loop.request("material_select", number=7)
    assert missing.error.startswith("material_select number 7:")
    assert "material_select number: 1.5 is not a material number" in (
        loop.request("material_select", number=1.5).error
    )


def lease_fault(detail: int, t_s: float) -> FaultReport:
    latched = 0 if detail == fp.LEASE_DETAIL_IDLE else 1 << fp.FaultCode.LEASE_EXPIRED
    return FaultReport(t_s, fp.FaultCode.LEASE_EXPIRED, detail, latched, 21.5)


def test_a_lease_lapsed_at_rest_is_logged_not_a_fault_to_rearm() -> None:
    """The board latched nothing (nothing lit, Z at rest): the daemon does not either."""
    loop = ready()
    loop.service._on_report(lease_fault(fp.LEASE_DETAIL_IDLE, loop.now))
    assert loop.sequence.state is State.IDLE
    assert not [e for e in loop.events if isinstance(e, BoardFaulted)]
    assert loop.m3().ok  # the next cut runs with no re-arm


def test_a_lease_lost_during_a_cut_or_latched_still_latches() -> None:
    loop = ready()
    loop.service._on_report(lease_fault(fp.LEASE_DETAIL_LATCHED, loop.now))
    assert loop.sequence.state is State.FAULTED
    assert loop.sequence.error == "board fault: LEASE_EXPIRED"
    cutting = ready()
    assert cutting.m3().ok
    cutting.service._on_report(lease_fault(fp.LEASE_DETAIL_IDLE, cutting.now))
    assert cutting.sequence.state is State.FAULTED  # busy: never taken for an idle lapse


def test_an_internal_fault_names_the_self_check_the_board_failed() -> None:
    """FAULT INTERNAL's detail says which self-check failed: the error the sender and the
    owner see names it (a tick overrun, an ADC conversion missing, a watchdog near-miss)."""
    for detail, words in ((1, "tick overrun"), (2, "adc incomplete"), (3, "watchdog near miss")):
        loop = ready()
        assert loop.m3().ok
        internal = 1 << fp.FaultCode.INTERNAL
        loop.service._on_report(FaultReport(loop.now, fp.FaultCode.INTERNAL, detail, internal, 3))
        assert loop.sequence.state is State.FAULTED
        assert loop.sequence.error == f"board fault: INTERNAL ({words})"
        faulted = [e for e in loop.events if isinstance(e, BoardFaulted)]
        assert faulted, loop.events
