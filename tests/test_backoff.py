"""The one reconnect backoff of the daemon (board link and broker)."""

from __future__ import annotations

import random

import pytest

from dthc_bridge.backoff import backoff_delay_s


class _Fixed(random.Random):
    """A generator whose ``uniform`` returns one end of the range: 0 low, 1 high."""

    def __init__(self, end: int) -> None:
        super().__init__(0)
        self.end = end

    def uniform(self, a: float, b: float) -> float:
        return (a, b)[self.end]


@pytest.mark.parametrize(
    ("failures", "ceiling_s"),
    [(0, 0.2), (1, 0.2), (2, 0.4), (3, 0.8), (4, 1.6), (5, 3.2), (6, 5.0), (60, 5.0)],
)
def test_the_ceiling_doubles_per_failure_up_to_the_cap(failures: int, ceiling_s: float) -> None:
    """The upper bound starts at initial_s, doubles each failure and stops at max_s."""
    high = backoff_delay_s(failures, initial_s=0.2, max_s=5.0, rng=_Fixed(1))
    low = backoff_delay_s(failures, initial_s=0.2, max_s=5.0, rng=_Fixed(0))
    assert high == pytest.approx(ceiling_s)
    assert low == pytest.approx(ceiling_s / 2)


def test_the_jitter_spreads_delays_over_the_upper_half() -> None:
    """Seeded draws land in [ceiling/2, ceiling] and differ, so clients do not retry in step."""
    rng = random.Random(7)
    delays = [backoff_delay_s(3, initial_s=0.5, max_s=30.0, rng=rng) for _ in range(200)]
    assert all(1.0 <= d <= 2.0 for d in delays)
    assert len(set(delays)) == len(delays)
    assert min(delays) < 1.2
    assert max(delays) > 1.8
