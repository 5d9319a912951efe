"""Board time to host time: 32-bit extension and the drift-tracking fit."""

from __future__ import annotations

import random

import pytest

from dthc_bridge.link import BoardClock, extend_u32


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


def test_clock_fit_tracks_offset_and_drift_and_ignores_late_replies() -> None:
    """With 50 ppm drift and occasional slow replies, mapped times stay within 100 µs."""
    rng = random.Random(2)
    clock = BoardClock()
    offset_s, rate = 1234.5, 1.0 + 50e-6
    for i in range(40):
        board_us = 1_000_000 + i * 983_900
        true_host = board_us * 1e-6 * rate + offset_s
        rtt = 0.0002 + (0.02 if i % 7 == 3 else rng.uniform(0, 0.00005))  # some late replies
        sent = true_host - rtt / 2
        clock.observe(sent, sent + rtt, board_us)
    probe_us = 1_000_000 + 40 * 983_900
    expected = probe_us * 1e-6 * rate + offset_s
    assert clock.to_host(probe_us) == pytest.approx(expected, abs=100e-6)
    assert clock.rate == pytest.approx(rate, abs=5e-6)


def test_extend_follows_the_latest_board_time() -> None:
    """Sample timestamps crossing a 32-bit wrap keep increasing in 64 bits."""
    clock = BoardClock()
    clock.last_board_us = 0xFFFF_F000
    first = clock.extend(0xFFFF_FC18)
    second = clock.extend(0x0000_0400)  # after the wrap
    assert second > first
    assert second - first == 0x400 + (0x1_0000_0000 - 0xFFFF_FC18)
