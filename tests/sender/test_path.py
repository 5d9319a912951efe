"""The program's path as geometry: where the torch is on it, moves along it (arcs kept as
arcs), the rest of a split segment, and the bounds of paused motion."""

from __future__ import annotations

import math

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.program.plan import ProgramPlan
from dthc_tools.sender.backend import BackendError
from dthc_tools.sender.path import PathPoint, ProgramPath, build_path
from dthc_tools.sender.recovery import PausedProgram
from mock_device.plant.gantry import Gantry
from tests.sender.test_sender_lines import FakeBackend

# Three cuts: a straight one, one with a counter-clockwise half circle, an inch-free third.
PROGRAM = [
    "G21 G90", "G0 X10 Y10", "M3", "M667", "G1 X110 Y10 F3000", "M5",        # cut 1: 100 mm
    "G0 X10 Y50", "M3", "G3 X50 Y50 I20 J0 F2000", "G1 X50 Y80", "M5",       # cut 2: arc + 30
    "G0 X200 Y200", "M3", "G1 X260 Y200 F3000", "M5", "M30",                 # cut 3: 60 mm
]  # fmt: skip


def path_of(lines: list[str]) -> ProgramPath:
    return build_path(ProgramPlan(lines, Dialect.MASSO, {}))


def test_segments_know_their_line_their_cut_and_the_step_that_starts_it() -> None:
    path = path_of(PROGRAM)
    cuts = [(s.source_line, s.kind, s.cut) for s in path.segments]
    assert cuts == [(2, 0, None), (5, 1, 0), (7, 0, None), (9, 3, 1), (10, 1, 1),
                    (12, 0, None), (14, 1, 2)]  # fmt: skip
    arc = path.segments[3]
    assert arc.length == pytest.approx(math.pi * 20.0)
    assert arc.point_at(arc.length / 2) == pytest.approx((30.0, 30.0))  # below: G3 from the left
    assert len(path.cut_steps) == 3


def test_the_torch_is_found_on_the_path_and_refused_off_it() -> None:
    path = path_of(PROGRAM)
    found = path.locate(60.0, 10.2)
    assert found.segment == 1
    assert found.s == pytest.approx(50.0)
    point = path.locate(30.0, 30.0)
    assert point.segment == 3
    assert point.s == pytest.approx(math.pi * 10.0)
    with pytest.raises(BackendError, match=r"the torch \(X60.000 Y15.000\) is not on"):
        path.locate(60.0, 15.0)
    # Only what was sent counts: the torch cannot be on a segment not yet queued.
    with pytest.raises(BackendError, match="not on the program's path"):
        path.locate(230.0, 200.0, up_to_step=path.segments[4].step_index)


def test_walking_back_stops_at_the_cut_start_and_forward_at_the_end() -> None:
    path = path_of(PROGRAM)
    point = PathPoint(1, 50.0)
    assert path.cut_start(point) == PathPoint(1, 0.0)
    assert path.distance(point, path.cut_start(point)) == -50.0
    back, available = path.walk(point, -20.0)
    assert (back, available) == (PathPoint(1, 30.0), 20.0)
    ahead, available = path.walk(point, 1000.0)
    assert ahead == path.end()
    assert available == pytest.approx(path.distance(point, path.end()))


def test_moves_along_an_arc_stay_arcs_both_ways() -> None:
    path = path_of(PROGRAM)
    start = PathPoint(3, 0.0)
    forward = list(path.moves(start, PathPoint(4, 10.0), 1200.0))
    assert forward == ["G3 X50.0000 Y50.0000 I20.0000 J0.0000 F1200", "G1 X50.0000 Y60.0000 F1200"]
    backward = list(path.moves(PathPoint(4, 10.0), PathPoint(3, math.pi * 10.0), 1200.0))
    assert backward == [
        "G1 X50.0000 Y50.0000 F1200",
        "G2 X30.0000 Y30.0000 I-20.0000 J0.0000 F1200",
    ]


def test_the_rest_of_a_split_arc_is_cut_as_the_program_drew_it() -> None:
    """A gantry that runs the program's arc and one that runs the arc split at a point and
    its rest end on the same path (checked point by point)."""
    path = path_of(PROGRAM)
    point = PathPoint(3, math.pi * 20.0 / 3)  # a third of the half circle
    rest = path.rest_of(point)
    assert rest is not None
    assert rest.startswith("G3 X50.0000 Y50.0000 ")
    x, y = path.xy(point)
    whole, split = Gantry(), Gantry()
    whole.feed_program(["G21 G90 G0 X10 Y50", "G3 X50 Y50 I20 J0 F2000"])
    split.feed_program([f"G21 G90 G0 X{x:.4f} Y{y:.4f}", rest])
    arc = path.segments[3]
    for gantry in (whole, split):
        ends = [(s.x0 + s.ux * s.length_mm, s.y0 + s.uy * s.length_mm) for s in gantry._queue]
        for ex, ey in ends[1:]:
            assert math.hypot(ex - arc.cx, ey - arc.cy) == pytest.approx(20.0, abs=1e-3)
    assert path.rest_of(PathPoint(1, 100.0)) is None  # at the segment's end: nothing left


def test_inch_programs_are_tracked_in_millimetres_and_written_in_inches() -> None:
    path = path_of(["G20 G90", "G0 X1 Y1", "M3", "G1 X3 Y1 F100", "M5"])
    cut = path.segments[1]
    assert cut.x0 == pytest.approx(25.4)
    assert cut.x1 == pytest.approx(76.2)
    assert path.rest_of(PathPoint(1, 25.4)) == "G1 X3.0000 Y1.0000 F100"
    assert list(path.moves(PathPoint(1, 25.4), PathPoint(1, 0.0), 254.0)) == [
        "G1 X1.0000 Y1.0000 F10"
    ]


class _Daemon:
    """Answers ``status`` with the cut sequence's state."""

    def __init__(self, state: str) -> None:
        self.state = state

    async def request(self, name: str, /, **_args: object) -> dict[str, object]:
        assert name == "status"
        return {"state": self.state}


class _Sender:
    def __init__(self, state: str) -> None:
        self.daemon = _Daemon(state)
        self.backend = FakeBackend()


@pytest.mark.parametrize("state", ["cutting", "pierce_delay", "probing"])
async def test_paused_motion_never_moves_while_a_cut_may_be_lit(state: str) -> None:
    """The torch never lights during paused motion: the daemon must say no cut runs
    (idle or faulted), else nothing is queued and the reason names its state."""
    sender = _Sender(state)
    paused = PausedProgram(sender, path_of(PROGRAM), up_to_step=None)
    paused.point = PathPoint(1, 50.0)
    with pytest.raises(BackendError, match=f"a cut is running \\({state}\\): stop it first"):
        await paused.move_along(-20.0)
    with pytest.raises(BackendError, match="a cut is running"):
        await paused.set_offset(1.0, 0.0)
    assert sender.backend.queued == []
    sender.daemon.state = "faulted"
    await paused.move_along(-20.0)
    assert sender.backend.queued == ["G21 G90", "G1 X40.0000 Y10.0000 F1000"]
