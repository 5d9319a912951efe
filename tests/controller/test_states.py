"""The cut sequence's handler table: every state has one, and the states that may burn are
the ones a torch disable puts out and where contact after arc OK is a crash. And the target
voltage, derived rather than adjusted in place."""

from __future__ import annotations

from dthc_bridge.controller.states import HANDLERS, State

BURNING = {State.ARC_WAIT, State.PIERCE_DELAY, State.PUDDLE_JUMP, State.TO_CUT_HEIGHT,
           State.CUTTING}  # fmt: skip


def test_every_state_has_a_handler() -> None:
    assert set(HANDLERS) == set(State)


def test_the_torch_may_burn_from_arc_wait_to_the_end_of_cutting() -> None:
    """A torch disable (over-cut) puts the torch out in these states only."""
    assert {state for state, handler in HANDLERS.items() if handler.torch_lit} == BURNING


def test_contact_after_arc_ok_is_a_fault_while_burning_and_during_the_pause_at_end() -> None:
    faulting = {state for state, handler in HANDLERS.items() if handler.contact_is_fault}
    assert faulting == BURNING | {State.PAUSE_AT_END}


def test_the_target_voltage_is_derived_from_the_cut_voltage_offset_and_override() -> None:
    """target = the cut's own voltage + torch up/down + height override x THC slope, and the
    THC holds exactly that: a new cut voltage (auto voltage's refinement) keeps the
    operator's offset and override; no cut voltage, no target."""
    from dthc_bridge.controller.sequence import CutSequence

    sequence = CutSequence()
    slope = sequence.thc.config.slope_v_per_mm
    sequence.adjust_voltage(2.0)
    sequence.override_height(0.2)
    assert sequence.target_v is None
    assert sequence.thc.target_v is None
    sequence.base_v = 120.0
    assert sequence.target_v == 120.0 + (2.0 + 0.2 * slope)
    sequence.base_v = 121.5
    assert sequence.thc.target_v == sequence.target_v == 121.5 + (2.0 + 0.2 * slope)
    sequence.override_height(0.0)
    sequence.adjust_voltage(-2.0)
    assert sequence.thc.target_v == 121.5
