"""Evaluate LinuxCNC NGC programs (parameters, expressions, o-words) into plain G-code lines.

Hand-written QtPlasmaC programs use NGC: ``#<x_offset> = 10``, ``G1 X[35.92 + #<x_offset>]``,
``o100 repeat [#2]`` ... ``o100 endrepeat``, subroutines, ``F#<_hal[plasmac.cut-feed-rate]>``.
The sender runs them through :class:`NgcProgram` first, so everything downstream only sees plain
lines: words with literal numbers, comments kept. Evaluation is lazy, one output line at a time,
so whatever the caller does with a line (select a material, say) happens before the next line is
evaluated, and a HAL read further on sees its effect.

Supported, with LinuxCNC's meaning:

- comments ``( ... )`` and ``;`` to the end of the line, passed through verbatim and never
  evaluated; ``%`` lines and blank lines give no output; ``N`` numbers are ordinary words;
- words: a letter (or ``$``, QtPlasmaC's spindle selector in ``M3 $0``) and a value: a number,
  ``[expression]``, ``#parameter``, a function, any of them after a sign (``X-#1``: LinuxCNC's
  ``read_real_value`` takes a sign before any value, so ``[-2 ** 2]`` is 4);
- parameters: numbered ``#1``..``#5000`` (``#1``-``#30`` local to a subroutine call, unset ones
  read 0), named locals ``#<name>`` and globals ``#<_name>`` (names case- and space-insensitive;
  reading an unset one is an error), indirection ``#[1 + 1]`` and ``##1``, ``EXISTS[#<name>]``,
  ``#<_hal[pin]>`` through the ``hal`` reader (pin as written, spaces removed), ``#<_value>``
  and ``#<_value_returned>`` after a call;
- assignments, several per line and mixed with words: every right-hand side and word reads the
  values from before the line, and the assignments take effect after it (as LinuxCNC does);
- expressions: ``**``; ``* / MOD``; ``+ -``; ``EQ NE GT GE LT LE``; ``AND OR XOR`` (that order,
  left to right within a level); ``ABS ACOS ASIN COS EXP FIX FUP ROUND LN SIN SQRT TAN`` and
  ``ATAN[y]/[x]``, angles in degrees; EQ and NE with LinuxCNC's 0.0001 tolerance; ROUND halves
  away from zero; a negative MOD result is moved up by ``|divisor|``;
- o-words, numbered or ``o<name>``: ``sub``/``endsub [v]``/``return [v]``/``call [a]...``,
  ``if``/``elseif``/``else``/``endif``, ``while``/``endwhile``, ``do``/``while``,
  ``repeat``/``endrepeat``, ``break``, ``continue``;
- ``M2``/``M30``: the line is output and the program ends.

Choices where LinuxCNC leaves room, or where a construct is refused rather than guessed at
(every refusal is an :class:`NgcError` naming what the user wrote):

- broken programs send nothing: syntax, o-word structure and calls of undefined subroutines are
  found when the program is built; :meth:`NgcProgram.check` lists them all and
  :meth:`NgcProgram.evaluate` raises the first before it yields a line. Errors that depend on
  values (unset parameter, division by zero, a failed HAL read, an endless loop caught by
  ``max_steps``) come from ``evaluate`` at the line where they happen;
- output: a line whose words are all literal numbers, with no assignment, is passed through
  as written (stripped); any other line is rebuilt from its words and comments in source order,
  separated by one space, computed values written by :func:`format_number`; lines left empty
  (assignments only, o-word lines) give no output;
- comments are never evaluated, so ``(debug,#1)``-style messages pass through with their ``#``;
- whitespace is skipped between tokens and dropped inside ``<names>``; inside a number or a
  keyword it is an error (LinuxCNC deletes all whitespace first, so ``X1 0`` is X10 there);
- a sub may be defined before or after its call, but only at the top level, once; subroutine
  files are not searched; calls nest at most 50 deep;
- refused: block delete ``/``, system parameters above #5000 (offsets and positions live in the
  machine, not the program) for reading and writing, predefined ``#<_x>``-style and
  ``#<_ini[...]>`` names, computed o-word labels, Fanuc-style ``M98``/``M99``, a repeat count
  that is not a whole number, o-word forms other than those above.

Why hand-written: none of the Python G-code packages evaluates NGC. ``pygcode`` reads each
word's value with a per-letter number regex and keeps an ``O`` word as an opaque string, so
parameters, expressions and control flow are out of reach; ``gcodeparser`` splits Marlin-style
lines into a command, numeric parameters and a comment. LinuxCNC's own interpreter is C++ that
comes with a LinuxCNC install, not a Python package.
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TypeAlias

from ..controller.words import NESTED_COMMENT

__all__ = ["EvaluatedLine", "HalReader", "NgcError", "NgcProgram", "format_number"]

HalReader = Callable[[str], float]


STREAMED_OWORD = (
    "o-word flow (sub, call, if, while, repeat) needs the whole program, and a program "
    "streamed line by line (a grbl sender) arrives one line at a time: run it with "
    "dthc-bridge send, or from a post without o-words"
)


class NgcError(ValueError):
    """A program refused: the source line, the construct as the user wrote it, and why."""

    line: int
    text: str
    reason: str

    def __init__(self, line: int, text: str, reason: str) -> None:
        super().__init__(f"line {line}: {text}: {reason}")
        self.line = line
        self.text = text
        self.reason = reason


@dataclass(frozen=True, slots=True)
class EvaluatedLine:
    """One plain output line and the 1-based source line it came from."""

    source_line: int
    text: str


def format_number(value: float) -> str:
    """A value as a G-code number: at most 6 decimals, no trailing zeros, no exponent, no -0."""
    text = f"{value:.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


# ---------------------------------------------------------------------------------------------
# Reading lines: expressions, words, o-words.


def _words(text: str) -> frozenset[str]:
    return frozenset(text.split())


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_DIGITS = re.compile(r"\d+")
_TOKEN = re.compile(r"[A-Za-z]+|\S")
# LinuxCNC's precedence(): higher binds tighter; equal levels go left to right.
_PRECEDENCE = {
    **dict.fromkeys(("**",), 6),
    **dict.fromkeys(("*", "/", "mod"), 5),
    **dict.fromkeys(("+", "-"), 4),
    **dict.fromkeys(("eq", "ne", "gt", "ge", "lt", "le"), 3),
    **dict.fromkeys(("and", "or", "xor"), 2),
}
_WORD_OPERATORS = ("mod", "and", "xor", "or", "eq", "ne", "gt", "ge", "lt", "le")
_FUNCTIONS = _words("abs acos asin atan cos exists exp fix fup ln round sin sqrt tan")
# keyword -> (fewest, most [arguments], what to say otherwise)
_O_ARGS = {
    **dict.fromkeys(_words("if elseif while"), (1, 1, "needs one [condition]")),
    "repeat": (1, 1, "needs one [count]"),
    "call": (0, 30, "takes at most 30 [arguments]"),
    **dict.fromkeys(_words("endsub return"), (0, 1, "takes at most one [value]")),
    **dict.fromkeys(
        _words("sub else endif endwhile do endrepeat break continue"),
        (0, 0, "takes no [arguments]"),
    ),
}
# LinuxCNC's predefined named parameters: the machine's state, which this evaluator has not got.
_PREDEFINED = _words(
    "_vmajor _vminor _line _motion_mode _plane _ccomp _metric _imperial _absolute _incremental "
    "_inverse_time _units_per_minute _units_per_rev _coord_system _tool_offset _retract_r "
    "_retract_old_z _spindle_rpm_mode _spindle_css_mode _ijk_absolute_mode _lathe_diameter_mode "
    "_lathe_radius_mode _spindle_on _spindle_cw _mist _flood _speed_override _feed_override "
    "_adaptive_feed _feed_hold _feed _rpm _x _y _z _a _b _c _u _v _w _abs_x _abs_y _abs_z _abs_a "
    "_abs_b _abs_c _abs_u _abs_v _abs_w _current_tool _current_pocket _selected_tool "
    "_selected_pocket _call_level _remap_level _task _value _value_returned"
)


@dataclass(frozen=True, slots=True)
class _Num:
    value: float


@dataclass(frozen=True, slots=True)
class _Neg:
    operand: _Expr


@dataclass(frozen=True, slots=True)
class _Param:
    """``#1``, ``#[e]``, ``##1`` (index set) or ``#<name>`` (name lower-cased, raw as written)."""

    src: str
    index: _Expr | None = None
    name: str = ""
    raw: str = ""


