"""G-code lines into the typed plasma commands of :mod:`.commands`.

The G-code sender sends us single lines. :func:`parse_line` splits one line into the plasma
commands it carries (in line order) and whatever is left for the motion backend (the
structured MQTT requests that are not G-code are parsed by the request table,
:mod:`dthc_bridge.requests`). It is pure and stateless, and every problem is a
:class:`~.commands.CommandError` naming the offending word (``"G200 Q: unknown parameter"``,
``"G100 P6 H: required parameter is missing"``).

Dialects understood:

* MASSO (v5 / DTHC): ``T112 M6`` (``M6`` with any other tool leaves plasma mode),
  ``G200 F P D C V A O S`` (cut parameters; bare ``G200`` = legacy mode), ``M3``/``M03``,
  ``M5``/``M05``, ``M667 [F]`` (THC on, F = Z feed while under THC), ``M666`` (THC off).
* RosettaCNC ``G100 P<n>``: P0 resume point, P4 current, P5 voltage mode, P6 probe and
  start, P7 THC comparator on/off. P1, P2, P3, P8 and P1000 are machine functions, not
  plasma ones, and are refused.
* LinuxCNC PlasmaC: ``M62``/``M64 P2`` THC off, ``M63``/``M65 P2`` THC on, ``P3`` torch
  disable/enable (hole over-cut; 62/63 with the next motion, 64/65 at once);
  ``M67``/``M68 E3 Q<n>`` velocity reduction to n percent (67 with the next motion, 68 at
  once); ``M3 $0 S1``/``M5 $0``/``M5 $-1`` (``$1`` scribe and ``$2`` spotting are refused by
  name); in the ``plasmac`` dialect ``T0 M6`` is the torch and ``(o=...)`` comments define
  materials; ``M190 P<n>`` selects a material.
* Z belongs to the board (all dialects): ``G38.2``/``G38.3``/``G31 Z F`` probe, ``G92 Z``,
  ``G10 L20 Z`` and ``G92.1`` set the work Z origin, ``G0``/``G1``/``G53 Z`` move Z. In the
  ``relay`` dialect ``M3`` is a bare torch relay.

Choices made where the source documents are silent or ambiguous:

* Tokens (:mod:`.words`, shared with the sender, the mock and the bench): a word is a
  letter (either case) and a number with optional sign and decimals; blanks between words,
  and between a letter and its number, are optional. ``(...)`` and ``;`` comments are
  removed and kept in :attr:`ParsedLine.comment` (several are joined with ``"; "``).
  Anything else (``#1``, ``[...]``, ``/``, ``=``) is refused; a line holding only ``%`` (the
  program delimiter) is empty.
* Which command a parameter word belongs to: the G or M word before it; words before the
  first G/M word belong to the first one (so ``F600 M667`` is ``M667 F600``). A plasma
  command refuses any word it does not take, which keeps mixed lines honest
  (``G200 X5`` and ``X5 G200`` are errors, ``G1 X5 M3`` is motion plus a torch start). On a
  line with ``M6`` the one ``T`` word belongs to ``M6`` wherever it stands; a ``T`` on a line
  without ``M6`` is passed to the motion backend untouched.
* ``G200`` with some parameters: each missing one takes the :class:`~.commands.CutParams`
  default, not the value of an earlier ``G200`` (the parser is stateless and MASSO says a new
  G200 overwrites the previous settings). ``V0`` is auto voltage (``cut_voltage_v=None``),
  O and S must be 0 or 1. Ranges are checked by ``CutParams``.
* ``M667 F`` must be > 0. ``M667``/``M666`` give ``synchronized=False`` (the default).
* RosettaCNC ``G100 P6``: E (piercing delay) and F (arc-OK timeout) are in **seconds**, the
  unit RosettaCNC uses for its dwell. A, C (feeds), D, H (heights) and F must be > 0, E >= 0;
  B is a machine Z coordinate and may have any sign. I is 0..3, default 0.
* ``G100 P4 A`` (amperes) is > 0 and <= 400. ``G100 P5 A0 B`` needs B in the ``G200 V``
  range (50..300 V); with ``A1`` a B word is accepted and ignored, as RosettaCNC does.
  ``G100 P7`` gives an unsynchronized :class:`~.commands.ThcEnable` (RosettaCNC stops motion
  for it by default).
* ``G100 P0``: the :class:`~.commands.ResumePoint` line is the ``line_number`` argument (the
  sender's own position in its file, unique by construction) when given, else the line's N
  word. :attr:`ParsedLine.line_number` is the N word when present, else the argument.
* ``M67``/``M68``: Q must be 0..100; the value is passed through (PlasmaC reads <= 0 as 100 %).
  ``M62``-``M65`` with P0/P1 (digital output, arc-OK ignore) or any output but P2/P3 are
  refused, as is ``M67``/``M68`` with any E but 3.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .commands import (
    Command,
    CommandError,
    CutParams,
    DefineMaterial,
    LegacyMode,
    PlasmaMode,
    ProbeAndStart,
    ProbeSurface,
    ProgramZMove,
    ResumePoint,
    SelectCurrent,
    SelectMaterial,
    SetCutParams,
    SetWorkZ,
    ThcEnable,
    TorchEnable,
    TorchStart,
    TorchStop,
    VelocityReduction,
    VoltageMode,
    check_range,
)
from .dialect import Dialect
from .words import GcodeSyntaxError, Tokens, Word, tokenize

__all__ = [
    "MAX_VOLTAGE_STEP_V",
    "ParsedLine",
    "parse_line",
]

MAX_VOLTAGE_STEP_V = 50.0
"""Largest torch up/down step one request may ask for (``torch_up``/``torch_down``)."""


@dataclass(frozen=True, slots=True)
class ParsedLine:
    """One G-code line, split.

    ``commands`` are the plasma commands in execution (= line) order; ``motion`` is the rest
    of the line for the motion backend, or None when nothing is left: its words exactly as
    written, without the N word, comments and plasma words (adjacent words keep the spacing
    they had; one blank joins what was on either side of a removed word or comment);
    ``line_number`` is the N word, else the caller's ``line_number``; ``comment`` is the
    comment text, if any.
    """

    commands: tuple[Command, ...] = ()
    motion: str | None = None
    line_number: int | None = None
    comment: str | None = None


@dataclass(frozen=True, slots=True)
class _Context:
    line: int | None  # the resume line (G100 P0)
    dialect: Dialect


# --------------------------------------------------------------------------- tokens


def _lex(line: str) -> Tokens:
    """Words and comments of ``line``; a syntax error is a :class:`CommandError` naming it."""
    try:
        return tokenize(line)
    except GcodeSyntaxError as exc:
        raise CommandError(exc.text, exc.reason) from None


def _value(name: str, word: Word) -> float:
    """The number of ``word``; errors are named ``name``."""
    try:
        return word.value
    except GcodeSyntaxError as exc:
        raise CommandError(name, exc.reason) from None


def _whole(name: str, value: float) -> int:
    if not value.is_integer():
        raise CommandError(name, f"{value:g} is not a whole number")
    return int(value)


# --------------------------------------------------------------------------- parameters


class _Params:
    """The parameter words of one plasma command, checked against what it takes."""

    def __init__(self, command: str, words: Sequence[Word], allowed: str) -> None:
        self.command = command
        self.values: dict[str, float] = {}
        for word in words:
            name = self.name(word.letter)
            if word.letter not in allowed:
                raise CommandError(name, "unknown parameter")
            if word.letter in self.values:
                raise CommandError(name, "duplicate parameter")
            self.values[word.letter] = _value(name, word)

    def name(self, letter: str) -> str:
        return f"{self.command} {letter}"

    def get(self, letter: str) -> float | None:
        return self.values.get(letter)

    def require(self, letter: str) -> float:
        value = self.values.get(letter)
        if value is None:
            raise CommandError(self.name(letter), "required parameter is missing")
        return value

    def positive(self, letter: str) -> float:
        value = self.require(letter)
        if value <= 0:
            raise CommandError(self.name(letter), f"{value:g} must be greater than 0")
        return value

    def non_negative(self, letter: str) -> float:
        value = self.require(letter)
        if value < 0:
            raise CommandError(self.name(letter), f"{value:g} must not be negative")
        return value

    def choice(self, letter: str, choices: Sequence[int]) -> int:
        value = self.require(letter)
        if value not in choices:
            allowed = ", ".join(str(c) for c in choices[:-1]) + f" or {choices[-1]}"
            raise CommandError(self.name(letter), f"{value:g} must be {allowed}")
        return int(value)


def _single(command: str, letter: str, words: Sequence[Word]) -> tuple[Word | None, list[Word]]:
    """Split the one ``letter`` word (refusing a second) from the other words."""
    found = [w for w in words if w.letter == letter]
    if len(found) > 1:
        raise CommandError(f"{command} {letter}", "duplicate parameter")
    return (found[0] if found else None), [w for w in words if w.letter != letter]


# --------------------------------------------------------------------------- MASSO


def _g200(words: Sequence[Word], _ctx: _Context) -> Command:
    p = _Params("G200", words, "FPDCVAOS")
    if not p.values:
        return LegacyMode()
    default = CutParams()

    def get(letter: str, fallback: float) -> float:
        value = p.get(letter)
        return fallback if value is None else value

    voltage = p.get("V")
    return SetCutParams(
        CutParams(
            touch_feed_mm_min=get("F", default.touch_feed_mm_min),
            pierce_height_mm=get("P", default.pierce_height_mm),
            pierce_delay_ms=get("D", default.pierce_delay_ms),
            cut_height_mm=get("C", default.cut_height_mm),
            cut_voltage_v=default.cut_voltage_v if voltage is None else (voltage or None),
            anti_dive_percent=get("A", default.anti_dive_percent),
            ohmic=bool(p.choice("O", (0, 1))) if "O" in p.values else default.ohmic,
            stop_after_pierce=(
                bool(p.choice("S", (0, 1))) if "S" in p.values else default.stop_after_pierce
            ),
        )
    )


_TOOLS_NOT_HERE = {1: "the scribe", 2: "the spotting torch"}


def _plasmac_tool(command: str, p: _Params, *, stop: bool) -> None:
    """PlasmaC's ``$`` word: $0 the torch, $1 scribe, $2 spotting; M5 $-1 stops them all."""
    if "$" not in p.values:
        return
    tool = _whole(p.name("$"), p.values["$"])
    if tool == 0 or (stop and tool == -1):
        return
    name = f"{command} ${tool}"
    if tool in _TOOLS_NOT_HERE:
        raise CommandError(name, f"{_TOOLS_NOT_HERE[tool]} is not on this board (only $0)")
    raise CommandError(name, "not a PlasmaC tool ($0 torch" + (", $-1 all" if stop else "") + ")")


