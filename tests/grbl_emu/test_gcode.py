"""The emulator's G-code parser on its own: targets, arc centres, offsets, modal resets."""

from __future__ import annotations

import math

import pytest

from dthc_tools.grbl_emu.blocks import Dwell, Move, MoveKind, ProgramStop, scan_words
from dthc_tools.grbl_emu.codes import GcodeRefused, Status
from dthc_tools.grbl_emu.gcode import GcodeInterpreter


def run(parser: GcodeInterpreter, line: str) -> tuple[object, ...]:
    """One prepared line (upper case, no blanks) through the parser."""
    return parser.execute(scan_words(line))


def test_scan_words_reads_grbl_numbers() -> None:
    """Signs, a leading point and no digits after the point are numbers; letters must lead."""
    assert [(w.letter, w.value) for w in scan_words("G1X-.5Y+2.F100")] == [
        ("G", 1.0),
        ("X", -0.5),
        ("Y", 2.0),
        ("F", 100.0),
    ]
    with pytest.raises(GcodeRefused) as exc:
        scan_words("X-")
    assert exc.value.status is Status.BAD_NUMBER_FORMAT


@pytest.mark.parametrize(
    ("line", "center"),
    [
        ("G3X10Y10R10F100", (0.0, 10.0)),  # short way round, counter-clockwise: centre left
        ("G2X10Y10R10F100", (10.0, 0.0)),  # short way round, clockwise: centre right
        ("G3X10Y10R-10F100", (10.0, 0.0)),  # negative R: the long way, centre swaps side
    ],
)
def test_radius_arcs_find_grbls_centre(line: str, center: tuple[float, float]) -> None:
    """R-form arcs: the centre on the side grbl puts it, from the sign of R and the turn."""
    (move,) = run(GcodeInterpreter(), line)
    assert isinstance(move, Move)
    assert move.center == pytest.approx(center)
    assert move.radius_mm == pytest.approx(10.0)


def test_inch_mode_converts_targets_offsets_and_feeds() -> None:
    """G20: X, I, J and F are inches; everything inside is millimetres."""
    parser = GcodeInterpreter()
    (move,) = run(parser, "G20G2X2Y0I1J0F10")
    assert isinstance(move, Move)
    assert move.end == pytest.approx((50.8, 0.0, 0.0))
    assert move.center == pytest.approx((25.4, 0.0))
    assert move.feed_mm_min == pytest.approx(254.0)


def test_inverse_time_feed_becomes_a_path_speed() -> None:
    """G93 F2: the move takes half a minute, whatever its length; F is needed every block."""
    parser = GcodeInterpreter()
    (move,) = run(parser, "G93G1X30F2")
    assert isinstance(move, Move)
    assert move.feed_mm_min == pytest.approx(60.0)
    with pytest.raises(GcodeRefused) as exc:
        run(parser, "G1X40")
    assert exc.value.status is Status.UNDEFINED_FEED_RATE
    with pytest.raises(GcodeRefused):
        run(parser, "G94G1X50")  # back to G94: the feed is undefined until an F


def test_g92_and_g10_offsets_and_wco() -> None:
    """G92 makes the current point the given one; G10 L2 sets a table entry; WCO sums them."""
    parser = GcodeInterpreter()
    run(parser, "G0X100Y50")
    run(parser, "G92X0Y0")
    assert parser.work_offset() == (100.0, 50.0, 0.0)
    (move,) = run(parser, "G0X10")
    assert isinstance(move, Move)
    assert move.end == (110.0, 50.0, 0.0)
    run(parser, "G10L2P1X5")
    assert parser.work_offset() == (105.0, 50.0, 0.0)
    run(parser, "G92.1")
    assert parser.work_offset() == (5.0, 0.0, 0.0)


def test_g28_goes_home_through_the_intermediate_point() -> None:
    """G28.1 stores the position; G28 X.. moves via the point, then only X goes home."""
    parser = GcodeInterpreter()
    run(parser, "G0X20Y30")
    run(parser, "G28.1")
    run(parser, "G0X50Y60")
    first, second = run(parser, "G28X40")
    assert isinstance(first, Move)
    assert isinstance(second, Move)
    assert first.end == (40.0, 60.0, 0.0)
    assert second.end == (20.0, 60.0, 0.0)
    assert second.kind is MoveKind.RAPID


def test_dwell_motion_and_program_end_come_in_grbls_order() -> None:
    """A dwell before the motion of its block; M2 last, with the modes reset."""
    parser = GcodeInterpreter()
    run(parser, "G91G1F100")
    actions = run(parser, "G4P0.5X1M2")
    assert [type(a) for a in actions] == [Dwell, Move, ProgramStop]
    assert parser.modal.absolute is True
    assert parser.modal.motion == 1


def test_a_refused_block_changes_nothing() -> None:
    """Modal words before the error in a bad block are not applied."""
    parser = GcodeInterpreter()
    with pytest.raises(GcodeRefused):
        run(parser, "G20G91G1X1X2")
    assert parser.state_report(report_inches=False) == (
        "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]"
    )


def test_arc_extents_include_the_bulge() -> None:
    """A half circle from (0,0) to (0,20) clockwise around (0,10) reaches x = -10."""
    move = Move(MoveKind.ARC_CW, (0.0, 0.0, 0.0), (0.0, 20.0, 0.0), 100.0, (0.0, 10.0))
    xmin, xmax, ymin, ymax = move.xy_extents()
    assert (xmin, xmax) == pytest.approx((-10.0, 0.0))
    assert (ymin, ymax) == pytest.approx((0.0, 20.0))
    assert move.xy_length_mm() == pytest.approx(math.pi * 10.0)