@dataclass(frozen=True, slots=True)
class _Binary:
    src: str
    op: str
    left: _Expr
    right: _Expr


@dataclass(frozen=True, slots=True)
class _Func:
    src: str
    name: str
    args: tuple[_Expr, ...]


@dataclass(frozen=True, slots=True)
class _Exists:
    name: str


_Expr: TypeAlias = _Num | _Neg | _Param | _Binary | _Func | _Exists


@dataclass(frozen=True, slots=True)
class _Word:
    src: str
    letter: str
    value: _Expr
    literal: str | None  # the number as written, when the value is one


@dataclass(frozen=True, slots=True)
class _Assign:
    target: _Param
    value: _Expr


@dataclass(frozen=True, slots=True)
class _GLine:
    """A line of words, comments and assignments."""

    number: int
    text: str
    items: tuple[_Word | str, ...]  # str: a comment, verbatim
    assigns: tuple[_Assign, ...]
    plain: bool  # literal words only: output the line as written


@dataclass(frozen=True, slots=True)
class _OLine:
    number: int
    text: str
    head: str  # "o100 repeat" as written
    label: str  # "100" or "<name>", normalised
    keyword: str
    args: tuple[_Expr, ...]


def _name(label: str, keyword: str) -> str:
    return f"o{label} {keyword}"