def _m3(words: Sequence[Word], ctx: _Context) -> Command:
    # S is a spindle speed (PlasmaC M3 $0 S1, grbl M03 S1000): it means nothing to a torch.
    p = _Params("M3", words, "$S")
    _plasmac_tool("M3", p, stop=False)
    return TorchStart(relay=ctx.dialect is Dialect.RELAY)


def _m5(words: Sequence[Word], _ctx: _Context) -> Command:
    p = _Params("M5", words, "$S")
    _plasmac_tool("M5", p, stop=True)
    return TorchStop()


def _m190(words: Sequence[Word], _ctx: _Context) -> Command:
    p = _Params("M190", words, "P")
    number = _whole(p.name("P"), p.require("P"))
    if number < -1:
        raise CommandError(p.name("P"), f"{number} is not a material number (-1 = the previous)")
    return SelectMaterial(number)


def _m666(words: Sequence[Word], _ctx: _Context) -> Command:
    _Params("M666", words, "")
    return ThcEnable(False)


def _m667(words: Sequence[Word], _ctx: _Context) -> Command:
    p = _Params("M667", words, "F")
    return ThcEnable(True, z_feed_mm_min=p.positive("F") if "F" in p.values else None)


def _m6(words: Sequence[Word], ctx: _Context) -> Command:
    p = _Params("M6", words, "T")
    tool = _whole(p.name("T"), p.require("T"))
    if tool < 0:
        raise CommandError(p.name("T"), f"{tool} is not a tool number")
    if ctx.dialect is Dialect.PLASMAC:
        # PlasmaC selects its scribe and spotting torch with M3 $1 / $2 (refused there): a
        # T<n> M6 is a tool number (a 2008 SheetCam post's T1 is its plasma tool).
        return PlasmaMode(tool, torch=True)
    return PlasmaMode(tool)


