"""The forms real programs use (docs/real-programs in the README): each parses to the
command the daemon acts on, or to an error naming what the user wrote.

PlasmaC's ``$`` tools, ``T0 M6``, materials, torch enable/disable, relay ``M3``, probes, work
Z origins and Z words. The MASSO and RosettaCNC forms are in ``test_gcode.py``.
"""

from __future__ import annotations

import pytest

from dthc_bridge.controller.commands import (
    Command,
    CommandError,
    DefineMaterial,
    PlasmaMode,
    ProbeSurface,
    ProgramZMove,
    SelectMaterial,
    SetWorkZ,
    ThcEnable,
    TorchEnable,
    TorchStart,
    TorchStop,
)
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.controller.gcode import ParsedLine, parse_line

PLASMAC = Dialect.PLASMAC
RELAY = Dialect.RELAY
MASSO = Dialect.MASSO


def parsed(line: str, dialect: Dialect = PLASMAC) -> ParsedLine:
    return parse_line(line, dialect=dialect)


def commands(line: str, dialect: Dialect = PLASMAC) -> tuple[Command, ...]:
    return parsed(line, dialect).commands


def error(line: str, dialect: Dialect = PLASMAC) -> CommandError:
    with pytest.raises(CommandError) as info:
        parse_line(line, dialect=dialect)
    return info.value


# --------------------------------------------------------------------------- torch on/off


@pytest.mark.parametrize("line", ["M3 $0 S1", "M03 $0 S1", "m3 $0 s1", "M3 S1", "M3S1", "M3"])
def test_every_plasmac_torch_start_is_a_torch_start(line: str) -> None:
    result = parsed(line)
    assert result.commands == (TorchStart(),)
    assert result.motion is None  # the S word is a spindle speed: nothing for motion


@pytest.mark.parametrize("line", ["M5 $0", "M05 $0", "M5 $-1", "M5", "M05"])
def test_every_plasmac_torch_stop_is_a_torch_stop(line: str) -> None:
    assert commands(line) == (TorchStop(),)


@pytest.mark.parametrize(
    ("line", "word", "names"),
    [
        ("M3 $1 S1", "M3 $1", "scribe"),
        ("M3 $2 S1", "M3 $2", "spotting torch"),
        ("M5 $1", "M5 $1", "scribe"),
        ("M5 $2", "M5 $2", "spotting torch"),
    ],
)
def test_tools_this_board_does_not_have_are_refused_by_name(
    line: str, word: str, names: str
) -> None:
    err = error(line)
    assert err.word == word
    assert names in err.reason


@pytest.mark.parametrize(("line", "word"), [("M3 $-1", "M3 $-1"), ("M5 $7", "M5 $7")])
def test_an_unknown_tool_number_is_refused(line: str, word: str) -> None:
    assert error(line).word == word


def test_a_fractional_tool_is_refused_naming_it() -> None:
    err = error("M3 $0.5 S1")
    assert err.word == "M3 $"
    assert "0.5" in err.reason


def test_m3_in_the_relay_dialect_is_a_relay_start() -> None:
    assert commands("M3", RELAY) == (TorchStart(relay=True),)
    assert commands("M03 S1000", RELAY) == (TorchStart(relay=True),)
    assert commands("M3 S1", MASSO) == (TorchStart(relay=False),)


# --------------------------------------------------------------------------- tool change


@pytest.mark.parametrize("line", ["T0 M6", "M6 T0", "M06 T0", "T0M6"])
def test_t0_m6_is_the_torch_in_a_plasmac_program(line: str) -> None:
    assert commands(line) == (PlasmaMode(0, torch=True),)


def test_t0_m6_outside_plasmac_is_an_ordinary_tool_change() -> None:
    # In MASSO only T112 is the torch: the sequence leaves plasma mode for T0.
    assert commands("T0 M6", MASSO) == (PlasmaMode(0),)


@pytest.mark.parametrize(("tool", "names"), [(1, "scribe"), (2, "spotting torch")])
def test_plasmac_scribe_and_spotting_tools_are_refused_at_their_m3(tool: int, names: str) -> None:
    """PlasmaC selects them with M3 $1 / $2; a T1 M6 is a tool number (SheetCam's plasma
    tool), not the scribe."""
    err = error(f"M3 ${tool} S1")
    assert err.word == f"M3 ${tool}"
    assert names in err.reason
    assert commands(f"T{tool} M6") == (PlasmaMode(tool, torch=True),)


def test_g43_h0_passes_to_motion() -> None:
    result = parsed("T0 M6 G43 H0")
    assert result.commands == (PlasmaMode(0, torch=True),)
    assert result.motion == "G43 H0"


def test_the_feed_written_on_a_tool_change_line_goes_to_motion() -> None:
    result = parsed("M06 T1 F5840", MASSO)
    assert result.commands == (PlasmaMode(1),)
    assert result.motion == "F5840"


# --------------------------------------------------------------------------- materials


@pytest.mark.parametrize(("line", "number"), [("M190 P3", 3), ("M190 P-1", -1), ("M190P0", 0)])
def test_m190_selects_a_material(line: str, number: int) -> None:
    assert commands(line) == (SelectMaterial(number),)


@pytest.mark.parametrize(
    ("line", "word"), [("M190", "M190 P"), ("M190 P-2", "M190 P"), ("M190 P1.5", "M190 P")]
)
def test_a_bad_material_number_is_refused(line: str, word: str) -> None:
    assert error(line).word == word