class _Parser:
    """Reads one source line into a :class:`_GLine` or :class:`_OLine` (None: no output)."""

    def __init__(self, text: str, line: int) -> None:
        self.s = text.rstrip("\r\n")
        self.i = 0
        self.line = line
        self.item = 0  # start of the word or assignment being read, for error text
        self.bracket: int | None = None  # the outermost '[' still open

    def error(self, start: int, end: int | None, reason: str) -> NgcError:
        return NgcError(self.line, self.s[start:end].strip() or self.s.strip(), reason)

    def peek(self) -> str:
        """The next character after whitespace ('' at the end of the line)."""
        while self.i < len(self.s) and self.s[self.i].isspace():
            self.i += 1
        return self.s[self.i : self.i + 1]

    def ended(self, what: str) -> NgcError:
        if self.bracket is not None:
            return self.error(self.bracket, None, "'[' is never closed")
        return self.error(self.item, None, f"the line ends where {what} should be")

    def letters(self) -> str:
        start = self.i
        while self.i < len(self.s) and self.s[self.i].isascii() and self.s[self.i].isalpha():
            self.i += 1
        return self.s[start : self.i]

    def read(self) -> _GLine | _OLine | None:
        c = self.peek()
        if not c or c == "%":
            return None
        if c == "/":
            raise self.error(self.i, None, "block delete '/' is not supported")
        if c in ("n", "N"):  # a line number may stand before an o-word
            start = self.i
            self.i += 1
            if self.peek().isdigit():
                self.number()
            if self.peek() in ("o", "O"):
                return self.oword()
            self.i = start
        return self.oword() if c in ("o", "O") else self.gline()

    def number(self) -> float:
        match = _NUMBER.match(self.s, self.i)
        if match is None:
            raise self.error(self.i, self.i + 1, "expected a number")
        self.i = match.end()
        return float(match.group())

    def value(self) -> _Expr:
        c = self.peek()
        if not c:
            raise self.ended("a value")
        if c == "[":
            return self.bracketed()
        if c == "#":
            return self.param()
        after = self.s[self.i + 1 : self.i + 2]
        if c in "+-" and not (after.isdigit() or after == "."):
            self.i += 1  # a sign before '[', '#' or a function (LinuxCNC read_real_value)
            operand = self.value()
            return operand if c == "+" else _Neg(operand)
        if c.isdigit() or c in "+-.":
            return _Num(self.number())
        if c.isascii() and c.isalpha():
            return self.function()
        raise self.error(self.i, self.i + 1, "expected a number, '[', '#' or a function")

    def bracketed(self) -> _Expr:
        outermost = self.bracket is None
        if outermost:
            self.bracket = self.i
        self.i += 1
        expr = self.binary(0)
        self.i += 1  # binary() returns only at ']'
        if outermost:
            self.bracket = None
        return expr

    def binary(self, min_precedence: int) -> _Expr:
        """Precedence climbing: operands and operators up to the enclosing ']'."""
        self.peek()
        start = self.i
        left = self.value()
        while (op := self.operator()) is not None and _PRECEDENCE[op] >= min_precedence:
            self.i += len(op)
            right = self.binary(_PRECEDENCE[op] + 1)
            left = _Binary(self.s[start : self.i].strip(), op, left, right)
        return left

    def operator(self) -> str | None:
        c = self.peek()
        if c == "]":
            return None
        if not c:
            raise self.ended("an operator or ']'")
        if self.s.startswith("**", self.i):
            return "**"
        if c in "*/+-":
            return c
        ahead = self.s[self.i : self.i + 3].lower()
        for op in _WORD_OPERATORS:
            if ahead.startswith(op):
                return op
        token = _TOKEN.match(self.s, self.i)
        end = token.end() if token else self.i + 1
        raise self.error(self.i, end, "expected an operator or ']'")

    def function(self) -> _Expr:
        start = self.i
        name = self.letters().lower()
        if self.peek() != "[" or name not in _FUNCTIONS:
            end = self.bracket_end() if self.peek() == "[" else self.i
            known = name in _FUNCTIONS
            reason = f"{name.upper()} needs its argument in [ ]" if known else "unknown function"
            raise self.error(start, end, reason)
        if name == "exists":
            self.i += 1
            target = self.param() if self.peek() == "#" else None
            if target is None or not target.name or self.peek() != "]":
                raise self.error(start, self.bracket_end(start), "EXISTS takes one #<name>")
            self.i += 1
            return _Exists(target.name)
        args = [self.bracketed()]
        if name == "atan":
            if self.peek() != "/" or self.s[self.i + 1 :].lstrip()[:1] != "[":
                raise self.error(start, self.i, "ATAN takes two arguments: ATAN[y]/[x]")
            self.i += 1
            self.peek()
            args.append(self.bracketed())
        return _Func(self.s[start : self.i].strip(), name, tuple(args))

    def bracket_end(self, start: int | None = None) -> int | None:
        """Just past the ']' that closes the first '[' from start (None: never closed)."""
        depth, first = 0, self.s.find("[", self.i if start is None else start)
        for at in range(first, len(self.s) if first >= 0 else first):
            depth += {"[": 1, "]": -1}.get(self.s[at], 0)
            if depth == 0:
                return at + 1
        return None

    def angle_name(self, start: int) -> str:
        """The ``<name>`` at the cursor, blanks removed (LinuxCNC ignores them); past it."""
        close = self.s.find(">", self.i)
        if close < 0:
            raise self.error(start, None, "'<' is never closed")
        raw = "".join(self.s[self.i + 1 : close].split())
        self.i = close + 1
        return raw

    def param(self) -> _Param:
        start = self.i
        self.i += 1
        c = self.peek()
        if c == "<":
            raw = self.angle_name(start)
            if not raw:
                raise self.error(start, self.i, "empty parameter name")
            return _Param(self.s[start : self.i], name=raw.lower(), raw=raw)
        if c.isdigit():
            index: _Expr = _Num(self.number())
        elif c in ("[", "#"):
            index = self.value()
        else:
            raise self.error(start, self.i + 1, "'#' needs a number, <name> or [expression]")
        return _Param(self.s[start : self.i].strip(), index=index)

    def gline(self) -> _GLine:
        items: list[_Word | str] = []
        assigns: list[_Assign] = []
        plain = True
        while c := self.peek():
            self.item = start = self.i
            if c == "(":
                close = self.s.find(")", start)
                if close < 0:
                    raise self.error(start, None, "comment '(' is never closed")
                if self.s.find("(", start + 1, close) >= 0:
                    raise self.error(start, close + 1, NESTED_COMMENT)
                items.append(self.s[start : close + 1])
                self.i = close + 1
            elif c == ";":
                items.append(self.s[start:].rstrip())
                self.i = len(self.s)
            elif c == "#":
                target = self.param()
                if self.peek() != "=":
                    raise self.error(start, self.i, "a parameter alone is not a word: '=' expected")
                self.i += 1
                assigns.append(_Assign(target, self.value()))
                plain = False
            elif c in ("o", "O"):
                raise self.error(start, None, "an o-word must start its line")
            elif c == "$" or (c.isascii() and c.isalpha()):
                self.i += 1
                value_start = self.i
                value = self.value()
                written = self.s[value_start : self.i]
                literal = written.strip()
                is_number = isinstance(value, _Num) and _NUMBER.fullmatch(literal) is not None
                plain = plain and is_number and literal == written
                src = self.s[start : self.i].strip()
                word = _Word(src, c, value, literal if is_number else None)
                if is_number and c in "mM" and float(literal) in (98.0, 99.0):
                    raise self.error(start, self.i, _FANUC)
                items.append(word)
            else:
                raise self.error(start, start + 1, f"unexpected character {c!r}")
        return _GLine(self.line, self.s.strip(), tuple(items), tuple(assigns), plain)

    def oword(self) -> _OLine:
        start = self.i
        self.i += 1
        c = self.peek()
        if c == "<":
            label = "<" + self.angle_name(start).lower() + ">"
        elif digits := _DIGITS.match(self.s, self.i):
            label = str(int(digits.group()))
            self.i = digits.end()
        else:
            raise self.error(start, None, "an o-word needs a number or <name> (computed: no)")
        self.peek()
        keyword = self.letters().lower()
        head = self.s[start : self.i].strip()
        if keyword not in _O_ARGS:
            if not keyword:
                raise self.error(start, None, "o-word without a keyword (o100 sub, o100 if, ...)")
            raise self.error(start, self.i, f"unknown o-word keyword {keyword!r}")
        args: list[_Expr] = []
        while self.peek() == "[":
            self.item = self.i
            args.append(self.bracketed())
        while c := self.peek():  # only comments may follow
            close = self.s.find(")", self.i)
            if c == ";":
                break
            if c != "(" or close < 0:
                raise self.error(self.i, None, f"unexpected text after '{head}'")
            self.i = close + 1
        fewest, most, reason = _O_ARGS[keyword]
        if not fewest <= len(args) <= most:
            raise self.error(start, None, f"'{keyword}' {reason}")
        return _OLine(self.line, self.s.strip(), head, label, keyword, tuple(args))


