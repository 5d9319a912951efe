"""Benchmarks and simulation tooling: the closed loop in simulated time, suites of figures."""

from __future__ import annotations

__all__: list[str] = []
