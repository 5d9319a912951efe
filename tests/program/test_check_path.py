"""``check-program --json`` gives the planned XY path: one entry per planned move, in program
order, in millimetres (G20 programs converted), arcs with their centre and sense."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.program.check import check_program

# Inches, relative moves, both arc senses, an NGC loop, a Z-only move (not an XY move).
PROGRAM = [
    "G20 G90",
    "#<step> = 1",
    "G0 X1 Y1",
    "G0 Z0.5",
    "M3 $0 S1",
    "G91",
    "o10 repeat [2]",
    "  G1 X#<step> F50",
    "o10 endrepeat",
    "G90 G2 X3 Y3 I0 J1",
    "G3 X2 Y4 I-1 J0",
    "M5 $0",
    "M2",
]


def test_the_path_is_every_planned_xy_move_in_mm_in_program_order() -> None:
    """Loops are unrolled (a line per pass), G91 moves are absolute positions, inches become
    mm, a Z-only move is no entry, arcs carry centre and sense."""
    report = check_program(PROGRAM, dialect=Dialect.PLASMAC)
    mm = 25.4
    expected = [
        {"line": 3, "kind": "rapid", "from": [0.0, 0.0], "to": [mm, mm]},
        {"line": 8, "kind": "feed", "from": [mm, mm], "to": [2 * mm, mm]},
        {"line": 8, "kind": "feed", "from": [2 * mm, mm], "to": [3 * mm, mm]},
        {"line": 10, "kind": "arc", "from": [3 * mm, mm], "to": [3 * mm, 3 * mm],
         "center": [3 * mm, 2 * mm], "cw": True},
        {"line": 11, "kind": "arc", "from": [3 * mm, 3 * mm], "to": [2 * mm, 4 * mm],
         "center": [2 * mm, 3 * mm], "cw": False},
    ]  # fmt: skip
    assert [entry.keys() for entry in report.path] == [entry.keys() for entry in expected]
    for got, want in zip(report.path, expected, strict=True):
        for key, value in want.items():
            assert got[key] == (pytest.approx(value, abs=1e-9) if key in ("from", "to", "center")
                                else value), (got, want)  # fmt: skip


def test_the_cli_json_carries_the_path(tmp_path: Path) -> None:
    """``--json`` prints the path beside the cuts, as JSON numbers in mm."""
    program = tmp_path / "square.nc"
    program.write_text("G21 G90\nG0 X10 Y10\nM3\nG1 X20 F1000\nG1 Y20\nM5\nM30\n")
    result = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "check-program", "--json", str(program)],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    doc = json.loads(result.stdout)
    assert doc["path"] == [
        {"line": 2, "kind": "rapid", "from": [0.0, 0.0], "to": [10.0, 10.0]},
        {"line": 4, "kind": "feed", "from": [10.0, 10.0], "to": [20.0, 10.0]},
        {"line": 5, "kind": "feed", "from": [20.0, 10.0], "to": [20.0, 20.0]},
    ]