_FANUC = "M98/M99 (Fanuc-style subroutines) are not supported: use o-word sub/call"


# ---------------------------------------------------------------------------------------------
# Program structure: o-word blocks matched up before anything runs.


@dataclass(slots=True)
class _If:
    branches: list[tuple[_OLine, list[_Node]]]  # if / elseif / else line and its body


@dataclass(slots=True)
class _Loop:
    head: _OLine  # while / do / repeat
    body: list[_Node]
    tail: _OLine | None = None  # the closing 'while [cond]' of a do-while


@dataclass(slots=True)
class _Sub:
    head: _OLine
    body: list[_Node]
    end: _OLine


_Node: TypeAlias = _GLine | _OLine | _If | _Loop


@dataclass(slots=True)
class _Open:
    head: _OLine
    body: list[_Node]  # where lines go now
    node: _If | _Loop | None = None  # None: a sub
    has_else: bool = False


_CLOSES = {"endsub": "sub", "endif": "if", "endwhile": "while", "endrepeat": "repeat"}
_CLOSER = {v: k for k, v in _CLOSES.items()} | {"do": "while"}
_LOOPS = ("while", "do", "repeat")


class _Builder:
    """Matches o-word blocks up, line by line, collecting every error it can."""

    def __init__(self, lines: Sequence[str]) -> None:
        self.top: list[_Node] = []
        self.subs: dict[str, _Sub] = {}
        self.errors: list[NgcError] = []
        self.stack: list[_Open] = []
        calls: list[_OLine] = []
        for number, text in enumerate(lines, start=1):
            try:
                line = _Parser(text, number).read()
                if line is not None:
                    self.place(line, calls)
            except NgcError as exc:
                self.errors.append(exc)
        for still in self.stack:
            missing = _name(still.head.label, _CLOSER[still.head.keyword])
            self.errors.append(NgcError(still.head.number, still.head.head, f"no '{missing}'"))
        for call in calls:
            if call.label not in self.subs:
                reason = f"no '{_name(call.label, 'sub')}' in this program"
                self.errors.append(NgcError(call.number, call.head, reason))
        self.errors.sort(key=lambda exc: exc.line)

    def place(self, line: _GLine | _OLine, calls: list[_OLine]) -> None:
        block = self.stack[-1].body if self.stack else self.top
        if isinstance(line, _GLine):
            block.append(line)
            return
        kw, label = line.keyword, line.label
        top = self.stack[-1] if self.stack else None
        closes_do = top is not None and top.head.keyword == "do" and top.head.label == label
        if kw in ("sub", "if", "do", "repeat") or (kw == "while" and not closes_do):
            self.open(line, block)
        elif kw in ("elseif", "else"):
            if top is None or not isinstance(top.node, _If) or top.head.label != label:
                raise self.fail(line, f"no open '{_name(label, 'if')}'")
            if top.has_else:
                raise self.fail(line, f"comes after '{_name(label, 'else')}'")
            top.body = []
            top.node.branches.append((line, top.body))
            top.has_else = kw == "else"
        elif kw in _CLOSES or kw == "while":
            opened = self.close(line, _CLOSES.get(kw, "do"))
            if kw == "endsub":
                self.subs[label] = _Sub(opened.head, opened.body, line)
            elif kw == "while" and isinstance(opened.node, _Loop):
                opened.node.tail = line
        else:
            if kw in ("break", "continue") and not any(
                o.head.label == label and o.head.keyword in _LOOPS for o in self.stack
            ):
                raise self.fail(line, f"not inside a loop 'o{label}'")
            if kw in ("break", "continue") and any(
                o.head.label == label and o.head.keyword == "repeat" for o in self.stack
            ):
                # LinuxCNC's interpreter refuses it ('no matching while/do label'): a
                # program that runs here would not run there.
                raise self.fail(line, f"'{kw}' works in while and do loops, not in repeat "
                                "(LinuxCNC refuses it)")  # fmt: skip
            if kw == "return" and not (
                self.stack and self.stack[0].node is None and self.stack[0].head.label == label
            ):
                raise self.fail(line, f"not inside '{_name(label, 'sub')}'")
            if kw == "call":
                calls.append(line)
            block.append(line)

    def open(self, line: _OLine, block: list[_Node]) -> None:
        for o in self.stack:
            if line.keyword == "sub":
                where = f"'{_name(o.head.label, o.head.keyword)}' (line {o.head.number})"
                raise self.fail(line, f"a sub cannot be defined inside {where}")
            if o.head.label == line.label:
                raise self.fail(line, f"'o{line.label}' is already open on line {o.head.number}")
        if line.keyword == "sub":
            if line.label in self.subs:
                first = self.subs[line.label].head.number
                raise self.fail(line, f"defined before, on line {first}")
            self.stack.append(_Open(line, []))
            return
        node: _If | _Loop
        if line.keyword == "if":
            body: list[_Node] = []
            node = _If([(line, body)])
        else:
            node = _Loop(line, [])
            body = node.body
        block.append(node)
        self.stack.append(_Open(line, body, node))

    def close(self, line: _OLine, kind: str) -> _Open:
        top = self.stack[-1] if self.stack else None
        if top is not None and top.head.keyword == kind and top.head.label == line.label:
            return self.stack.pop()
        for depth, o in enumerate(self.stack):
            if top is not None and o.head.keyword == kind and o.head.label == line.label:
                del self.stack[depth:]  # this error stands for the blocks left open inside
                inner = _name(top.head.label, top.head.keyword)
                raise self.fail(line, f"'{inner}' (line {top.head.number}) must be closed first")
        raise self.fail(line, f"no open '{_name(line.label, kind)}'")

    @staticmethod
    def fail(line: _OLine, reason: str) -> NgcError:
        return NgcError(line.number, line.head, reason)