# --------------------------------------------------------------------------- RosettaCNC G100

MAX_PIERCE_DELAY_S = 10.0  # as G200 D's 10 000 ms

_G100_NOT_PLASMA = {
    1: "go to a position",
    2: "axis-free movement",
    3: "continuous axis movement",
    8: "lube request",
    1000: "Modbus shared area",
}


def _g100(words: Sequence[Word], ctx: _Context) -> Command:
    p_word, rest = _single("G100", "P", words)
    if p_word is None:
        raise CommandError("G100 P", "required parameter is missing (selects the function)")
    function = _whole("G100 P", _value("G100 P", p_word))
    command = f"G100 P{function}"
    if function in _G100_NOT_PLASMA:
        raise CommandError(command, f"not a plasma function: {_G100_NOT_PLASMA[function]}")
    if function == 0:
        _Params(command, rest, "")
        return ResumePoint(ctx.line)
    if function == 4:
        p = _Params(command, rest, "A")
        return SelectCurrent(check_range(p.name("A"), p.positive("A"), 0.0, 400.0))
    if function == 5:
        p = _Params(command, rest, "AB")
        if p.choice("A", (0, 1)) == 1:
            return VoltageMode(True)
        return VoltageMode(False, check_range(p.name("B"), p.require("B"), 50.0, 300.0))
    if function == 6:
        p = _Params(command, rest, "ABCDEFHI")
        # Checked here, in RosettaCNC's words and units: the cut parameters they become
        # would name MASSO's G200 letters (and D in milliseconds) to a Rosetta user.
        delay_s = p.non_negative("E")
        if delay_s > MAX_PIERCE_DELAY_S:
            hint = (f"; {delay_s:g} looks like milliseconds: E{delay_s / 1000:g} is "
                    f"{delay_s / 1000:g} s" if delay_s >= 100 else "")  # fmt: skip
            raise CommandError(
                p.name("E"), f"pierce delay {delay_s:g} s is out of range "
                f"0..{MAX_PIERCE_DELAY_S:g} (seconds){hint}",
            )  # fmt: skip
        return ProbeAndStart(
            z_feed_mm_min=p.positive("A"),
            touch_target_z_mm=p.require("B"),
            touch_feed_mm_min=check_range(p.name("C"), p.positive("C"), 1.0, 3000.0),
            pierce_height_mm=check_range(p.name("D"), p.positive("D"), 0.5, 25.0),
            pierce_delay_s=delay_s,
            arc_ok_timeout_s=p.positive("F"),
            cut_height_mm=check_range(p.name("H"), p.positive("H"), 0.2, 10.0),
            mode=p.choice("I", (0, 1, 2, 3)) if "I" in p.values else 0,
        )
    if function == 7:
        p = _Params(command, rest, "A")
        return ThcEnable(bool(p.choice("A", (0, 1))))
    raise CommandError(command, "unknown G100 function")


