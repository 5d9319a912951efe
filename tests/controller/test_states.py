"""The cut sequence's handler table: every state has one, and the states that may burn are
the ones a torch disable puts out and where contact after arc OK is a crash."""

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
