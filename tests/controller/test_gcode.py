"""G-code lines and MQTT requests into plasma commands: every form in the seed documents.

The seeds are the MASSO G200 post-processor requirements (with a full sample program), the
RosettaCNC G100 function list and the LinuxCNC PlasmaC description. Errors must name the
offending word; no input may raise anything but CommandError.
"""

from __future__ import annotations

import contextlib
import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dthc_bridge.controller.commands import (
    Command,
    CommandError,
    CutParams,
    CycleStart,
    LegacyMode,
    OperatingMode,
    PlasmaMode,
    ProbeAndStart,
    ProgramZMove,
    ResumePoint,
    SelectCurrent,
    SetCutParams,
    ThcEnable,
    ThcMode,
    TorchStart,
    TorchStop,
    VelocityReduction,
    VoltageAdjust,
    VoltageMode,
)
from dthc_bridge.controller.gcode import ParsedLine, parse_line
from dthc_bridge.requests import COMMAND_REQUESTS, parse_request

SEEDS = Path("/work/shared/seeds")
MASSO_SEED = SEEDS / "000_4b3df242e51ae6b5.txt"
VENDORED_SAMPLE = (
    Path(__file__).parents[2] / "dthc_tools" / "demo" / "programs" / "masso_sample.ngc"
)


def commands(line: str, line_number: int | None = None) -> tuple[Command, ...]:
    return parse_line(line, line_number=line_number).commands


def error(line: str) -> CommandError:
    with pytest.raises(CommandError) as info:
        parse_line(line)
    return info.value


def extract_sample(text: str) -> list[str]:
    """The sample program: from "(Plasma Sample File)" to its M30 (program end), verbatim."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "(Plasma Sample File)")
    end = next(i for i in range(start, len(lines)) if re.search(r"\bM30\b", lines[i]))
    return lines[start : end + 1]


def sample_program() -> list[str]:
    """The sample read from the MASSO seed; the vendored copy where the seeds are absent."""
    source = MASSO_SEED if MASSO_SEED.exists() else VENDORED_SAMPLE
    return extract_sample(source.read_text(encoding="utf-8"))


# --------------------------------------------------------------------------- MASSO

SAMPLE_G200 = SetCutParams(
    CutParams(
        touch_feed_mm_min=200.0,
        pierce_height_mm=10.0,
        pierce_delay_ms=500.0,
        cut_height_mm=3.5,
        cut_voltage_v=116.0,
        anti_dive_percent=0.0,
        ohmic=False,
        stop_after_pierce=False,
    )
)


def test_masso_sample_program_gives_the_plasma_command_sequence() -> None:
    """Every line of the MASSO sample parses, and its plasma commands come out in order."""
    program = sample_program()
    assert len(program) == 39
    sequence = [cmd for line in program for cmd in parse_line(line).commands]
    safe_z = ProgramZMove(20.0)  # "G00 Z20.000 (Safe Z move)": Z belongs to the board
    assert sequence == [
        PlasmaMode(112),
        SAMPLE_G200,
        safe_z,
        TorchStart(),
        ThcEnable(True, z_feed_mm_min=600.0),
        ThcEnable(False),
        TorchStop(),
        safe_z,
        TorchStart(),
        ThcEnable(True, z_feed_mm_min=600.0),
        ThcEnable(False),
        TorchStop(),
        safe_z,
    ]
    assert PlasmaMode(112).enabled


def test_masso_sample_keeps_n_numbers_comments_and_motion_per_line() -> None:
    """Each sample line keeps its N number and comment; non-plasma words pass through as written."""
    for line in sample_program():
        parsed = parse_line(line)
        n_match = re.match(r"N(\d+)", line)
        assert parsed.line_number == (int(n_match.group(1)) if n_match else None), line
        comment = re.search(r"\((.*)\)", line)
        assert parsed.comment == (comment.group(1).strip() if comment else None), line
        if not parsed.commands:
            rest = re.sub(r"^N\d+\s*", "", re.sub(r"\(.*\)", "", line)).strip()
            assert parsed.motion == (rest or None), line
        else:
            assert parsed.motion is None, line


def test_masso_sample_arc_line_passes_through_untouched() -> None:
    """The sample's G03 arc reaches the motion backend exactly as written, without N12."""
    parsed = parse_line("N12 G03 X60.000 Y85.000 I-10.000 J0.000 F3000")
    assert parsed == ParsedLine(motion="G03 X60.000 Y85.000 I-10.000 J0.000 F3000", line_number=12)


