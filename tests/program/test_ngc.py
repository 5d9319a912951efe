"""The NGC evaluator: hand-written QtPlasmaC programs in, plain G-code lines out."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dthc_bridge.program.ngc import EvaluatedLine, NgcError, NgcProgram, format_number


def run(source: str, **kwargs: object) -> list[str]:
    """The output texts of a program given as one string."""
    program = NgcProgram(source.splitlines(), **kwargs)  # type: ignore[arg-type]
    return [line.text for line in program.evaluate()]


def value(expression: str) -> str:
    """What ``X<expression>`` evaluates to, as it would be sent."""
    (line,) = run(f"G0 X{expression}")
    return line.removeprefix("G0 X")


def error(source: str, **kwargs: object) -> NgcError:
    """The error evaluating a program raises."""
    program = NgcProgram(source.splitlines(), **kwargs)  # type: ignore[arg-type]
    with pytest.raises(NgcError) as caught:
        list(program.evaluate())
    return caught.value


HOLES = """\
%
(o=0, ph=3.1, pd=0.1, ch=0.75, fr=3000)
#<x_offset> = 10
#<kerf> = 1.5
#2 = 3  ; holes
G21 G40 G64P0.1
G41.1 D[#<kerf> * 0.5]
o100 repeat [#2]
  G0 X[35.92 + #<x_offset>] Y[20 - #<x_offset> / 2]
  M3 $0 S1
  G1 X[35.92 + #<x_offset> + 5] F#<_hal[plasmac.cut-feed-rate]>
  M5 $-1
  #<x_offset> = [#<x_offset> + 25]
o100 endrepeat
G40
M2
%
"""


def test_a_hole_pattern_is_unrolled_into_plain_lines() -> None:
    program = NgcProgram(HOLES.splitlines(), hal={"plasmac.cut-feed-rate": 3000.0}.__getitem__)
    assert list(program.evaluate()) == [
        EvaluatedLine(2, "(o=0, ph=3.1, pd=0.1, ch=0.75, fr=3000)"),
        EvaluatedLine(5, "; holes"),
        EvaluatedLine(6, "G21 G40 G64P0.1"),
        EvaluatedLine(7, "G41.1 D0.75"),
        EvaluatedLine(9, "G0 X45.92 Y15"),
        EvaluatedLine(10, "M3 $0 S1"),
        EvaluatedLine(11, "G1 X50.92 F3000"),
        EvaluatedLine(12, "M5 $-1"),
        EvaluatedLine(9, "G0 X70.92 Y2.5"),
        EvaluatedLine(10, "M3 $0 S1"),
        EvaluatedLine(11, "G1 X75.92 F3000"),
        EvaluatedLine(12, "M5 $-1"),
        EvaluatedLine(9, "G0 X95.92 Y-10"),
        EvaluatedLine(10, "M3 $0 S1"),
        EvaluatedLine(11, "G1 X100.92 F3000"),
        EvaluatedLine(12, "M5 $-1"),
        EvaluatedLine(15, "G40"),
        EvaluatedLine(16, "M2"),
    ]
    assert program.get("x_offset") == 85.0
    assert program.get("#<X_Offset>") == 85.0
    assert program.get("2") == 3.0


def test_plain_lines_and_comments_pass_through_verbatim() -> None:
    source = """\
(o=0, ph=3.1, pd=0.1, ch=0.75, fr=3000)
(a comment with #1 [1+ = $ and #<nope> in it)
G1X10Y5 (cut) F[2 * 1000]
N120 G1 X10.000 Y-5 ; #<not> evaluated [
M3 $0 S1
M5 $-1
#1 = 4 (kept after an assignment)
"""
    assert run(source) == [
        "(o=0, ph=3.1, pd=0.1, ch=0.75, fr=3000)",
        "(a comment with #1 [1+ = $ and #<nope> in it)",
        "G1 X10 Y5 (cut) F2000",
        "N120 G1 X10.000 Y-5 ; #<not> evaluated [",
        "M3 $0 S1",
        "M5 $-1",
        "(kept after an assignment)",
    ]


def test_blank_percent_assignment_and_oword_lines_give_no_output() -> None:
    source = "%\n\n   \n#<a> = 1\n#2=[#<a> + 1]\no1 if [#2 EQ 2]\nG0 X#2\no1 endif\n%\n"
    program = NgcProgram(source.splitlines())
    assert list(program.evaluate()) == [EvaluatedLine(7, "G0 X2")]


def test_words_take_spaces_signs_brackets_and_parameters() -> None:
    source = "#1 = 2\n#<x offset> = 3\nG1 X [1 + 2] Y-#1 Z+#1 A-[#1 * 2] B#<xoffset> C- SIN[90]"
    assert run(source) == ["G1 X3 Y-2 Z2 A-4 B3 C-1"]


def test_a_lines_assignments_read_the_values_from_before_the_line() -> None:
    source = "#1 = 1\n#1 = 5 #2 = #1 G0 X#1\nG0 X#1 Y#2"
    assert run(source) == ["G0 X1", "G0 X5 Y1"]
    exc = error("#<a> = 1 #<b> = [#<a> + 1]")  # #<a> is set only after the line
    assert (exc.text, exc.reason) == ("#<a>", "parameter is not set")


def test_parameter_indirection_and_exists() -> None:
    source = """\
#1 = 2
#2 = 7
G0 X#[#1] Y##1 Z#[1 + 1]
#<set> = 0
G0 X[EXISTS[#<set>]] Y[EXISTS[#<unset>]] Z[EXISTS[#<_value>]]
"""
    assert run(source) == ["G0 X7 Y7 Z7", "G0 X1 Y0 Z1"]


def test_unset_numbered_parameters_read_zero() -> None:
    assert run("G0 X#1 Y#31 Z#4999") == ["G0 X0 Y0 Z0"]


def test_a_subroutine_gets_its_arguments_and_returns_a_value() -> None:
    source = """\
#<_depth> = 0.5
o<hole> call [10] [20] [3]
o<hole> call [40] [20] [4]
G0 X#<_value> Y#1
M2
o<hole> sub
  #<r> = [#3 / 2]
  G0 X[#1 - #<r>] Y#2 Z#<_depth>
  o<hole> return [#1 + #2]
o<hole> endsub
"""
    program = NgcProgram(source.splitlines())
    out = list(program.evaluate())
    assert out == [
        EvaluatedLine(8, "G0 X8.5 Y20 Z0.5"),
        EvaluatedLine(8, "G0 X38 Y20 Z0.5"),
        EvaluatedLine(4, "G0 X60 Y0"),
        EvaluatedLine(5, "M2"),
    ]
    assert program.get("_value") == 60.0
    assert program.get("_value_returned") == 1.0
    assert program.get("r") is None  # the sub's local went with its call


def test_a_sub_sees_globals_but_not_the_callers_locals() -> None:
    source = """\
o<s> sub
  G0 X#<_g>
  G0 X#<mine>
o<s> endsub
#<_g> = 1
#<mine> = 2
o<s> call
"""
    exc = error(source)
    assert (exc.line, exc.text) == (3, "#<mine>")
    assert "not set" in exc.reason


def test_numbered_locals_are_restored_after_a_call() -> None:
    source = """\
o1 sub
  #1 = 99
  #31 = 31
o1 endsub
#1 = 5
o1 call [7]
G0 X#1 Y#31
"""
    assert run(source) == ["G0 X5 Y31"]


def test_endsub_with_a_value_and_nested_calls() -> None:
    source = """\
o<twice> sub
  o<twice> endsub [#1 * 2]
o<outer> sub
  o<twice> call [#1 + 1]
  o<outer> return [#<_value> + 100]
o<outer> endsub
o<outer> call [4]
G0 X#<_value>
"""
    assert run(source) == ["G0 X110"]


@pytest.mark.parametrize(
    ("size", "expected"),
    [(150, "(big)"), (75, "(medium)"), (10, "(small)"), (50, "(small)")],
)
def test_if_elseif_else(size: int, expected: str) -> None:
    source = f"""\
#<size> = {size}
O<s> IF [#<size> GT 100]
  (big)
o<S> ElseIf [#<size> GT 50]
  (medium)
o<s> else
  (small)
o<s> endif
"""
    assert run(source) == [expected]


def test_while_with_break_and_continue() -> None:
    source = """\
#1 = 0
o2 while [1]
  #1 = [#1 + 1]
  o3 if [#1 EQ 2]
    o2 continue
  o3 endif
  o4 if [#1 GE 4]
    o2 break
  o4 endif
  G0 X#1
o2 endwhile
G0 Y#1
"""
    assert run(source) == ["G0 X1", "G0 X3", "G0 Y4"]


def test_do_while_runs_its_body_at_least_once() -> None:
    source = """\
#1 = 10
o5 do
  G0 X#1
  #1 = [#1 + 1]
o5 while [#1 LT 3]
o6 do
  #1 = [#1 - 5]
  G0 Y#1
o6 while [#1 GT 0]
"""
    assert run(source) == ["G0 X10", "G0 Y6", "G0 Y1", "G0 Y-4"]


def test_break_out_of_a_repeat_loop_is_refused_as_linuxcnc_refuses_it() -> None:
    source = """\
#1 = 0
o1 repeat [3]
  o2 repeat [2]
    #1 = [#1 + 1]
    o3 if [#1 EQ 5]
      o1 break
    o3 endif
    G0 X#1
  o2 endrepeat
o1 endrepeat
o4 repeat [0]
  G0 Y1
o4 endrepeat
"""
    with pytest.raises(NgcError, match="works in while and do loops, not in repeat"):
        run(source)


def test_m2_and_m30_end_the_program_even_inside_a_sub() -> None:
    assert run("G0 X1\nM30\nG0 X2") == ["G0 X1", "M30"]
    source = "o<end> sub\n  M2\no<end> endsub\no<end> call\nG0 X2\n"
    program = NgcProgram(source.splitlines())
    assert [line.text for line in program.evaluate()] == ["M2"]
    assert program.get("1") is None  # back at the top level's frame


def test_hal_reads_are_lazy_and_see_what_the_caller_did() -> None:
    """The caller selects a material on line k; line k+1's feed rate must be the new one."""
    pins = {"plasmac.cut-feed-rate": 4000.0}
    reads: list[str] = []

    def hal(pin: str) -> float:
        reads.append(pin)
        return pins[pin]

    source = """\
F#<_hal[plasmac.cut-feed-rate]>
M190 P3
M66 P3 L3 Q1
G1 X10 F#<_hal[plasmac.cut-feed-rate]>
"""
    lines = NgcProgram(source.splitlines(), hal=hal).evaluate()
    assert next(lines).text == "F4000"
    assert next(lines).text == "M190 P3"
    pins["plasmac.cut-feed-rate"] = 2500.0  # what selecting material 3 does
    assert reads == ["plasmac.cut-feed-rate"]  # nothing read ahead
    assert next(lines).text == "M66 P3 L3 Q1"
    assert next(lines).text == "G1 X10 F2500"
    assert next(lines, None) is None


def test_a_failing_hal_read_names_the_pin_and_the_line() -> None:
    def hal(pin: str) -> float:
        raise KeyError(pin)

    exc = error("G0 X1\nF#<_hal[plasmac.nope]>", hal=hal)
    assert (exc.line, exc.text) == (2, "#<_hal[plasmac.nope]>")
    assert "plasmac.nope" in exc.reason


def test_get_is_case_insensitive_and_none_when_unset() -> None:
    program = NgcProgram(["#<keep-z-motion> = 1", "#<_Global> = 2", "#40 = 3"])
    assert program.get("keep-z-motion") is None  # nothing has run yet
    assert list(program.evaluate()) == []
    assert program.get("Keep-Z-Motion") == 1.0
    assert program.get("_global") == 2.0
    assert program.get("40") == 3.0
    assert program.get("missing") is None
    assert program.get("7") is None


def test_each_evaluate_starts_afresh() -> None:
    program = NgcProgram(["#<_n> = [EXISTS[#<_n>] * 10 + 1]", "G0 X#<_n>"])
    assert [line.text for line in program.evaluate()] == ["G0 X1"]
    assert [line.text for line in program.evaluate()] == ["G0 X1"]


@pytest.mark.parametrize(
    ("expression", "expected"),
    [
        ("[35.92 + 10]", "45.92"),
        ("[1 / 3]", "0.333333"),
        ("[2 + 3 * 4]", "14"),
        ("[[2 + 3] * 4]", "20"),
        ("[2 * 3 ** 2]", "18"),
        ("[2 ** 3 ** 2]", "64"),  # left to right, as LinuxCNC
        ("[-2 ** 2]", "4"),  # the sign belongs to the value
        ("[10 - 4 - 3]", "3"),
        ("[7 MOD 3]", "1"),
        ("[-7 mod 3]", "2"),
        ("[1 + 2 EQ 3]", "1"),
        ("[1 EQ 1.00001]", "1"),
        ("[1 NE 1.00001]", "0"),
        ("[2 GT 1 AND 1 LT 2]", "1"),
        ("[0 OR 0]", "0"),
        ("[1 XOR 1]", "0"),
        ("[3 GE 3]", "1"),
        ("[3 LE 2]", "0"),
        ("[1LTEXP[1]]", "1"),
        ("ABS[-1.5]", "1.5"),
        ("ACOS[0.5]", "60"),
        ("ASIN[1]", "90"),
        ("ATAN[1]/[1]", "45"),
        ("ATAN[1]/[-1]", "135"),
        ("COS[60]", "0.5"),
        ("EXP[0]", "1"),
        ("FIX[-2.5]", "-3"),
        ("FUP[2.1]", "3"),
        ("ROUND[2.5]", "3"),
        ("ROUND[-2.5]", "-3"),
        ("LN[1]", "0"),
        ("sin[30]", "0.5"),
        ("SQRT[16]", "4"),
        ("TAN[45]", "1"),
        ("[-0]", "0"),
        ("[1e0]", None),
    ],
)
def test_expressions(expression: str, expected: str | None) -> None:
    if expected is None:
        with pytest.raises(NgcError):
            value(expression)
    else:
        assert value(expression) == expected


def test_format_number() -> None:
    assert format_number(45.92) == "45.92"
    assert format_number(-0.0) == "0"
    assert format_number(-0.0000001) == "0"
    assert format_number(1e20) == "100000000000000000000"
    assert format_number(2.5e-6) == "0.000003"
    assert format_number(-12.0) == "-12"


@given(st.floats(min_value=-1e12, max_value=1e12, allow_nan=False))
def test_format_number_is_compact_and_faithful(x: float) -> None:
    text = format_number(x)
    assert "e" not in text
    assert text != "-0"
    assert math.isclose(float(text), x, abs_tol=5.1e-7, rel_tol=1e-15)
    if "." in text:
        assert not text.endswith(("0", "."))
        assert len(text.split(".")[1]) <= 6


@given(
    st.lists(st.integers(min_value=1, max_value=9), min_size=1, max_size=8),
    st.lists(st.sampled_from(["+", "-", "*", "/"]), min_size=7, max_size=7),
)
def test_arithmetic_precedence(numbers: list[int], ops: list[str]) -> None:
    """* and / bind tighter than + and -, each level left to right (as in arithmetic)."""
    text = str(numbers[0])
    terms = [float(numbers[0])]  # the expected value, as a sum of products
    for number, op in zip(numbers[1:], ops, strict=False):
        text += f" {op} {number}"
        if op in "*/":
            terms[-1] = terms[-1] * number if op == "*" else terms[-1] / number
        else:
            terms.append(number if op == "+" else -number)
    expected = sum(terms)
    assert float(value(f"[{text}]")) == pytest.approx(expected, abs=1e-6)


# Every refusal names what the user wrote.
@pytest.mark.parametrize(
    ("source", "line", "text", "reason"),
    [
        ("G0 X1\no100 endrepeat", 2, "o100 endrepeat", "no open 'o100 repeat'"),
        ("o1 while [1]\no2 endwhile\no1 endwhile", 2, "o2 endwhile", "no open 'o2 while'"),
        ("o1 if [1]\no2 repeat [2]\no1 endif", 3, "o1 endif", "'o2 repeat' (line 2)"),
        ("o1 if [1]\nG0 X1", 1, "o1 if", "no 'o1 endif'"),
        ("o1 else", 1, "o1 else", "no open 'o1 if'"),
        ("o1 if [1]\no1 else\no1 elseif [1]\no1 endif", 3, "o1 elseif", "after 'o1 else'"),
        ("o1 repeat [2]\no2 break\no1 endrepeat", 2, "o2 break", "not inside a loop 'o2'"),
        ("o<a> sub\no<b> return\no<a> endsub", 2, "o<b> return", "not inside 'o<b> sub'"),
        ("o1 if [1]\no<s> sub\no<s> endsub\no1 endif", 2, "o<s> sub", "cannot be defined"),
        ("o<s> sub\no<s> endsub\no<S> sub\no<s> endsub", 3, "o<S> sub", "on line 1"),
        ("o1 while [1]\no1 if [1]\no1 endif\no1 endwhile", 2, "o1 if", "already open"),
        ("G0 X1\no<nope> call [1]", 2, "o<nope> call", "no 'o<nope> sub'"),
        ("o100 for [1]", 1, "o100 for", "unknown o-word keyword"),
        ("o100", 1, "o100", "without a keyword"),
        ("o[1] call", 1, "o[1] call", "needs a number or <name>"),
        ("o1 if", 1, "o1 if", "needs one [condition]"),
        ("o1 if [1] G0 X1", 1, "G0 X1", "unexpected text after 'o1 if'"),
        ("G0 X1 o1 call", 1, "o1 call", "must start"),
        ("G1 X[FOO[1]]", 1, "FOO[1]", "unknown function"),
        ("G1 X[1 FOO 2]", 1, "FOO", "expected an operator"),
        ("G1 X[1 +", 1, "[1 +", "never closed"),
        ("G1 X[[1 + 2]", 1, "[[1 + 2]", "never closed"),
        ("G1 X", 1, "X", "the line ends"),
        ("G1 X1 (cut", 1, "(cut", "never closed"),
        ("G1 #1", 1, "#1", "'=' expected"),
        ("G1 X#<a", 1, "#<a", "never closed"),
        ("G1 X#x", 1, "#x", "'#' needs"),
        ("G1 X&1", 1, "&", "expected a number"),
        ("G1 X1 &", 1, "&", "unexpected character"),
        ("G1 XATAN[1]", 1, "ATAN[1]", "ATAN[y]/[x]"),
        ("G1 X[EXISTS[#1]]", 1, "EXISTS[#1]", "#<name>"),
        ("G1 XSQRT", 1, "SQRT", "needs its argument"),
        ("/G1 X1", 1, "/G1 X1", "block delete"),
        ("M98 P100", 1, "M98", "not supported"),
        ("#1 = 99\nM#1", 2, "M#1", "not supported"),
        ("G0 X1\nG1 X#<undefined_name>", 2, "#<undefined_name>", "parameter is not set"),
        ("G1 X#5161", 1, "#5161", "system parameter not supported"),
        ("#5221 = 1", 1, "#5221", "system parameter not supported"),
        ("G1 X#0", 1, "#0", "out of range"),
        ("G1 X#[1 / 3]", 1, "#[1 / 3]", "not whole"),
        ("G1 X#<_x>", 1, "#<_x>", "not supported"),
        ("G1 X#<_ini[plasma]max>", 1, "#<_ini[plasma]max>", "not supported"),
        ("#<_value> = 1", 1, "#<_value>", "read-only"),
        ("F#<_hal[plasmac.cut-feed-rate]>", 1, "#<_hal[plasmac.cut-feed-rate]>", "no HAL"),
        ("#2 = 0\nG1 X[1 / #2]", 2, "1 / #2", "division by zero"),
        ("G1 X[5 MOD 0]", 1, "5 MOD 0", "division by zero"),
        ("G1 X[SQRT[-1]]", 1, "SQRT[-1]", "square root of a negative"),
        ("G1 X[LN[0]]", 1, "LN[0]", "logarithm"),
        ("G1 XACOS[2]", 1, "ACOS[2]", "outside -1..1"),
        ("G1 X[-8 ** 0.5]", 1, "-8 ** 0.5", "fractional power"),
        ("G1 X[0 ** -1]", 1, "0 ** -1", "negative power"),
        ("G1 X[10 ** 400]", 1, "10 ** 400", "too large"),
        ("o1 repeat [1.5]\no1 endrepeat", 1, "o1 repeat [1.5]", "not whole"),
    ],
)
def test_errors_name_what_the_user_wrote(source: str, line: int, text: str, reason: str) -> None:
    exc = error(source)
    assert (exc.line, exc.text) == (line, text)
    assert reason in exc.reason
    assert str(exc) == f"line {line}: {text}: {exc.reason}"
    assert isinstance(exc, ValueError)


def test_an_endless_loop_stops_at_max_steps() -> None:
    exc = error("o1 while [1]\n  G0 X1\no1 endwhile", max_steps=1000)
    assert "program runs more than 1000 lines: endless loop?" in str(exc)
    exc = error("o1 while [1]\no1 endwhile")  # no output at all: still caught
    assert "endless loop" in exc.reason


def test_endless_recursion_is_caught() -> None:
    exc = error("o<r> sub\no<r> call\no<r> endsub\no<r> call")
    assert (exc.line, exc.text) == (2, "o<r> call")
    assert "nested" in exc.reason


def test_a_broken_program_yields_nothing_and_check_lists_every_error() -> None:
    source = "G0 X1\nG0 X2\no1 endif\nG1 X[FOO[1]]\nG0 X#<nope>\no<gone> call"
    program = NgcProgram(source.splitlines())
    assert [(exc.line, exc.text) for exc in program.check()] == [
        (3, "o1 endif"),
        (4, "FOO[1]"),
        (6, "o<gone> call"),
    ]  # #<nope> is only known to be unset when line 5 runs
    lines = program.evaluate()
    with pytest.raises(NgcError, match="o1 endif"):
        next(lines)
    assert NgcProgram(HOLES.splitlines()).check() == []


def test_oword_spelling_line_numbers_and_trailing_comments() -> None:
    source = """\
N10 O100 REPEAT[2] (twice)
N20 G0 X1
N30 o100 EndRepeat ; done
o< Hole Pattern > call [5]
o<holepattern> sub
  G0 Y#1
o<HOLEPATTERN> endsub
"""
    assert run(source) == ["N20 G0 X1", "N20 G0 X1", "G0 Y5"]


def test_a_single_string_is_split_into_lines() -> None:
    program = NgcProgram("#1 = 2\nG0 X#1\n")
    assert list(program.evaluate()) == [EvaluatedLine(2, "G0 X2")]