# ---------------------------------------------------------------------------------------------
# Running: parameters, expression values, control flow.

_TOLERANCE_EQUAL = 0.0001  # LinuxCNC's EQ / NE
_MAX_CALL_DEPTH = 50
_FIRST_SYSTEM_PARAMETER = 5001
_LAST_PARAMETER = 5601


def _mod(left: float, right: float) -> float:
    result = math.fmod(left, right)
    return result + abs(right) if result < 0.0 else result


def _round(x: float) -> float:
    return math.copysign(math.floor(abs(x) + 0.5), x)


_BINARY: dict[str, Callable[[float, float], float]] = {
    "**": math.pow,
    "*": operator.mul,
    "/": operator.truediv,
    "mod": _mod,
    "+": operator.add,
    "-": operator.sub,
    "eq": lambda a, b: float(abs(a - b) < _TOLERANCE_EQUAL),
    "ne": lambda a, b: float(abs(a - b) >= _TOLERANCE_EQUAL),
    "gt": lambda a, b: float(a > b),
    "ge": lambda a, b: float(a >= b),
    "lt": lambda a, b: float(a < b),
    "le": lambda a, b: float(a <= b),
    "and": lambda a, b: float(a != 0.0 and b != 0.0),
    "or": lambda a, b: float(a != 0.0 or b != 0.0),
    "xor": lambda a, b: float((a != 0.0) != (b != 0.0)),
}
_UNARY: dict[str, Callable[[float], float]] = {
    "abs": abs,
    "acos": lambda x: math.degrees(math.acos(x)),
    "asin": lambda x: math.degrees(math.asin(x)),
    "cos": lambda x: math.cos(math.radians(x)),
    "exp": math.exp,
    "fix": lambda x: float(math.floor(x)),
    "fup": lambda x: float(math.ceil(x)),
    "ln": math.log,
    "round": _round,
    "sin": lambda x: math.sin(math.radians(x)),
    "sqrt": math.sqrt,
    "tan": lambda x: math.tan(math.radians(x)),
}