def test_vendored_sample_is_the_seed_sample_verbatim() -> None:
    """The copy used when the seeds are absent is the seed's sample program, line for line."""
    if not MASSO_SEED.exists():
        pytest.skip("seed documents are not available here")
    seed = extract_sample(MASSO_SEED.read_text(encoding="utf-8"))
    assert extract_sample(VENDORED_SAMPLE.read_text(encoding="utf-8")) == seed


def test_g200_seed_example_maps_every_parameter() -> None:
    """N10 G200 F150 P5.5 D500 C3.1 V116 A90 O1 S0: F P D(ms) C V A O S land in CutParams."""
    parsed = parse_line("N10 G200 F150 P5.5 D500 C3.1 V116 A90 O1 S0")
    assert parsed == ParsedLine(
        commands=(
            SetCutParams(
                CutParams(
                    touch_feed_mm_min=150.0,
                    pierce_height_mm=5.5,
                    pierce_delay_ms=500.0,
                    cut_height_mm=3.1,
                    cut_voltage_v=116.0,
                    anti_dive_percent=90.0,
                    ohmic=True,
                    stop_after_pierce=False,
                )
            ),
        ),
        line_number=10,
    )


def test_g200_d_is_milliseconds_and_s1_stops_after_pierce() -> None:
    """D2000 is 2 s written in milliseconds; S1 asks for the stop after pierce; O0 is float."""
    (cmd,) = commands("G200 F150 P4 D2000 C1.5 V120 A50 O0 S1")
    assert isinstance(cmd, SetCutParams)
    assert cmd.params.pierce_delay_ms == 2000.0
    assert cmd.params.stop_after_pierce is True
    assert cmd.params.ohmic is False


def test_g200_v0_means_auto_voltage() -> None:
    """V0 is MASSO's auto voltage: no fixed cut voltage."""
    (cmd,) = commands("G200 F150 P5.5 D500 C3.1 V0 A90 O1 S0")
    assert isinstance(cmd, SetCutParams)
    assert cmd.params.cut_voltage_v is None


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G200 S1", CutParams(stop_after_pierce=True)),
        ("G200 V130", CutParams(cut_voltage_v=130.0)),
        ("G200 P4 C1", CutParams(pierce_height_mm=4.0, cut_height_mm=1.0)),
        ("G200 O1", CutParams(ohmic=True)),
    ],
)
def test_g200_missing_parameters_take_the_cutparams_defaults(
    line: str, expected: CutParams
) -> None:
    """A G200 with some parameters sets them and leaves every other one at its default."""
    assert commands(line) == (SetCutParams(expected),)


@pytest.mark.parametrize("line", ["G200", "N3 G200", "g200 (legacy)", "G200 ; old file"])
def test_bare_g200_is_legacy_mode(line: str) -> None:
    """G200 without parameters switches to legacy mode, comments or not."""
    assert commands(line) == (LegacyMode(),)


@pytest.mark.parametrize(
    ("line", "tool"),
    [
        ("N10 T112 M06", 112),
        ("T112 M6", 112),
        ("T112M6", 112),
        ("M6 T112", 112),
        ("t112 m06", 112),
        ("T1 M6", 1),
        ("T0 M06", 0),
    ],
)
def test_tool_change_enters_or_leaves_plasma_mode(line: str, tool: int) -> None:
    """T112 M6 is one command entering plasma mode; any other tool leaves it."""
    assert commands(line) == (PlasmaMode(tool),)
    assert PlasmaMode(tool).enabled is (tool == 112)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("M3", TorchStart()),
        ("M03", TorchStart()),
        ("m3", TorchStart()),
        ("M5", TorchStop()),
        ("M05", TorchStop()),
        ("N10 M667 F500", ThcEnable(True, z_feed_mm_min=500.0)),
        ("M667", ThcEnable(True)),
        ("M666", ThcEnable(False)),
    ],
)
def test_masso_m_codes(line: str, expected: Command) -> None:
    """M3/M03 start, M5/M05 stop, M667 [F] THC on with its Z feed, M666 THC off."""
    assert commands(line) == (expected,)


