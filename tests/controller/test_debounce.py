"""The input debouncer: a raw change counts once it has held for the debounce time."""

from __future__ import annotations

from dthc_bridge.controller.debounce import Edge, InputDebouncer
from firmware_protocol.constants import InputMask

HOLD_S = 0.005


def test_a_change_counts_once_it_has_held_the_debounce_time() -> None:
    """A float switch closing gives no edge at once, one edge 5 ms later, and none after."""
    debouncer = InputDebouncer()
    assert debouncer.feed(InputMask.FLOAT, 1.000, HOLD_S) == []
    assert debouncer.poll(1.004, HOLD_S) == []
    assert debouncer.stable == 0
    assert debouncer.poll(1.0051, HOLD_S) == [Edge(InputMask.FLOAT, active=True)]
    assert debouncer.stable == InputMask.FLOAT
    assert debouncer.poll(1.100, HOLD_S) == []


def test_a_bounce_back_to_the_stable_level_gives_no_edge() -> None:
    """Closed and open again within the debounce time: nothing happened."""
    debouncer = InputDebouncer()
    debouncer.feed(InputMask.OHMIC, 0.0, HOLD_S)
    debouncer.feed(0, 0.002, HOLD_S)
    assert debouncer.poll(0.010, HOLD_S) == []
    assert debouncer.stable == 0


def test_each_bit_counts_from_its_own_last_change() -> None:
    """Arc OK and breakaway change 3 ms apart: each edge comes when its own bit has held;
    a bit that keeps bouncing restarts its time."""
    debouncer = InputDebouncer()
    debouncer.feed(InputMask.ARC_OK, 0.000, HOLD_S)
    debouncer.feed(InputMask.ARC_OK | InputMask.BREAKAWAY, 0.003, HOLD_S)
    assert debouncer.poll(0.0051, HOLD_S) == [Edge(InputMask.ARC_OK, active=True)]
    debouncer.feed(InputMask.ARC_OK, 0.006, HOLD_S)  # breakaway bounced open
    debouncer.feed(InputMask.ARC_OK | InputMask.BREAKAWAY, 0.007, HOLD_S)
    assert debouncer.poll(0.011, HOLD_S) == []
    assert debouncer.poll(0.0121, HOLD_S) == [Edge(InputMask.BREAKAWAY, active=True)]


def test_a_release_is_an_inactive_edge() -> None:
    debouncer = InputDebouncer()
    debouncer.feed(InputMask.FLOAT, 0.0, HOLD_S)
    debouncer.poll(0.01, HOLD_S)
    assert debouncer.feed(0, 0.02, 0.0) == [Edge(InputMask.FLOAT, active=False)]
    assert debouncer.raw == 0
    assert debouncer.stable == 0
