"""The sender counts the cuts a program starts from the parsed commands, not the text."""

from __future__ import annotations

import pytest

from dthc_bridge.controller.gcode import parse_line
from dthc_tools.sender.path import starts_cut

G100_P6 = "G100 P6 A1000 B-60 C300 D3.8 E0.5 F3 H1.5"


@pytest.mark.parametrize(
    ("line", "cuts"),
    [
        ("M3", 1),
        ("M03", 1),
        ("M003", 1),
        ("M5 (end of M3 cut)", 0),
        ("M5 M30", 0),
        ("M5 ; M300 next", 0),
        (G100_P6, 1),
        (G100_P6.replace("G100 P6", "G100P6"), 1),
        (G100_P6 + " I1", 1),
        (G100_P6 + " I2", 0),  # I2/I3 only set values
    ],
)
def test_cuts_started_on_a_line(line: str, cuts: int) -> None:
    assert sum(starts_cut(c) for c in parse_line(line).commands) == cuts