def test_several_plasma_words_keep_line_order() -> None:
    """M3 M667 F600 is two commands in that order; reversed on the line, reversed in the result."""
    assert commands("M3 M667 F600") == (TorchStart(), ThcEnable(True, z_feed_mm_min=600.0))
    assert commands("M667 F600 M3") == (ThcEnable(True, z_feed_mm_min=600.0), TorchStart())


# --------------------------------------------------------------------------- RosettaCNC G100


def test_g100_p0_is_a_resume_point_at_the_senders_line() -> None:
    """P0 records the caller's line number; without one, the N word; without both, none."""
    assert commands("G100 P0", line_number=42) == (ResumePoint(42),)
    assert commands("N7 G100 P0") == (ResumePoint(7),)
    assert commands("G100 P0") == (ResumePoint(None),)


def test_g100_p4_sets_the_plasma_current() -> None:
    """P4 A<amperes> is the current set point."""
    assert commands("G100 P4 A45") == (SelectCurrent(45.0),)
    assert commands("G100 P4 A400") == (SelectCurrent(400.0),)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G100 P5 A0 B120", VoltageMode(False, 120.0)),
        ("G100 P5 A1", VoltageMode(True)),
        ("G100 P5 A1 B0", VoltageMode(True)),  # B is optional (and unused) with A1
    ],
)
def test_g100_p5_selects_fixed_or_auto_voltage(line: str, expected: VoltageMode) -> None:
    """P5 A0 B<volts> is a fixed voltage, P5 A1 auto-acquired after torch activation."""
    assert commands(line) == (expected,)


@pytest.mark.parametrize(
    ("suffix", "mode"), [("", 0), (" I0", 0), (" I1", 1), (" I2", 2), (" I3", 3)]
)
def test_g100_p6_probe_and_start_in_each_mode(suffix: str, mode: int) -> None:
    """P6 A B C D E F H [I]: feeds, touch target, heights, delays in seconds, and the I mode."""
    line = "G100 P6 A1000 B-60 C300 D3.8 E0.5 F3 H1.5" + suffix
    assert commands(line) == (
        ProbeAndStart(
            z_feed_mm_min=1000.0,
            touch_target_z_mm=-60.0,
            touch_feed_mm_min=300.0,
            pierce_height_mm=3.8,
            pierce_delay_s=0.5,
            arc_ok_timeout_s=3.0,
            cut_height_mm=1.5,
            mode=mode,
        ),
    )


def test_g100_p6_accepts_zero_pierce_delay_and_any_word_order() -> None:
    """E0 (no pierce delay) is allowed; parameter order on the line does not matter."""
    (cmd,) = commands("G100 H1.5 F3 E0 D3.8 C300 B-60 A1000 I1 P6")
    assert isinstance(cmd, ProbeAndStart)
    assert cmd.pierce_delay_s == 0.0
    assert cmd.mode == 1


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G100 P7 A1", ThcEnable(True)),
        ("G100 P7 A0", ThcEnable(False)),
        ("g100p7a1", ThcEnable(True)),
    ],
)
def test_g100_p7_switches_the_thc_comparator(line: str, expected: ThcEnable) -> None:
    """P7 A1 turns the THC comparator on, A0 off."""
    assert commands(line) == (expected,)


