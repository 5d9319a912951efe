"""One modal state for every reader of a program (issue 30, STYLE 24): the rules of
G20/G21, G90/G91, G90.1/G91.1 and F, and the readers (the plan's path, the mock's gantry,
the emulated grbl, a restart's position) agreeing on where a program takes the tool."""

from __future__ import annotations

from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.controller.gcode import parse_line
from dthc_bridge.program.modal import ModalState
from dthc_bridge.program.plan import READABLE_PINS, DaemonStep, ProgramPlan, detect_dialect
from dthc_bridge.program.xypath import PathTracer
from dthc_tools.grbl_emu.blocks import Move, scan_words
from dthc_tools.grbl_emu.gcode import GcodeInterpreter
from dthc_tools.sender.sender import RestartPosition
from mock_device.plant.gantry import Gantry


def test_a_feed_is_read_in_the_units_of_its_own_block_and_kept_as_a_speed() -> None:
    modal = ModalState()
    modal.apply([("F", 10.0), ("G", 20.0)])  # G20 applies to the whole block
    assert modal.feed_mm_min == pytest.approx(254.0)
    modal.apply([("G", 21.0)])  # new units: the same speed, written differently
    assert modal.feed_mm_min == pytest.approx(254.0)
    assert modal.feed_in_units == pytest.approx(254.0)
    modal.apply([("F", 0.0)])  # not a feed: nothing changes
    assert modal.feed_mm_min == pytest.approx(254.0)


def test_targets_and_arc_centres_in_each_distance_mode() -> None:
    modal = ModalState()
    assert modal.xy_target(5.0, 5.0, {"X": 1.0}) == (1.0, 5.0)
    modal.apply([("G", 91.0), ("G", 20.0)])
    assert modal.xy_target(5.0, 5.0, {"X": 1.0}) == pytest.approx((30.4, 5.0))
    assert modal.arc_centre(5.0, 5.0, {"I": 1.0}) == pytest.approx((30.4, 5.0))
    modal.apply([("G", 90.1), ("G", 21.0)])
    assert modal.arc_centre(5.0, 5.0, {"I": 1.0}) == (1.0, 5.0)  # J omitted: the start's


PROGRAMS = Path(__file__).parents[1] / "programs"
PROGRAM = [
    "G21 G90 G1 X10 Y5 F600",
    "G20 G91 G1 X1 Y1",  # 25.4 mm more each way, still 600 mm/min
    "G21 G90 G0 X50 Y20",
    "G2 X60 Y30 I10 J0 F1200",
    "G91 G1 X-5",
    "G90 G20 G1 X2 Y2",
]
END_MM = (2 * 25.4, 2 * 25.4)


def test_every_reader_of_a_program_ends_where_the_others_do() -> None:
    plan = ProgramPlan(PROGRAM, Dialect.PLASMAC)
    tracer = PathTracer(plan)
    restart = RestartPosition()
    for index, step in enumerate(plan.steps()):
        tracer.step(index, step)
        restart.skip(step)
    last = tracer.segments[-1]
    assert (last.x1, last.y1) == pytest.approx(END_MM)
    assert (restart.x_mm, restart.y_mm) == pytest.approx(END_MM)
    assert tracer.modal.feed_mm_min == restart.modal.feed_mm_min == pytest.approx(1200.0)

    gantry = Gantry()
    gantry.feed_program(PROGRAM)
    while not gantry.idle:
        gantry.step(0.01)
    assert (gantry.x_mm, gantry.y_mm) == pytest.approx(END_MM, abs=1e-6)

    grbl = GcodeInterpreter()
    moves = [a for line in PROGRAM for a in grbl.execute(scan_words(line.replace(" ", "")))
             if isinstance(a, Move)]  # fmt: skip
    assert tuple(moves[-1].end[:2]) == pytest.approx(END_MM)
    assert moves[-1].feed_mm_min == pytest.approx(1200.0)
    assert grbl.feed_value == pytest.approx(1200.0)
    assert all(isinstance(m, ModalState) for m in (tracer.modal, restart.modal, grbl.modal))


@pytest.mark.parametrize(
    "name", sorted(p.name for p in PROGRAMS.iterdir() if p.suffix in (".nc", ".ngc"))
)
def test_a_daemon_step_carries_the_commands_the_daemon_will_parse(name: str) -> None:
    """Parsed once by the plan, read by the sender and the path; the daemon parses the
    text it is sent in the same dialect and must find the same commands."""
    lines = (PROGRAMS / name).read_text(encoding="utf-8").splitlines()
    plan = ProgramPlan(lines, detect_dialect(lines)[0], pins_mm=dict.fromkeys(READABLE_PINS, 1.0))
    daemon_steps = [step for step in plan.steps() if isinstance(step, DaemonStep)]
    assert daemon_steps
    for step in daemon_steps:
        again = parse_line(step.line, line_number=step.source_line, dialect=plan.dialect)
        assert step.parsed == again, step
