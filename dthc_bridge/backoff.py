"""Capped, jittered exponential backoff for reconnect loops (the board link, the broker)."""

from __future__ import annotations

import random

__all__ = ["backoff_delay_s"]


def backoff_delay_s(failures: int, *, initial_s: float, max_s: float, rng: random.Random) -> float:
    """How long to wait after ``failures`` consecutive failed attempts.

    The ceiling doubles from ``initial_s`` (first failure) up to ``max_s``; the delay is a
    uniform draw from half the ceiling up to the ceiling, so clients that failed together do
    not retry together. ``failures`` below 1 count as 1.
    """
    ceiling = min(max_s, initial_s * 2.0 ** max(0, failures - 1))
    return ceiling * rng.uniform(0.5, 1.0)