@pytest.mark.parametrize(
    ("line", "word", "what"),
    [
        ("G100 P1 A1 B2", "G100 P1", "go to a position"),
        ("G100 P2 A4 B1000", "G100 P2", "axis-free movement"),
        ("G100 P2 A6 B-500", "G100 P2", "axis-free movement"),
        ("G100 P2 A4 B0", "G100 P2", "axis-free movement"),
        ("G100 P3 A1 B100 C0 D0", "G100 P3", "continuous axis movement"),
        ("G100 P8 A3", "G100 P8", "lube request"),
        ("G100 P1000 A10", "G100 P1000", "Modbus shared area"),
        ("G100 P1000 A2 B3 C4", "G100 P1000", "Modbus shared area"),
        ("G100 P1000 B3 A2 C4", "G100 P1000", "Modbus shared area"),
    ],
)
def test_g100_machine_functions_are_not_plasma_functions(line: str, word: str, what: str) -> None:
    """P1, P2, P3, P8 and P1000 (the seed's own examples) are refused, saying what they are."""
    err = error(line)
    assert err.word == word
    assert err.reason == f"not a plasma function: {what}"


@pytest.mark.parametrize(
    "line",
    [
        "( © 2020 by RosettaCNC Motion             )",
        "G21 G40 G49 G90 G54 G50 G69",
        "G101 P47 ; Axes X,Y,Z,A,C will be interpolated",
        "G10 L101 P550 V1",
        "G1 X10 ",
        "M2",
        "",
    ],
)
def test_rosetta_example_lines_without_plasma_words_pass_through(line: str) -> None:
    """The non-plasma lines around the RosettaCNC examples go to motion, comments stripped."""
    parsed = parse_line(line)
    assert parsed.commands == ()
    rest = re.sub(r"\(.*\)|;.*", "", line).strip()
    assert parsed.motion == (rest or None)


@pytest.mark.parametrize(
    ("line", "word", "reason"),
    [
        ("G100", "G100 P", "required parameter is missing"),
        ("G100 A1", "G100 P", "required parameter is missing"),  # P is checked first
        ("G100 P9", "G100 P9", "unknown G100 function"),
        ("G100 P4.5 A3", "G100 P", "not a whole number"),
        ("G100 P0 A1", "G100 P0 A", "unknown parameter"),
        ("G100 P4", "G100 P4 A", "required parameter is missing"),
        ("G100 P4 A0", "G100 P4 A", "greater than 0"),
        ("G100 P4 A401", "G100 P4 A", "out of range"),
        ("G100 P5 A0", "G100 P5 B", "required parameter is missing"),
        ("G100 P5 A2", "G100 P5 A", "must be 0 or 1"),
        ("G100 P5 A0 B10", "G100 P5 B", "out of range"),
        ("G100 P6 B-60 C300 D3.8 E0.5 F3 H1.5", "G100 P6 A", "required parameter is missing"),
        ("G100 P6 A1000 C300 D3.8 E0.5 F3 H1.5", "G100 P6 B", "required parameter is missing"),
        ("G100 P6 A1000 B-60 D3.8 E0.5 F3 H1.5", "G100 P6 C", "required parameter is missing"),
        ("G100 P6 A1000 B-60 C300 E0.5 F3 H1.5", "G100 P6 D", "required parameter is missing"),
        ("G100 P6 A1000 B-60 C300 D3.8 F3 H1.5", "G100 P6 E", "required parameter is missing"),
        ("G100 P6 A1000 B-60 C300 D3.8 E0.5 H1.5", "G100 P6 F", "required parameter is missing"),
        ("G100 P6 A1000 B-60 C300 D3.8 E0.5 F3", "G100 P6 H", "required parameter is missing"),
        ("G100 P6 A0 B-60 C300 D3.8 E0.5 F3 H1.5", "G100 P6 A", "greater than 0"),
        ("G100 P6 A1000 B-60 C-1 D3.8 E0.5 F3 H1.5", "G100 P6 C", "greater than 0"),
        ("G100 P6 A1000 B-60 C300 D0 E0.5 F3 H1.5", "G100 P6 D", "greater than 0"),
        ("G100 P6 A1000 B-60 C300 D3.8 E-1 F3 H1.5", "G100 P6 E", "must not be negative"),
        ("G100 P6 A1000 B-60 C300 D3.8 E0.5 F0 H1.5", "G100 P6 F", "greater than 0"),
        ("G100 P6 A1000 B-60 C300 D3.8 E0.5 F3 H-1.5", "G100 P6 H", "greater than 0"),
        ("G100 P6 A1000 B-60 C300 D3.8 E0.5 F3 H1.5 I4", "G100 P6 I", "must be 0, 1, 2 or 3"),
        ("G100 P6 A1000 B-60 C300 D3.8 E0.5 F3 H1.5 I1.5", "G100 P6 I", "must be 0, 1, 2 or 3"),
        ("G100 P7", "G100 P7 A", "required parameter is missing"),
        ("G100 P7 A2", "G100 P7 A", "must be 0 or 1"),
        ("G100 P7 A1 A0", "G100 P7 A", "duplicate parameter"),
        ("G100 P7 P7 A1", "G100 P", "duplicate parameter"),
    ],
)
def test_g100_errors_name_the_word(line: str, word: str, reason: str) -> None:
    """Missing, unknown, duplicate and out-of-range G100 words each name the word."""
    err = error(line)
    assert err.word == word
    assert reason in err.reason


