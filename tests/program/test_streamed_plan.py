"""A program planned as a grbl sender streams it, one line at a time (issue 32's port):
the same steps as planned whole, for every program that does not need the lines after it."""

from __future__ import annotations

from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.program.ngc import STREAMED_OWORD
from dthc_bridge.program.plan import (
    READABLE_PINS,
    DaemonStep,
    MotionStep,
    ProgramPlan,
    Refused,
    Step,
    detect_dialect,
)

PROGRAMS = Path(__file__).parents[1] / "programs"
NAMES = sorted(p.name for p in PROGRAMS.iterdir() if p.suffix in (".nc", ".ngc"))
PINS = dict.fromkeys(READABLE_PINS, 2.0)


def _streamed(lines: list[str], dialect: Dialect) -> list[Step]:
    plan = ProgramPlan([], dialect, pins_mm=dict(PINS))
    return [step for line in lines for step in plan.stream(line)]


@pytest.mark.parametrize("name", NAMES)
def test_streamed_line_by_line_a_program_plans_as_it_does_whole(name: str) -> None:
    lines = (PROGRAMS / name).read_text(encoding="utf-8").splitlines()
    dialect, _ = detect_dialect(lines)
    whole = list(ProgramPlan(lines, dialect, pins_mm=dict(PINS)).steps())
    streamed = _streamed(lines, dialect)
    if any(line.lstrip().lower().startswith("o") for line in lines):
        refused = [step for step in streamed if isinstance(step, Refused)]
        assert refused
        assert refused[0].error.endswith(STREAMED_OWORD)
        return
    if any(isinstance(step, Refused) for step in whole):
        # Planned whole, nothing follows an NGC error; streamed, each line stands alone.
        first = next(i for i, step in enumerate(whole) if isinstance(step, Refused))
        assert streamed[: first + 1] == whole[: first + 1]
        return
    assert streamed == whole


def test_a_streamed_line_reads_what_the_lines_before_it_set() -> None:
    plan = ProgramPlan([], Dialect.PLASMAC, pins_mm=dict(PINS))
    assert plan.stream("#<depth> = 3.8") == []
    assert plan.stream("#<keep-z-motion> = 1") == []
    steps = plan.stream("G0 Z[#<depth> + 1]")
    assert [_line(step) for step in steps] == ["G0 Z4.8", "G0"]  # Z to the board, G0 modal
    refused = plan.stream("G1 X[#<nothing> + ]")
    assert isinstance(refused[0], Refused)
    assert refused[0].text == "G1 X[#<nothing> + ]"
    assert [_line(step) for step in plan.stream("G20 G0 Z1")] == ["G0 Z25.4", "G20 G0"]


def _line(step: Step) -> str:
    assert isinstance(step, DaemonStep | MotionStep), step
    return step.line


@pytest.mark.parametrize("name", NAMES)
def test_streamed_with_detection_a_program_finds_the_dialect_it_is_detected_in_whole(
    name: str,
) -> None:
    """Starting from another dialect, a streamed plan takes the program's own from the
    first line that shows it; every step after that is the whole plan's."""
    lines = (PROGRAMS / name).read_text(encoding="utf-8").splitlines()
    dialect, why = detect_dialect(lines)
    other = Dialect.ROSETTA if dialect is not Dialect.ROSETTA else Dialect.MASSO
    plan = ProgramPlan([], other, pins_mm=dict(PINS))
    for line in lines:
        plan.stream(line, detect=True)
    assert plan.dialect is (dialect if why.startswith("found") else other)