def test_the_wait_after_m190_is_motion_not_a_plasma_command() -> None:
    # M66 P3 L3 Q1: the sender satisfies it (program plan), the parser leaves it to motion.
    assert parsed("M66 P3 L3 Q1").motion == "M66 P3 L3 Q1"


def test_a_magic_comment_defines_a_material_in_plasmac() -> None:
    line = "(o=0, nu=2, na=6mm mild, ph=3.8, pd=0.4, ch=1.5, fr=2400, th=1, cv=121)"
    assert commands(line) == (
        DefineMaterial("o=0, nu=2, na=6mm mild, ph=3.8, pd=0.4, ch=1.5, fr=2400, th=1, cv=121"),
    )


def test_a_magic_comment_is_an_ordinary_comment_in_masso() -> None:
    result = parsed("(o=0, nu=2, ph=3.8)", MASSO)
    assert result.commands == ()
    assert result.comment == "o=0, nu=2, ph=3.8"


def test_a_comment_that_only_mentions_o_is_not_a_material() -> None:
    assert commands("(outline of the part)") == ()


# --------------------------------------------------------------------------- PlasmaC outputs


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("M62 P3", TorchEnable(False, synchronized=True)),
        ("M63 P3", TorchEnable(True, synchronized=True)),
        ("M64 P3", TorchEnable(False, synchronized=False)),
        ("M65 P3", TorchEnable(True, synchronized=False)),
        ("M65 P2", ThcEnable(True, synchronized=False)),
    ],
)
def test_m62_to_m65_p3_disable_and_enable_the_torch(line: str, expected: Command) -> None:
    assert commands(line) == (expected,)


@pytest.mark.parametrize(("line", "word"), [("M64 P0", "M64 P0"), ("M65 P1", "M65 P1")])
def test_other_plasmac_outputs_are_refused_by_name(line: str, word: str) -> None:
    err = error(line)
    assert err.word == word
    assert "P2 (THC) and P3 (torch)" in err.reason


# --------------------------------------------------------------------------- probes, origins


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G38.2 Z-50 F600", ProbeSurface(-50.0, 600.0, True)),
        ("G38.3 Z-30 F300", ProbeSurface(-30.0, 300.0, False)),
        ("G31 Z-40 F500", ProbeSurface(-40.0, 500.0, True)),
    ],
)
def test_probes_along_z_are_the_boards(line: str, expected: Command) -> None:
    for dialect in (RELAY, PLASMAC, MASSO):
        assert commands(line, dialect) == (expected,)


@pytest.mark.parametrize(("line", "word"), [("G38.2 Z-50", "G38.2 F"), ("G38.2 F600", "G38.2 Z")])
def test_a_probe_needs_its_target_and_feed(line: str, word: str) -> None:
    err = error(line, RELAY)
    assert err.word == word
    assert "missing" in err.reason


@pytest.mark.parametrize(
    ("line", "release_required"), [("G38.4 Z5 F100", True), ("G38.5 Z5 F100", False)]
)
def test_probing_away_is_a_probe_up_to_the_release(line: str, release_required: bool) -> None:
    assert commands(line, RELAY) == (ProbeSurface(5.0, 100.0, release_required, away=True),)


@pytest.mark.parametrize(
    ("line", "expected", "motion"),
    [
        ("G92 Z0", SetWorkZ(0.0), None),
        ("G92 Z-1.5", SetWorkZ(-1.5), None),
        ("G10 L20 P1 Z0", SetWorkZ(0.0), None),
        ("G92.1", SetWorkZ(None), None),
        ("G92 X0 Y0 Z0", SetWorkZ(0.0), "G92 X0 Y0"),
    ],
)
def test_work_z_origins_are_the_boards(line: str, expected: Command, motion: str | None) -> None:
    result = parsed(line, RELAY)
    assert result.commands == (expected,)
    assert result.motion == motion


def test_g10_other_than_l20_refuses_z() -> None:
    assert error("G10 L2 P1 Z0", RELAY).word == "G10 Z"


# --------------------------------------------------------------------------- Z words


@pytest.mark.parametrize(
    ("line", "expected", "motion"),
    [
        ("G0 Z20", ProgramZMove(20.0), None),
        ("G00 Z5.0", ProgramZMove(5.0), None),
        ("G53 G0 Z-2", ProgramZMove(-2.0, machine=True), None),
        ("G1 Z3.8 F600", ProgramZMove(3.8, 600.0), "F600"),
        ("G90 G0 Z10", ProgramZMove(10.0), "G90"),
        ("G0 X10 Y20 Z5", ProgramZMove(5.0), "G0 X10 Y20"),
    ],
)
def test_z_words_go_to_the_board(line: str, expected: Command, motion: str | None) -> None:
    result = parsed(line, RELAY)
    assert result.commands == (expected,)
    assert result.motion == motion


@pytest.mark.parametrize(
    ("line", "word"),
    [
        ("G1 Z3", "G1 Z"),  # no F: the daemon does not track the modal feed
        ("G1 Z3 F0", "G1 F"),
        ("G2 X5 Y5 I2 Z3", "G2 Z"),
        ("G28 Z0", "G28 Z"),
        ("Z5", "Z5"),  # modal motion mode is not tracked by the daemon
        ("G0 Z5 Z6", "Z"),
    ],
)
def test_z_words_it_cannot_honour_are_refused_naming_them(line: str, word: str) -> None:
    assert error(line, RELAY).word == word


def test_a_line_without_z_is_untouched() -> None:
    result = parsed("G1 X10 Y5 F2400", RELAY)
    assert result.commands == ()
    assert result.motion == "G1 X10 Y5 F2400"