# --------------------------------------------------------------------------- LinuxCNC PlasmaC


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("M62 P2", ThcEnable(False, synchronized=True)),
        ("M63 P2", ThcEnable(True, synchronized=True)),
        ("M64 P2", ThcEnable(False, synchronized=False)),
        ("M65 P2", ThcEnable(True, synchronized=False)),
        ("m65p2", ThcEnable(True, synchronized=False)),
    ],
)
def test_plasmac_m62_to_m65_p2_switch_the_thc(line: str, expected: ThcEnable) -> None:
    """M62/M64 P2 disable, M63/M65 P2 enable; 62/63 with the next motion, 64/65 at once."""
    assert commands(line) == (expected,)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("M67 E3 Q60", VelocityReduction(60.0, synchronized=True)),
        ("M68 E3 Q60", VelocityReduction(60.0, synchronized=False)),
        ("M67 E3 Q100", VelocityReduction(100.0, synchronized=True)),
        ("M68 E3 Q0", VelocityReduction(0.0, synchronized=False)),
        ("M67 Q45.5 E3", VelocityReduction(45.5, synchronized=True)),
    ],
)
def test_plasmac_m67_m68_e3_reduce_velocity(line: str, expected: VelocityReduction) -> None:
    """M67 (synchronized) and M68 (immediate) E3 Q<n> run the cut at n percent."""
    assert commands(line) == (expected,)


