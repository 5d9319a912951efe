"""A valid material to build test cases from, shared by the material tests."""

from __future__ import annotations

from dthc_bridge.materials import Material


def recipe(number: int, **changes: object) -> Material:
    """A valid material (the mandatory keys at usual values) with ``changes``."""
    fields: dict[str, object] = {
        "pierce_height": 3.8,
        "pierce_delay_s": 0.4,
        "cut_height": 1.5,
        "cut_speed": 3000.0,
    }
    return Material(number, **(fields | changes))  # type: ignore[arg-type]
