"""Board time: 32-bit extension and one timeline across sessions and reboots."""

from __future__ import annotations

import pytest

from dthc_bridge.link import BoardClock, BoardTimeline, extend_u32


@pytest.mark.parametrize(
    ("t32", "reference", "expected"),
    [
        (10, 5, 10),
        (0xFFFF_FFF0, 0x1_0000_0010, 0xFFFF_FFF0),  # just before a wrap, seen after it
        (0x10, 0xFFFF_FFF0, 0x1_0000_0010),  # just after a wrap, seen before it
        (0, 3 * 2**32 + 5, 3 * 2**32),
    ],
)
def test_extend_u32_picks_the_value_nearest_the_reference(
    t32: int, reference: int, expected: int
) -> None:
    """A wrapped 32-bit board timestamp maps to the 64-bit time nearest 'now'."""
    assert extend_u32(t32, reference) == expected


def test_extend_follows_the_latest_board_time() -> None:
    """Sample timestamps crossing a 32-bit wrap keep increasing in 64 bits."""
    clock = BoardClock()
    clock.last_board_us = 0xFFFF_F000
    first = clock.extend(0xFFFF_FC18)
    second = clock.extend(0x0000_0400)  # after the wrap
    assert second > first
    assert second - first == 0x400 + (0x1_0000_0000 - 0xFFFF_FC18)


def test_the_timeline_keeps_the_board_spacing_within_a_session() -> None:
    """Two stamps 5 ms apart on the board are 5 ms apart on the timeline, whenever read."""
    timeline = BoardTimeline()
    timeline.new_session()
    first = timeline.seconds(7_000_000)
    second = timeline.seconds(7_005_000)
    assert second - first == pytest.approx(0.005, abs=1e-9)
    assert timeline.now_s == pytest.approx(second)


def test_the_timeline_never_runs_backwards_when_a_rebooted_board_counts_from_zero() -> None:
    """After a reboot the board's clock starts again near 0: the timeline goes on from the
    last time seen, so the sequence's timers and the THC's dt stay positive."""
    timeline = BoardTimeline()
    timeline.new_session()
    before = timeline.seconds(90_000_000)
    timeline.new_session()  # the board rebooted: its clock reads 0.2 s now
    after = timeline.seconds(200_000)
    later = timeline.seconds(205_000)
    assert after >= before
    assert later - after == pytest.approx(0.005, abs=1e-9)


def test_a_reconnect_to_the_same_board_keeps_its_clock() -> None:
    """A new session of a board that did not reboot reads on: no jump, no shift."""
    timeline = BoardTimeline()
    timeline.new_session()
    assert timeline.seconds(10_000_000) == pytest.approx(10.0)
    timeline.new_session()
    assert timeline.seconds(12_000_000) == pytest.approx(12.0)