@pytest.mark.parametrize(
    ("line", "word", "reason"),
    [
        ("M62 P1", "M62 P1", "not a plasma function of ours"),
        ("M63 P1", "M63 P1", "not a plasma function of ours"),
        ("M64 P0", "M64 P0", "not a plasma function of ours"),
        ("M65", "M65 P", "required parameter is missing"),
        ("M62 P2 Q1", "M62 Q", "unknown parameter"),
        ("M67 E0 Q50", "M67 E0", "not a plasma function of ours"),
        ("M68 E2 Q50", "M68 E2", "not a plasma function of ours"),
        ("M67 Q50", "M67 E", "required parameter is missing"),
        ("M68 E3", "M68 Q", "required parameter is missing"),
        ("M67 E3 Q101", "M67 Q", "out of range"),
        ("M68 E3 Q-1", "M68 Q", "out of range"),
    ],
)
def test_plasmac_errors_name_the_word(line: str, word: str, reason: str) -> None:
    """Other outputs and channels than P2/E3, and bad Q values, are refused by name."""
    err = error(line)
    assert err.word == word
    assert reason in err.reason


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("line", "word", "reason"),
    [
        ("G200 Q5", "G200 Q", "unknown parameter"),
        ("G200 F150 X5", "G200 X", "unknown parameter"),
        ("X5 G200 F150", "G200 X", "unknown parameter"),
        ("M3 P1000", "M3 P", "unknown parameter"),
        ("M666 F500", "M666 F", "unknown parameter"),
        ("T112 M6 P5", "M6 P", "unknown parameter"),
        ("G200 F", "G200 F", "missing value"),
        ("G200 F P5", "G200 F", "missing value"),
        ("G200 Fabc", "G200 F", "missing value"),
        ("G200 P100", "G200 P", "out of range"),
        ("G200 F0", "G200 F", "out of range"),
        ("G200 D-1", "G200 D", "out of range"),
        ("G200 V20", "G200 V", "out of range"),
        ("G200 A101", "G200 A", "out of range"),
        ("G200 F1 F2", "G200 F", "duplicate parameter"),
        ("G200 F1.2.3", "G200 F", "malformed number"),
        ("G200 F1-2", "G200 F", "malformed number"),
        ("G200 O2", "G200 O", "must be 0 or 1"),
        ("G200 S2", "G200 S", "must be 0 or 1"),
        ("G200 O0.5", "G200 O", "must be 0 or 1"),
        ("G200 S-1", "G200 S", "must be 0 or 1"),
        ("M667 F0", "M667 F", "greater than 0"),
        ("M6", "M6 T", "required parameter is missing"),
        ("T1 T2 M6", "M6 T", "duplicate parameter"),
        ("T112 M6 M6", "M6", "more than one tool change"),
        ("T1.5 M6", "M6 T", "not a whole number"),
        ("T-1 M6", "M6 T", "not a tool number"),
        ("G200 5", "5", "number without a letter"),
        ("150", "150", "number without a letter"),
        ("G200 F150 (open", "(", "not closed"),
        ("G200 F150)", ")", "without '('"),
        ("G1 X#1", "#", "unexpected character"),
        ("G1 X[1+2]", "[", "unexpected character"),
        ("G1 X1.2.3", "X", "malformed number"),
        ("G", "G", "missing value"),
        ("N1 N2 M3", "N", "more than one line number"),
        ("N1.5 M3", "N", "not a whole number"),
        ("N-3 M3", "N", "not a line number"),
        ("G200 F1" + "0" * 400, "G200 F", "too large"),
    ],
)
def test_errors_name_the_offending_word(line: str, word: str, reason: str) -> None:
    """Unknown word, missing value, out of range, duplicate, malformed number, O2/S2, stray text."""
    err = error(line)
    assert err.word == word
    assert reason in err.reason
    assert str(err).startswith(f"{word}: ")


def test_unknown_g200_word_message_reads_well() -> None:
    """The message for G200 Q5 is exactly "G200 Q: unknown parameter"."""
    assert str(error("G200 Q5")) == "G200 Q: unknown parameter"


# --------------------------------------------------------------------------- tokens and text


@pytest.mark.parametrize(
    ("compact", "spaced"),
    [
        ("g200f150p5.5", "G200 F150 P5.5"),
        ("G200F150P5.5D500C3.1V116A90O1S0", "G200 F150 P5.5 D500 C3.1 V116 A90 O1 S0"),
        ("N10G200 F150", "N10 G200 F150"),
        ("G200 F 150  P 5.5", "G200 F150 P5.5"),
        ("G200\tF+150\tC.5", "G200 F150 C0.5"),
        ("M0667 F0600.0", "M667 F600"),
        ("T112M06", "T112 M6"),
        (
            "g100 p6 a1000 b-60 c300 d3.8 e.5 f3 h1.5 i1",
            "G100 P6 A1000 B-60 C300 D3.8 E0.5 F3 H1.5 I1",
        ),
        ("M3M667F600", "M3 M667 F600"),
        ("G200 F150\r\n", "G200 F150"),
    ],
)
def test_compact_and_lower_case_forms_parse_like_the_spaced_form(compact: str, spaced: str) -> None:
    """Blanks are optional, letters case-insensitive, numbers may carry sign, zeros and decimals."""
    assert parse_line(compact).commands == parse_line(spaced).commands
    assert parse_line(compact).commands != ()