class _Flow(Exception):
    """break / continue / return / M2, carried up the generators to what it ends."""

    def __init__(self, kind: str, label: str = "", value: float | None = None) -> None:
        super().__init__(kind)
        self.kind = kind
        self.label = label
        self.value = value


@dataclass(slots=True)
class _Frame:
    """One call level's locals: #1-#30 and named parameters without a leading '_'."""

    numbered: dict[int, float] = field(default_factory=dict)
    named: dict[str, float] = field(default_factory=dict)


class NgcProgram:
    """An NGC program, checked when built and evaluated lazily by :meth:`evaluate`.

    ``lines`` are the source lines (a single string is split into lines); ``hal`` answers
    ``#<_hal[pin]>`` reads; ``max_steps`` bounds how many source lines one run may execute.
    """

    def __init__(
        self, lines: Sequence[str], *, hal: HalReader | None = None, max_steps: int = 1_000_000
    ) -> None:
        built = _Builder(lines.splitlines() if isinstance(lines, str) else lines)
        self._top, self._subs, self._errors = built.top, built.subs, built.errors
        self._hal = hal
        self._max_steps = max_steps
        self._reset()

    def check(self) -> list[NgcError]:
        """Every error found without running: syntax, o-word structure, undefined subs."""
        return list(self._errors)

    def evaluate(self) -> Iterator[EvaluatedLine]:
        """Lazy: yields output lines one by one, in execution order (loops unrolled, subs inlined).

        Each call starts a fresh run. The first error of :meth:`check`, if any, is raised before
        anything is yielded; errors that depend on values are raised where they happen.
        """
        if self._errors:
            raise self._errors[0]
        self._reset()
        try:
            yield from self._run(self._top)
        except _Flow as flow:
            if flow.kind != "stop":  # break/continue/return were matched up when built
                raise AssertionError(f"unmatched {flow.kind}") from flow

    def evaluate_streamed(self, number: int, text: str) -> EvaluatedLine | None:
        """One more line of a program that arrives line by line (a grbl sender streams it:
        nothing after it is known yet), evaluated with the parameters the lines before it
        set. O-word flow needs the lines after it, so it is refused; None for a line with
        nothing left to run (a comment, an assignment)."""
        line = _Parser(text, number).read()
        if line is None:
            return None
        if isinstance(line, _OLine):
            raise NgcError(number, line.head, STREAMED_OWORD)
        self._tick(line)
        output, _ = self._gline(line)
        return EvaluatedLine(number, output) if output else None

    def get(self, name: str, *, top_level: bool = False) -> float | None:
        """Current value of a parameter: ``get("keep-z-motion")``, ``get("_x_offset")``,
        ``get("1")``; case- and space-insensitive, ``#<...>`` optional; None when unset.

        Locals are those of the call level being run (the top level once a run has ended),
        or of the top level with ``top_level``: program settings such as
        ``#<keep-z-motion>`` are set there and hold inside subroutines too.
        """
        key = "".join(name.split()).lower().removeprefix("#")
        if key.startswith("<") and key.endswith(">"):
            key = key[1:-1]
        frame = self._frames[0 if top_level else -1]
        if key.isdigit():
            number = int(key)
            return (frame.numbered if number <= 30 else self._numbered).get(number)
        return (self._globals if key.startswith("_") else frame.named).get(key)

    def _reset(self) -> None:
        self._frames = [_Frame()]
        self._numbered: dict[int, float] = {}
        self._globals: dict[str, float] = {"_value": 0.0, "_value_returned": 0.0}
        self._steps = 0
        self._line = 0

    def _tick(self, line: _GLine | _OLine) -> None:
        """Count one executed source line; the guard against endless loops."""
        self._steps += 1
        self._line = line.number
        if self._steps > self._max_steps:
            reason = f"program runs more than {self._max_steps} lines: endless loop?"
            raise NgcError(line.number, line.text, reason)

    def _fail(self, text: str, reason: str) -> NgcError:
        return NgcError(self._line, text, reason)

    def _run(self, nodes: list[_Node]) -> Iterator[EvaluatedLine]:
        for node in nodes:
            if isinstance(node, _GLine):
                self._tick(node)
                text, stop = self._gline(node)
                if text:
                    yield EvaluatedLine(node.number, text)
                if stop:
                    raise _Flow("stop")
            elif isinstance(node, _If):
                for head, body in node.branches:
                    self._tick(head)
                    if not head.args or self._eval(head.args[0]) != 0.0:
                        yield from self._run(body)
                        break
            elif isinstance(node, _Loop):
                yield from self._loop(node)
            elif node.keyword == "call":
                yield from self._call(node)
            else:  # break, continue, return
                self._tick(node)
                value = self._eval(node.args[0]) if node.args else None
                raise _Flow(node.keyword, node.label, value)

    def _loop(self, loop: _Loop) -> Iterator[EvaluatedLine]:
        head, kind = loop.head, loop.head.keyword
        remaining = self._repeat_count(head) if kind == "repeat" else 0
        while True:
            self._tick(head)  # once per round, so even an empty endless loop hits max_steps
            if kind == "while" and self._eval(head.args[0]) == 0.0:
                return
            if kind == "repeat":
                if remaining <= 0:
                    return
                remaining -= 1
            try:
                yield from self._run(loop.body)
            except _Flow as flow:
                if flow.label != head.label or flow.kind not in ("break", "continue"):
                    raise
                if flow.kind == "break":
                    return
            if loop.tail is not None:  # do ... while [cond]
                self._tick(loop.tail)
                if self._eval(loop.tail.args[0]) == 0.0:
                    return

    def _repeat_count(self, head: _OLine) -> int:
        self._tick(head)
        value = self._eval(head.args[0])
        count = round(value)
        if abs(value - count) > _TOLERANCE_EQUAL:
            raise self._fail(head.text, f"repeat count {format_number(value)} is not whole")
        return max(count, 0)

    def _call(self, call: _OLine) -> Iterator[EvaluatedLine]:
        self._tick(call)
        sub = self._subs[call.label]
        args = [self._eval(arg) for arg in call.args]
        if len(self._frames) > _MAX_CALL_DEPTH:
            reason = f"calls nested more than {_MAX_CALL_DEPTH} deep: endless recursion?"
            raise self._fail(call.head, reason)
        self._frames.append(_Frame(numbered=dict(enumerate(args, start=1))))
        value: float | None = None
        try:
            yield from self._run(sub.body)
            self._tick(sub.end)
            value = self._eval(sub.end.args[0]) if sub.end.args else None
        except _Flow as flow:
            if flow.kind != "return":
                raise
            value = flow.value
        finally:
            self._frames.pop()
        self._globals["_value_returned"] = 0.0 if value is None else 1.0
        if value is not None:
            self._globals["_value"] = value

    def _gline(self, line: _GLine) -> tuple[str, bool]:
        """The output text of a line and whether it ends the program; then its assignments."""
        parts: list[str] = []
        stop = False
        for item in line.items:
            if isinstance(item, str):
                parts.append(item)
                continue
            value = self._eval(item.value)
            if item.letter in "mM":
                if value in (98.0, 99.0):
                    raise self._fail(item.src, _FANUC)
                stop = stop or value in (2.0, 30.0)
            parts.append(item.letter + (item.literal or format_number(value)))
        # Right-hand sides (and indirect targets) read the values from before the line.
        settings = [(self._target(a.target), self._eval(a.value)) for a in line.assigns]
        for key, value in settings:
            if isinstance(key, int):
                (self._frames[-1].numbered if key <= 30 else self._numbered)[key] = value
            else:
                (self._globals if key.startswith("_") else self._frames[-1].named)[key] = value
        return (line.text if line.plain else " ".join(parts)), stop

    def _index(self, param: _Param) -> int:
        assert param.index is not None
        value = self._eval(param.index)
        number = round(value)
        if abs(value - number) > _TOLERANCE_EQUAL:
            raise self._fail(param.src, f"parameter number {format_number(value)} is not whole")
        if not 1 <= number <= _LAST_PARAMETER:
            raise self._fail(param.src, f"parameter number {number} is out of range")
        if number >= _FIRST_SYSTEM_PARAMETER:
            raise self._fail(param.src, "system parameter not supported")
        return number

    def _target(self, param: _Param) -> int | str:
        if param.index is not None:
            return self._index(param)
        if param.name in _PREDEFINED or param.name.startswith(("_hal[", "_ini[")):
            raise self._fail(param.src, "predefined parameter: read-only")
        return param.name

    def _read(self, param: _Param) -> float:
        if param.index is not None:
            number = self._index(param)
            return (self._frames[-1].numbered if number <= 30 else self._numbered).get(number, 0.0)
        name = param.name
        store = self._globals if name.startswith("_") else self._frames[-1].named
        if name in store:
            return store[name]
        if name.startswith("_hal[") and name.endswith("]"):
            return self._read_hal(param, param.raw[5:-1])
        if name in _PREDEFINED or name.startswith("_ini["):
            raise self._fail(param.src, "predefined parameter not supported")
        raise self._fail(param.src, "parameter is not set")

    def _read_hal(self, param: _Param, pin: str) -> float:
        if self._hal is None:
            raise self._fail(param.src, "no HAL reader: HAL pins cannot be read here")
        try:
            value = float(self._hal(pin))
        except Exception as exc:  # the reader's own failure, reported at the line that read
            raise self._fail(param.src, f"reading HAL pin {pin!r} failed: {exc}") from exc
        if not math.isfinite(value):
            raise self._fail(param.src, f"HAL pin {pin!r} reads {value}")
        return value

    def _eval(self, expr: _Expr) -> float:
        if isinstance(expr, _Num):
            return expr.value
        if isinstance(expr, _Neg):
            return -self._eval(expr.operand)
        if isinstance(expr, _Param):
            return self._read(expr)
        if isinstance(expr, _Exists):
            store = self._globals if expr.name.startswith("_") else self._frames[-1].named
            return 1.0 if expr.name in store else 0.0
        try:
            result = self._binary(expr) if isinstance(expr, _Binary) else self._function(expr)
        except OverflowError:
            result = math.inf
        if not math.isfinite(result):
            raise self._fail(expr.src, "result is too large")
        return result

    def _binary(self, expr: _Binary) -> float:
        left, right = self._eval(expr.left), self._eval(expr.right)
        if expr.op in ("/", "mod") and right == 0.0:
            raise self._fail(expr.src, "division by zero")
        if expr.op == "**" and left < 0.0 and not right.is_integer():
            raise self._fail(expr.src, "negative number to a fractional power")
        if expr.op == "**" and left == 0.0 and right < 0.0:
            raise self._fail(expr.src, "zero to a negative power")
        return _BINARY[expr.op](left, right)

    def _function(self, expr: _Func) -> float:
        args = [self._eval(arg) for arg in expr.args]
        x = args[0]
        if expr.name == "atan":
            return math.degrees(math.atan2(x, args[1]))
        if expr.name in ("asin", "acos") and not -1.0 <= x <= 1.0:
            raise self._fail(expr.src, "argument outside -1..1")
        if expr.name == "sqrt" and x < 0.0:
            raise self._fail(expr.src, "square root of a negative number")
        if expr.name == "ln" and x <= 0.0:
            raise self._fail(expr.src, "logarithm of a number <= 0")
        return _UNARY[expr.name](x)