# --------------------------------------------------------------------------- LinuxCNC PlasmaC

_PLASMAC_OUTPUTS = {0: "a digital output", 1: "arc-OK ignore"}


def _thc_output(code: int) -> Callable[[Sequence[Word], _Context], Command]:
    """M62/M64 P2 (THC off) and M63/M65 P2 (THC on), P3 torch disable/enable (hole
    over-cut); 62/63 wait for the next motion, 64/65 act at once."""
    command = f"M{code}"

    def parse(words: Sequence[Word], _ctx: _Context) -> Command:
        p = _Params(command, words, "P")
        output = _whole(p.name("P"), p.require("P"))
        enabled, synchronized = code in (63, 65), code in (62, 63)
        if output == 2:
            return ThcEnable(enabled=enabled, synchronized=synchronized)
        if output == 3:
            return TorchEnable(enabled=enabled, synchronized=synchronized)
        what = _PLASMAC_OUTPUTS.get(output, "a digital output")
        raise CommandError(
            f"{command} P{output}",
            f"{what} is not a plasma function of ours: only P2 (THC) and P3 (torch)",
        )

    return parse


def _velocity_reduction(code: int) -> Callable[[Sequence[Word], _Context], Command]:
    """M67 (with the next motion) / M68 (at once) E3 Q<percent>."""
    command = f"M{code}"

    def parse(words: Sequence[Word], _ctx: _Context) -> Command:
        p = _Params(command, words, "EQ")
        channel = _whole(p.name("E"), p.require("E"))
        if channel != 3:
            raise CommandError(
                f"{command} E{channel}", "not a plasma function of ours; only E3 (velocity)"
            )
        percent = check_range(p.name("Q"), p.require("Q"), 0.0, 100.0)
        return VelocityReduction(percent, synchronized=code == 67)

    return parse


# --------------------------------------------------------------------------- Z: the board's


