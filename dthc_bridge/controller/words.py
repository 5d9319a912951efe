"""G-code words: the one tokeniser behind the daemon's parser, the sender, the mock and the bench.

A word is a letter (either case, kept upper case; ``$``, PlasmaC's tool selector, counts as
one) and a number with optional sign and decimals; blanks between words, and between a
letter and its number, are optional
(``G01X10.5Y-.5F1500``, ``M3S1``). ``(...)`` and ``;`` comments are removed and returned; a
line holding only ``%`` (the program delimiter) is empty. Anything else (``#1``, ``[...]``,
``/``, ``=``, a number without a letter) is refused with :class:`GcodeSyntaxError` naming it.

Pure and stateless: no I/O, no imports from the rest of the daemon, so the mock board and
the tools use the very same rules.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

__all__ = [
    "NESTED_COMMENT",
    "GcodeSyntaxError",
    "Tokens",
    "Word",
    "cutting_feed_mm_min",
    "tokenize",
    "words",
]


class GcodeSyntaxError(ValueError):
    """A line is not a sequence of words and comments. ``text`` names the offending part."""

    def __init__(self, text: str, reason: str) -> None:
        super().__init__(f"{text}: {reason}")
        self.text = text
        self.reason = reason


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_NUMBER_CHARS = frozenset("+-.0123456789")
_BLANKS = frozenset(" \t\r\n\f\v")
_CUTTING_MOTION = frozenset({1.0, 2.0, 3.0})


@dataclass(frozen=True, slots=True)
class Word:
    """One word as written: ``line[start:end]``."""

    letter: str  # upper case
    number: str  # the number as written; "" when the letter has none
    index: int  # position among the line's tokens (words and comments)
    start: int
    end: int

    @property
    def value(self) -> float:
        """The number; :class:`GcodeSyntaxError` (naming the letter) if missing or malformed."""
        if not self.number:
            raise GcodeSyntaxError(self.letter, "missing value")
        if _NUMBER.fullmatch(self.number) is None:
            raise GcodeSyntaxError(self.letter, f"malformed number {self.number!r}")
        value = float(self.number)
        if not math.isfinite(value):
            raise GcodeSyntaxError(self.letter, "number is too large")
        return value


@dataclass(frozen=True, slots=True)
class Tokens:
    """The words of a line in order, and its comments' text (stripped) in order."""

    words: tuple[Word, ...]
    comments: tuple[str, ...]


def _is_letter(ch: str) -> bool:
    # "$" is PlasmaC's tool word (``M3 $0 S1``), read like a letter.
    return (ch.isascii() and ch.isalpha()) or ch == "$"


def tokenize(line: str) -> Tokens:
    """Words and comments of ``line``; refuses stray characters and numbers without letters.

    A word's number is only checked by :attr:`Word.value`, so a caller can name the error
    after the command the word belongs to.
    """
    if line.strip() == "%":
        return Tokens((), ())
    found: list[Word] = []
    comments: list[str] = []
    tokens = 0
    i, n = 0, len(line)
    while i < n:
        ch = line[i]
        if ch in _BLANKS:
            i += 1
        elif ch == "(":
            end = line.find(")", i + 1)
            if end < 0:
                raise GcodeSyntaxError("(", "comment is not closed with ')'")
            inner = line.find("(", i + 1, end)
            if inner >= 0:
                raise GcodeSyntaxError(line[i : end + 1], NESTED_COMMENT)
            comments.append(line[i + 1 : end].strip())
            tokens += 1
            i = end + 1
        elif ch == ";":
            comments.append(line[i + 1 :].strip())
            break
        elif _is_letter(ch):
            j = i + 1
            while j < n and line[j] in " \t":
                j += 1
            k = j
            while k < n and line[k] in _NUMBER_CHARS:
                k += 1
            end = k if k > j else i + 1
            found.append(Word(ch.upper(), line[j:k], tokens, i, end))
            tokens += 1
            i = end
        elif ch in _NUMBER_CHARS:
            k = i
            while k < n and line[k] in _NUMBER_CHARS:
                k += 1
            raise GcodeSyntaxError(line[i:k], "number without a letter")
        elif ch == ")":
            raise GcodeSyntaxError(")", "')' without '('")
        else:
            raise GcodeSyntaxError(ch if ch.isprintable() else repr(ch), "unexpected character")
    return Tokens(tuple(found), tuple(comments))


NESTED_COMMENT = (
    "a comment inside a comment: '(' again before the first one's ')' (LinuxCNC and grbl "
    "refuse nested parentheses)"
)


def words(line: str) -> list[tuple[str, float]]:
    """``(letter, value)`` of every word of ``line`` in order, comments removed.

    Raises :class:`GcodeSyntaxError` for anything but words and comments, and for a word
    without a valid number.
    """
    return [(word.letter, word.value) for word in tokenize(line).words]


def cutting_feed_mm_min(line: str) -> float | None:
    """The programmed feed of a cutting move: the F value of a line with a G1, G2 or G3 word.

    None when the line has no such word, no F word or a negative F. The first F counts.
    Raises :class:`GcodeSyntaxError` like :func:`words`.
    """
    pairs = words(line)
    if not any(letter == "G" and value in _CUTTING_MOTION for letter, value in pairs):
        return None
    feed = next((value for letter, value in pairs if letter == "F"), None)
    return feed if feed is not None and feed >= 0.0 else None