def test_comments_are_stripped_kept_and_never_parsed() -> None:
    """Parenthesised comments anywhere and ';' to the end of line are kept, not interpreted."""
    parsed = parse_line("N7 G200 (set) F150 (fast) P5.5 ; M3 is not a command here")
    assert parsed.commands == (
        SetCutParams(CutParams(touch_feed_mm_min=150.0, pierce_height_mm=5.5)),
    )
    assert parsed.comment == "set; fast; M3 is not a command here"
    assert parse_line("(M3 M667)") == ParsedLine(comment="M3 M667")
    assert parse_line("M5;M3") == ParsedLine(commands=(TorchStop(),), comment="M3")
    assert parse_line("()").comment == ""


def test_line_number_comes_from_n_else_from_the_caller() -> None:
    """An N word sets line_number; without one the caller's number is kept."""
    assert parse_line("N10 M3", line_number=99).line_number == 10
    assert parse_line("M3", line_number=99).line_number == 99
    assert parse_line("M3").line_number is None


@pytest.mark.parametrize(
    ("line", "motion"),
    [
        ("G21", "G21"),
        ("G90 G17", "G90 G17"),
        ("N1 G21", "G21"),
        ("G0 X1 Y2", "G0 X1 Y2"),
        ("g1x10y20f3000", "g1x10y20f3000"),
        ("X10 Y20", "X10 Y20"),
        ("T5", "T5"),
        ("M30", "M30"),
        ("M8", "M8"),
        ("G10 L2 P1 X0 Y0", "G10 L2 P1 X0 Y0"),
        ("G200.5", "G200.5"),
        ("G1  X10\tY5 ", "G1  X10\tY5"),
        ("N3G1X1(c)Y2", "G1X1 Y2"),
    ],
)
def test_lines_without_plasma_words_go_to_motion_unchanged(line: str, motion: str) -> None:
    """Motion and modal words, T without M6 and other M codes pass through as written."""
    parsed = parse_line(line)
    assert parsed.commands == ()
    assert parsed.motion == motion


def test_motion_and_plasma_words_on_one_line_split_by_owner() -> None:
    """Parameters belong to the G/M word before them; motion keeps its F, M667 gets none."""
    parsed = parse_line("N5 G1 X10 F3000 M667")
    assert parsed.commands == (ThcEnable(True),)
    assert parsed.motion == "G1 X10 F3000"
    parsed = parse_line("G1X10 M3")
    assert parsed.commands == (TorchStart(),)
    assert parsed.motion == "G1X10"
    parsed = parse_line("M3 G1 X10")
    assert parsed.commands == (TorchStart(),)
    assert parsed.motion == "G1 X10"
    parsed = parse_line("G0 X1 T112 M6")
    assert parsed.commands == (PlasmaMode(112),)
    assert parsed.motion == "G0 X1"
    parsed = parse_line("G100 P7 A1 G1 X5")
    assert parsed.commands == (ThcEnable(True),)
    assert parsed.motion == "G1 X5"
    parsed = parse_line("F600 M667")
    assert parsed == ParsedLine(commands=(ThcEnable(True, z_feed_mm_min=600.0),))


@pytest.mark.parametrize("line", ["", "   ", "%", "N5", "N5 (Plasma)", "; only a comment"])
def test_empty_lines_have_no_commands_and_no_motion(line: str) -> None:
    """Blank lines, the % delimiter, a bare N word and comment-only lines carry nothing."""
    parsed = parse_line(line)
    assert parsed.commands == ()
    assert parsed.motion is None


# --------------------------------------------------------------------------- robustness


@settings(max_examples=400, deadline=None)
@given(st.text(max_size=60))
def test_arbitrary_text_raises_only_command_error(text: str) -> None:
    """Whatever the sender sends, parse_line either parses it or raises CommandError."""
    with contextlib.suppress(CommandError):
        parse_line(text)


GCODEISH = st.text(alphabet="GMTNFPDCVAOSEQIHBXYZ0123456789.-+ ()%;\tgmt", max_size=40)


@settings(max_examples=400, deadline=None)
@given(GCODEISH)
def test_gcode_like_text_raises_only_command_error(text: str) -> None:
    """Near-G-code (the alphabet of plasma lines) parses or raises CommandError, never else."""
    try:
        parsed = parse_line(text)
    except CommandError:
        return
    assert parsed.motion is None or parsed.motion.strip() == parsed.motion


