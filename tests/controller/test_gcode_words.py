"""The one G-code word tokeniser shared by the daemon, the sender, the mock gantry and the bench."""

from __future__ import annotations

import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dthc_bridge.controller.words import GcodeSyntaxError, cutting_feed_mm_min, tokenize, words


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G01X10.5Y-.5F1500", [("G", 1), ("X", 10.5), ("Y", -0.5), ("F", 1500)]),
        ("M3S1", [("M", 3), ("S", 1)]),
        ("g1 x+5 f100.", [("G", 1), ("X", 5), ("F", 100)]),
        ("G1 X 10\tY\t2", [("G", 1), ("X", 10), ("Y", 2)]),
        ("N10 G90.1", [("N", 10), ("G", 90.1)]),
        ("G1 (move to) X5 ; F100 (ignored)", [("G", 1), ("X", 5)]),
        ("", []),
        ("  %  ", []),
    ],
)
def test_words_are_letters_with_numbers_in_any_spacing_and_case(
    line: str, expected: list[tuple[str, float]]
) -> None:
    """Blanks are optional, letters are upper-cased, signs and bare decimals are numbers."""
    assert words(line) == expected


def test_comments_are_removed_and_returned_in_order() -> None:
    """``(...)`` and ``;`` comments are not words; their text comes back stripped."""
    tokens = tokenize("N5 ( Plasma ) M3 (on);  next cut ")
    assert [w.letter for w in tokens.words] == ["N", "M"]
    assert tokens.comments == ("Plasma", "on", "next cut")


def test_a_word_spans_its_text_as_written() -> None:
    """``line[start:end]`` is the word as written, blanks inside it included."""
    line = "G1X10 F 1500(c)Y2"
    spans = [line[w.start : w.end] for w in tokenize(line).words]
    assert spans == ["G1", "X10", "F 1500", "Y2"]
    assert [w.index for w in tokenize(line).words] == [0, 1, 2, 4]  # the comment is token 3


@pytest.mark.parametrize(
    ("line", "text", "reason"),
    [
        ("G1 (open", "(", "not closed"),
        ("G1 (move (to) X5", "(move (to)", "a comment inside a comment"),
        ("G1 X5)", ")", "without '('"),
        ("G1 #1=5", "#", "unexpected character"),
        ("G1 X5 10", "10", "number without a letter"),
        ("G1 X", "X", "missing value"),
        ("G1 X1-2", "X", "malformed number"),
        ("G1 X1O", "O", "missing value"),
        ("G1 X" + "9" * 400, "X", "too large"),
    ],
)
def test_anything_but_words_and_comments_is_refused_by_name(
    line: str, text: str, reason: str
) -> None:
    """Stray characters, lone numbers and words without a valid number name the culprit."""
    with pytest.raises(GcodeSyntaxError, match=re.escape(reason)) as info:
        words(line)
    assert info.value.text == text


def test_a_word_number_is_only_checked_when_its_value_is_read() -> None:
    """``tokenize`` keeps a bad number so the caller can name the command it belongs to."""
    (word,) = tokenize("X1-2").words
    assert word.number == "1-2"
    with pytest.raises(GcodeSyntaxError):
        _ = word.value


@pytest.mark.parametrize(
    ("line", "feed"),
    [
        ("G1 X10 F1500", 1500.0),
        ("G01X10F1500", 1500.0),
        ("g2 x1 y1 i1 j0 f3000 (F9)", 3000.0),
        ("G0 X10 F1500", None),
        ("F1500", None),
        ("G1 X10", None),
        ("G1 X10 F-5", None),
        ("G1 X10 ; F1500", None),
        ("G90 G1 X10 F800 F900", 800.0),
    ],
)
def test_cutting_feed_is_the_f_of_a_g1_g2_g3_line(line: str, feed: float | None) -> None:
    """The programmed cutting feed: F on a line with G1/G2/G3, compact forms included."""
    assert cutting_feed_mm_min(line) == feed


NUMBERS = st.one_of(
    st.integers(-99999, 99999).map(str),
    st.decimals(-9999, 9999, places=3, allow_nan=False, allow_infinity=False).map(str),
)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.sampled_from("GMXYZFIJNSTPgmxyzf"), NUMBERS), max_size=8),
    st.sampled_from(["", " ", "\t", "  "]),
    st.sampled_from(["", " "]),
)
def test_any_spacing_of_words_reads_back_the_same(
    pairs: list[tuple[str, str]], between: str, inside: str
) -> None:
    """Words joined with or without blanks, in either case, read back letter and value."""
    line = between.join(letter + inside + number for letter, number in pairs)
    assert words(line) == [(letter.upper(), float(number)) for letter, number in pairs]