def _probe(code: str, require_contact: bool) -> Callable[[Sequence[Word], _Context], Command]:
    """G38.2/G38.3 (LinuxCNC, grbl) and G31 (Mach3) along Z: the board probes and stops."""

    def parse(words: Sequence[Word], _ctx: _Context) -> Command:
        p = _Params(code, words, "ZF")
        return ProbeSurface(p.require("Z"), p.positive("F"), require_contact)

    return parse


def _probe_away(code: str, require_release: bool) -> Callable[[Sequence[Word], _Context], Command]:
    """G38.4/G38.5 along Z: the board moves up until the touch-off sensors release."""

    def parse(words: Sequence[Word], _ctx: _Context) -> Command:
        p = _Params(code, words, "ZF")
        return ProbeSurface(p.require("Z"), p.positive("F"), require_release, away=True)

    return parse


_MOTION_G = {0.0: "G0", 1.0: "G1"}
_NO_Z_G = {2.0: "G2", 3.0: "G3", 28.0: "G28", 30.0: "G30"}
_ORIGIN_G = {92.0: "G92", 10.0: "G10"}


def _z_commands(words: list[Word], heads: Sequence[Word]) -> tuple[list[Command], list[Word]]:
    """The Z word of a motion line as the board's command (docs: Z belongs to the board).

    Returns the commands and the words left for motion. ``G0``/``G1 Z`` is a Z move (G1
    needs its F on the line: the daemon does not track the modal feed), ``G53`` makes it a
    machine Z; ``G92 Z``/``G10 L20 Z`` set the work Z origin (``G92.1`` clears it)."""
    values = {_value("G", h): h for h in heads if h.letter == "G"}
    if 92.1 in values:
        return [SetWorkZ(None)], [w for w in words if w is not values[92.1]]
    z_words = [w for w in words if w.letter == "Z"]
    if not z_words:
        return [], words
    if len(z_words) > 1:
        raise CommandError("Z", "given twice")
    z = _value("Z", z_words[0])
    rest = [w for w in words if w is not z_words[0]]
    for code in _ORIGIN_G:
        if code in values:
            if code == 10.0:
                l_word = next((w for w in words if w.letter == "L"), None)
                if l_word is None or _value("G10 L", l_word) != 20.0:
                    raise CommandError("G10 Z", "only G10 L20 sets the Z origin")
            # G92 X0 Y0 Z0: the Z origin is the board's, the XY one stays with motion.
            left = rest if any(w.letter in "XYABC" for w in rest) else []
            return [SetWorkZ(z)], left
    for code, name in _NO_Z_G.items():
        if code in values:
            raise CommandError(f"{name} Z", "Z belongs to the board: move Z on its own line")
    motion = [values[c] for c in _MOTION_G if c in values]
    if not motion:
        raise CommandError(f"Z{z_words[0].number}", "no G0 or G1 on the line (the daemon "
                           "does not track the modal motion mode)")  # fmt: skip
    feed: float | None = None
    if _value("G", motion[-1]) == 1.0:
        f_word = next((w for w in words if w.letter == "F"), None)
        if f_word is None:
            raise CommandError("G1 Z", "F is required on the line")
        feed = _value("F", f_word)
        if feed <= 0:
            raise CommandError("G1 F", f"{feed:g} must be greater than 0")
    command = ProgramZMove(z, feed, machine=53.0 in values)
    if not any(w.letter in "XYABCIJ" for w in rest):
        # Z alone: the move heads go; modal words (G90, the F) stay with motion.
        moves = {id(h) for h in motion} | ({id(values[53.0])} if 53.0 in values else set())
        rest = [w for w in rest if id(w) not in moves]
    return [command], rest


# --------------------------------------------------------------------------- lines

_Handler = Callable[[Sequence[Word], _Context], Command]

_PLASMA_G: dict[float, tuple[str, _Handler]] = {
    31.0: ("G31", _probe("G31", True)),
    38.2: ("G38.2", _probe("G38.2", True)),
    38.3: ("G38.3", _probe("G38.3", False)),
    38.4: ("G38.4", _probe_away("G38.4", True)),
    38.5: ("G38.5", _probe_away("G38.5", False)),
    100.0: ("G100", _g100),
    200.0: ("G200", _g200),
}
_PLASMA_M: dict[float, tuple[str, _Handler]] = {
    3.0: ("M3", _m3),
    5.0: ("M5", _m5),
    6.0: ("M6", _m6),
    62.0: ("M62", _thc_output(62)),
    63.0: ("M63", _thc_output(63)),
    64.0: ("M64", _thc_output(64)),
    65.0: ("M65", _thc_output(65)),
    67.0: ("M67", _velocity_reduction(67)),
    68.0: ("M68", _velocity_reduction(68)),
    190.0: ("M190", _m190),
    666.0: ("M666", _m666),
    667.0: ("M667", _m667),
}


