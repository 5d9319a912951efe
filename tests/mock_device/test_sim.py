"""SimulatedBoard's real-time pacing: which ticks are due, and re-anchoring after a reboot."""

from __future__ import annotations

import pytest

from mock_device.sim import SimulatedBoard


def test_only_ticks_whose_sample_time_has_come_run() -> None:
    """At 1 kHz, 2.9 ms after the anchor two ticks are due (samples at 1 and 2 ms), not a
    third whose sample belongs to 3 ms."""
    board = SimulatedBoard()
    start_us = board.firmware.t_us
    assert board.tick_due(10.0) == 0  # anchors
    assert board.tick_due(10.0029) == 2
    assert board.firmware.t_us == start_us + 2000
    assert board.tick_due(10.0030) == 1
    assert board.due_at_s(board.firmware.t_us + 5000) == pytest.approx(10.008)


def test_max_ticks_caps_one_call() -> None:
    board = SimulatedBoard()
    board.tick_due(0.0)
    assert board.tick_due(1.0, max_ticks=200) == 200
    assert board.tick_due(1.0) == 800


def test_a_reboot_is_anchored_again_instead_of_catching_up() -> None:
    """The rebooted firmware's clock starts at 0: it starts from the next call's time, not
    from the first anchor (which would run every tick since then at once)."""
    board = SimulatedBoard()
    board.tick_due(0.0)
    board.tick_due(5.0)
    board.reboot()
    assert board.firmware.t_us == 0
    assert board.tick_due(5.5) == 0
    assert board.tick_due(5.6) == 100