@settings(max_examples=150, deadline=None)
@given(
    st.permutations(["F150", "P5.5", "D500", "C3.1", "V116", "A90", "O1", "S0"]),
    st.sampled_from(["", " ", "  "]),
)
def test_g200_word_order_and_spacing_do_not_matter(words: list[str], sep: str) -> None:
    """G200 parameters in any order, with or without blanks, give the same cut parameters."""
    assert commands("G200" + sep + sep.join(words)) == commands(
        "G200 F150 P5.5 D500 C3.1 V116 A90 O1 S0"
    )


# --------------------------------------------------------------------------- MQTT requests


@pytest.mark.parametrize(
    ("name", "args", "expected"),
    [
        ("torch_up", {}, VoltageAdjust(1.0)),
        ("torch_down", {}, VoltageAdjust(-1.0)),
        ("torch_up", {"volts": 2.5}, VoltageAdjust(2.5)),
        ("torch_down", {"volts": 3}, VoltageAdjust(-3.0)),
        ("cycle_start", {}, CycleStart()),
        ("cycle_start", {"transaction": "abc", "deadline_ms": 500}, CycleStart()),
        ("operating_mode", {"mode": 0}, OperatingMode(ThcMode.VOLTAGE_ONLY)),
        ("operating_mode", {"mode": 1}, OperatingMode(ThcMode.ARC_OK_AND_VOLTAGE)),
        ("operating_mode", {"mode": 2}, OperatingMode(ThcMode.ARC_OK_AND_UPDOWN)),
        ("velocity_reduction", {"percent": 60}, VelocityReduction(60.0, synchronized=False)),
    ],
)
def test_requests_become_commands(name: str, args: dict[str, object], expected: Command) -> None:
    """Torch up/down, cycle start, operating mode and velocity reduction requests map 1:1."""
    assert parse_request(name, args) == expected


@pytest.mark.parametrize(
    ("name", "args", "word"),
    [
        ("fire", {}, "fire"),
        ("", {}, "request"),
        ("torch_up", {"volts": 0}, "torch_up volts"),
        ("torch_down", {"volts": -1}, "torch_down volts"),
        ("torch_up", {"volts": 51}, "torch_up volts"),
        ("torch_up", {"volts": "1"}, "torch_up volts"),
        ("torch_up", {"volts": float("nan")}, "torch_up volts"),
        ("torch_up", {"step": 1}, "torch_up step"),
        ("cycle_start", {"now": True}, "cycle_start now"),
        ("operating_mode", {}, "operating_mode mode"),
        ("operating_mode", {"mode": 3}, "operating_mode mode"),
        ("operating_mode", {"mode": 1.5}, "operating_mode mode"),
        ("operating_mode", {"mode": True}, "operating_mode mode"),
        ("operating_mode", {"mode": None}, "operating_mode mode"),
        ("velocity_reduction", {}, "velocity_reduction percent"),
        ("velocity_reduction", {"percent": 101}, "velocity_reduction percent"),
        ("velocity_reduction", {"percent": -5}, "velocity_reduction percent"),
        ("thc_hold", {}, "thc_hold on"),
        ("thc_hold", {"on": 1}, "thc_hold on"),
        ("abort", {"now": True}, "abort now"),
    ],
)
def test_bad_requests_name_the_argument(name: str, args: dict[str, object], word: str) -> None:
    """Unknown requests, unknown or missing arguments and bad values raise CommandError by name."""
    with pytest.raises(CommandError) as info:
        parse_request(name, args)
    assert info.value.word == word


def test_request_names_are_published() -> None:
    """The gateway can list exactly the requests the parser understands."""
    assert {
        "torch_up",
        "torch_down",
        "cycle_start",
        "operating_mode",
        "velocity_reduction",
        "rearm",
        "ohmic_test",
        "probe_test",
        "jog_z",
        "material_select",
        "thc_hold",
        "thc",
        "abort",
        "height_override",
    } == COMMAND_REQUESTS