@dataclass(slots=True)
class _Group:
    head: Word | None  # the G/M word; None only for a line without any
    handler: _Handler | None  # None: not a plasma command, the words go to motion
    params: list[Word]


def _classify(word: Word) -> tuple[str, _Handler] | None:
    table = _PLASMA_G if word.letter == "G" else _PLASMA_M
    return table.get(_value(word.letter, word))


def _motion_text(line: str, words: Sequence[Word]) -> str | None:
    """The kept words as written: runs of adjacent words verbatim, runs joined by one blank."""
    runs: list[str] = []
    first = previous = None
    for word in words:
        if previous is None or word.index != previous.index + 1:
            if first is not None and previous is not None:
                runs.append(line[first.start : previous.end])
            first = word
        previous = word
    if first is not None and previous is not None:
        runs.append(line[first.start : previous.end])
    return " ".join(runs) or None


def parse_line(
    line: str, *, line_number: int | None = None, dialect: Dialect = Dialect.MASSO
) -> ParsedLine:
    """Split one G-code line into plasma commands, motion text, line number and comment.

    ``line_number`` is the caller's position of the line (used when the line has no N word,
    and for ``G100 P0`` resume points); ``dialect`` decides the few forms dialects disagree
    on (:mod:`.dialect`). Raises :class:`CommandError` naming the word.
    """
    tokens = _lex(line)
    comments = tokens.comments
    words = list(tokens.words)

    number_words = [w for w in words if w.letter == "N"]
    if len(number_words) > 1:
        raise CommandError("N", "more than one line number")
    n_word: int | None = None
    if number_words:
        n_word = _whole("N", _value("N", number_words[0]))
        if n_word < 0:
            raise CommandError("N", f"{n_word} is not a line number")
    words = [w for w in words if w.letter != "N"]

    heads = {w.index: _classify(w) for w in words if w.letter in "GM"}
    tool_changes = [i for i, kind in heads.items() if kind is not None and kind[0] == "M6"]
    if len(tool_changes) > 1:
        raise CommandError("M6", "more than one tool change on the line")
    tool_word: Word | None = None
    if tool_changes:
        tool_word, words = _single("M6", "T", words)

    leading: list[Word] = []
    groups: list[_Group] = []
    for word in words:
        if word.index in heads:
            kind = heads[word.index]
            groups.append(_Group(word, None if kind is None else kind[1], []))
        elif groups:
            groups[-1].params.append(word)
        else:
            leading.append(word)
    if groups:
        groups[0].params[:0] = leading
    elif leading:
        groups.append(_Group(None, None, leading))

    commands: list[Command] = []
    motion: list[Word] = []
    ctx = _Context(line_number if line_number is not None else n_word, dialect)
    if dialect is Dialect.PLASMAC:
        commands.extend(DefineMaterial(c) for c in comments if c.startswith("o="))
    for group in groups:
        if group.handler is None:
            for word in group.params:
                _value(word.letter, word)
            motion.extend(group.params)
            if group.head is not None:
                motion.append(group.head)
        else:
            params = group.params
            if (
                group.head is not None
                and tool_word is not None
                and group.head.index in tool_changes
            ):
                params = [tool_word, *params]
            if group.head is not None and group.head.index in tool_changes:
                # M06 T1 F5840 (posts write the feed there): the F is the machine's.
                motion.extend(w for w in params if w.letter == "F")
                params = [w for w in params if w.letter != "F"]
            commands.append(group.handler(params, ctx))
    motion.sort(key=lambda w: w.index)
    heads_left = [w for w in motion if w.letter in "GM"]
    z_commands, motion = _z_commands(motion, heads_left)
    commands.extend(z_commands)

    return ParsedLine(
        commands=tuple(commands),
        motion=_motion_text(line, motion),
        line_number=n_word if n_word is not None else line_number,
        comment="; ".join(comments) if comments else None,
    )
