"""A program file, as the sender runs it: dialect rules, NGC evaluation, Z to the board.

:class:`ProgramPlan` turns the lines of a program into :data:`Step` s, lazily and in order:

* :class:`DaemonStep`: a plain line for the daemon (plasma words, Z moves, probes, the Z
  origin, materials) or a feed note (``G1 F<mm/min>``: the anti-dive reference);
* :class:`MotionStep`: a plain line for the XY motion backend (modal-only lines included);
* :class:`DwellStep`: ``G4 P``, after motion and Z have finished;
* :class:`Refused`: a line that cannot run, with the reason naming what the user wrote.

Rules, per dialect (:class:`~dthc_bridge.controller.dialect.Dialect`):

* NGC dialects (``plasmac``, ``relay``, ``rosetta``) are evaluated by
  :mod:`.ngc` first, so downstream only sees plain lines; in ``masso`` text after ``#`` is
  a comment (an option of the MASSO post).
* Z belongs to the board: a Z word becomes a daemon line in millimetres, absolute, work
  coordinates (``G53``: machine); a line mixing XY and Z moves Z first going up and last
  going down, so the torch never drags. PlasmaC strips Z moves unless
  ``#<keep-z-motion> = 1``; a probe (``G38.2``) and the Z origin (``G92 Z``) always pass.
* Units and distance mode (``G20``/``G21``, ``G90``/``G91``) are tracked here: the daemon's
  Z words and feed notes are always mm and absolute; the motion backend gets the program's
  own modal lines and keeps its own state.
* ``#<pierce-only> = 1`` (PlasmaC): each cut pierces, then ``M5`` follows at once and the
  cut's motion is skipped. ``#<holes>``, ``#<h_diameter>``, ``#<h_velocity>``,
  ``#<oclength>``, ``#<m_diameter>``, ``#<tube-cut>`` belong to QtPlasmaC's G-code filter,
  which rewrites hole paths: they are not applied (a warning says so once); the program's
  own ``M67 E3`` and ``M62 P3`` lines are.
* ``M66 P3 L3 Q<t>`` (wait for the material change) is satisfied when the daemon has
  answered the ``M190`` before it: a :class:`DaemonStep` answers only once applied.
* A shop code table (``H1`` → ``M667``) rewrites words before parsing; the ``relay``
  dialect starts with FireControl's ``H1``/``H0`` (THC on/off).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

from ..code_map import code_key
from ..controller.commands import (
    CommandError,
    ProbeSurface,
    ProgramZMove,
    SetWorkZ,
    TorchStart,
    TorchStop,
)
from ..controller.dialect import Dialect
from ..controller.gcode import ParsedLine, parse_line
from ..controller.words import GcodeSyntaxError, Word, tokenize
from ..materials.magic import TUBE_DEFAULTS
from .modal import ModalState
from .ngc import EvaluatedLine, NgcError, NgcProgram
from .ngc import format_number as _fmt

__all__ = [
    "DEFAULT_CODES",
    "DaemonStep",
    "DwellStep",
    "MotionStep",
    "ProgramPlan",
    "Refused",
    "Step",
    "detect_dialect",
]

CUT_FEED_PIN = "plasmac.cut-feed-rate"
FLOAT_TRAVEL_PIN = "plasmac.float-switch-travel"
KERF_WIDTH_PINS = ("qtplasmac.kerf_width-f", "plasmac_run.kerf-width-f")  # today's, 2019's
READABLE_PINS = (CUT_FEED_PIN, *KERF_WIDTH_PINS, FLOAT_TRAVEL_PIN)
"""The HAL pins a program may read (``#<_hal[...]>``): the daemon answers each from the
material in force or its configuration, in mm (mm/min for the feed); the plan gives them
in the program's units. The keys of the daemon's ``pins`` answer (program_start, M190)."""

DEFAULT_CODES: Mapping[Dialect, Mapping[str, str]] = {
    # FireControl-style programs switch their THC with H1 / H0.
    Dialect.RELAY: {"H1": "M667", "H0": "M666"},
}

_PROBE_G = frozenset({31.0, 38.2, 38.3, 38.4, 38.5})  # the board probes (38.4/5: away, up)
_ORIGIN_G = frozenset({92.0, 10.0, 92.1})  # G92 Z, G10 L20 Z, G92.1: the board's Z origin

_FILTER_PARAMS = ("holes", "h_diameter", "h_velocity", "oclength", "m_diameter")


@dataclass(frozen=True, slots=True)
class DaemonStep:
    """A line for the daemon, and its commands as the plan parsed it: its readers (the
    sender, the path) take them from here instead of parsing the line again (STYLE 24).
    The daemon parses the text it is sent, in the same dialect."""

    line: str
    source_line: int
    text: str  # the program's line as written (evaluated)
    parsed: ParsedLine
    feed_note: bool = False  # only the anti-dive reference: never waits for motion


@dataclass(frozen=True, slots=True)
class MotionStep:
    """A line for the motion backend, and its words (read once, when it is made)."""

    line: str
    source_line: int
    text: str
    words: tuple[Word, ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "words", tokenize(self.line).words)


@dataclass(frozen=True, slots=True)
class DwellStep:
    seconds: float
    source_line: int
    text: str


@dataclass(frozen=True, slots=True)
class Refused:
    source_line: int
    text: str
    error: str


Step = DaemonStep | MotionStep | DwellStep | Refused


def detect_dialect(
    lines: Sequence[str], fallback: tuple[Dialect, str] | None = None
) -> tuple[Dialect, str]:
    """The dialect a program is most likely written in, and why (what was found).

    ``fallback``: the dialect (and its reason) when nothing dialect-specific is found; the
    daemon's ``controller.dialect`` where it is known, else NGC (LinuxCNC)."""
    text = "\n".join(lines)
    checks: list[tuple[Dialect, str, str]] = [
        (Dialect.MASSO, r"\bT\s*112\b|\bG\s*200\b|\bM\s*66[67]\b", "T112/G200/M666/M667"),
        (Dialect.ROSETTA, r"\bG\s*100\s*P", "G100 P"),
        (Dialect.PLASMAC, r"\$\s*-?[0-2]\b|\bM\s*190\b|\(o=|#<|\bo\s*(?:<|\d)",
         "$n/M190/(o=)/#<…>/o-words"),
        # Relay only when the program handles Z itself: it probes and sets its Z origin.
        (Dialect.RELAY, r"\bG\s*(?:38\.[2-5]|31)\b(?=[\s\S]*\bG\s*(?:92|10\s*L\s*20)\b[^\n]*Z)",
         "a probe (G38.2/G31) and its own Z origin (G92 Z): the program handles Z itself"),
    ]  # fmt: skip
    for dialect, pattern, found in checks:
        if re.search(pattern, text, re.IGNORECASE):
            return dialect, f"found {found}"
    dialect, why = fallback or (Dialect.PLASMAC, "NGC (LinuxCNC) assumed")
    return dialect, f"nothing dialect-specific found: {why}"


# M codes a motion controller runs itself (RS274NGC, LinuxCNC's user M100-M199): program
# flow, tool change, coolant, overrides, modal state.
MOTION_M_CODES = frozenset(
    {0.0, 1.0, 2.0, 30.0, 60.0, 6.0, 7.0, 8.0, 9.0, 4.0, 48.0, 49.0, 50.0, 51.0, 52.0, 53.0,
     61.0, 70.0, 71.0, 72.0, 73.0, *(float(n) for n in range(100, 200))}
)  # fmt: skip


def unknown_m_codes(steps: Sequence[Step]) -> list[Refused]:
    """For a program that plans no cut: the M codes neither the daemon nor a motion
    controller knows (a shop's post switching the torch with M13/M15), each refused at its
    first line with the --code mapping that would make them a torch start and stop. The
    check and the sender refuse such a program alike (a cut-less run is not "OK")."""
    first: dict[float, MotionStep] = {}
    for step in steps:
        if isinstance(step, MotionStep):
            for word in step.words:
                if word.letter == "M" and word.value not in MOTION_M_CODES:
                    first.setdefault(word.value, step)
    names = [f"M{code:g}" for code in first]
    if not names:
        return []
    hint = (f"--code {names[0]}=M3 --code {names[1]}=M5" if len(names) >= 2
            else f"--code {names[0]}=M3")  # fmt: skip
    return [
        Refused(step.source_line, step.line.strip(), f"{name}: not a code the daemon knows, "
                f"and the program has no cut: if these switch the torch, map them ({hint})")
        for name, step in zip(names, first.values(), strict=True)
    ]  # fmt: skip


_TUBE_MATERIAL = re.compile(r"\(\s*o\s*=\s*0\b[^)]*\)")


def _with_tube_defaults(match: re.Match[str]) -> str:
    """A tube program's ``(o=0, pd=...)`` with QtPlasmaC's defaults for what it left out."""
    comment = match.group(0)[1:-1]
    given = {part.split("=", 1)[0].strip() for part in comment.split(",") if "=" in part}
    if "pd" not in given:
        return match.group(0)  # refused by the daemon as any material without pd
    missing = [f"{key}={value}" for key, value in TUBE_DEFAULTS.items() if key not in given]
    return "(" + ", ".join([comment.strip(), *missing]) + ")"


def _strip_hash_comment(line: str) -> str:
    """MASSO: ``#`` outside parentheses starts a comment."""
    depth = 0
    for i, ch in enumerate(line):
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth = max(0, depth - 1)
        elif ch == "#" and depth == 0:
            return line[:i]
    return line


@dataclass
class ProgramPlan:
    """The steps of one program. ``pins_mm`` holds what ``#<_hal[...]>`` reads (in mm, the
    program reads them in its units; READABLE_PINS): the caller sets them from the daemon's
    answers (program_start, ``M190``) before the next step is taken."""

    lines: Sequence[str]
    dialect: Dialect
    codes: Mapping[str, str] = field(default_factory=dict)
    pins_mm: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    z_stripped: int = 0

    def __post_init__(self) -> None:
        self._codes = {**DEFAULT_CODES.get(self.dialect, {}), **self.codes}
        self._modal = ModalState()
        self._z_mm: float | None = None  # work Z as last commanded; None: unknown
        self._noted_feed_mm_min: float | None = None  # the cutting feed the daemon was told
        self._ngc: NgcProgram | None = None
        self._in_cut = False
        self._pierce_only_skip = False
        self._warned_filter = False
        self._dialect_found = False  # a streamed plan has found its dialect in the lines
        self._probed = False  # a probe ran (G38.x/G31)
        self._touched_off = False  # ... and the program set its Z origin after it
        self._stopped_by_probe_down = False  # Z rests where a probe down stopped (G38.2)
        self._warned_zero_at_switch = False

    # --- program parameters ----------------------------------------------------------------

    def parameter(self, name: str) -> float | None:
        """A program setting (``#<keep-z-motion>``): set at the top level, read anywhere."""
        return None if self._ngc is None else self._ngc.get(name, top_level=True)

    @property
    def keep_z_motion(self) -> bool:
        return (
            self.dialect is not Dialect.PLASMAC
            or bool(self.parameter("keep-z-motion"))
            or self.tube_cut  # a tube program probes and moves Z itself
        )

    @property
    def tube_cut(self) -> bool:
        """QtPlasmaC's ``#<tube-cut> = 1``: Z motion kept, and a temporary material may give
        only its pierce delay (pierce height, cut height and feed 0: the program's own)."""
        return self.dialect is Dialect.PLASMAC and bool(self.parameter("tube-cut"))

    @property
    def pierce_only(self) -> bool:
        return bool(self.parameter("pierce-only"))

    def note_pins(self, answer: Mapping[str, object]) -> None:
        """The daemon's answer to program_start or M190: the pins it gives (in mm)."""
        pins = answer.get("pins")
        if isinstance(pins, Mapping):
            for pin, value in pins.items():
                if pin in READABLE_PINS and isinstance(value, int | float):
                    self.pins_mm[pin] = float(value)
        elif isinstance(feed := answer.get("cut_feed_mm_min"), int | float):  # an older daemon
            self.pins_mm[CUT_FEED_PIN] = float(feed)

    def _hal(self, pin: str) -> float:
        if pin not in READABLE_PINS:
            raise ValueError(
                f"HAL pin {pin!r} is not one the daemon answers (readable: "
                f"{', '.join(READABLE_PINS)})"
            )
        value = self.pins_mm.get(pin)
        if value is None:  # the daemon did not say (it always does)
            raise ValueError(f"HAL pin {pin!r}: the daemon gave no value")
        return value / self._modal.mm_per_unit

    # --- steps -----------------------------------------------------------------------------

    def _source(self) -> Iterator[EvaluatedLine]:
        if self.dialect is Dialect.MASSO:
            for number, line in enumerate(self.lines, start=1):
                yield EvaluatedLine(number, _strip_hash_comment(line))
            return
        self._ngc = NgcProgram(self.lines, hal=self._hal)
        yield from self._ngc.evaluate()

    def steps(self) -> Iterator[Step]:
        """Every step in order; a :class:`Refused` for each line that cannot run (after an
        NGC error the program's flow is unknown, so nothing follows it)."""
        source = self._source()
        while True:
            try:
                line = next(source)
            except StopIteration:
                return
            except NgcError as exc:
                # The whole line as written; the error names the construct in it.
                yield Refused(exc.line, self._written(exc.line), f"{exc.text}: {exc.reason}")
                return
            if not line.text.strip():
                continue
            try:
                yield from self._line(line.source_line, line.text)
            except (CommandError, GcodeSyntaxError, ValueError) as exc:
                yield Refused(line.source_line, self._written(line.source_line), str(exc))
            self._check_filter_params()

    def stream(self, text: str, *, detect: bool = False) -> list[Step]:
        """The steps of one more line of a program that arrives line by line, as a grbl
        sender streams it: the same rules as :meth:`steps`, with what the lines before it
        set (modal state, parameters, the touch-off). ``lines`` grows with each one; a
        refused line is a :class:`Refused` and changes nothing after it.

        ``detect``: the dialect is the one :func:`detect_dialect` finds in the lines so far,
        from the first line that shows one on (until then, the plan's own): a stream has no
        lines ahead to look at."""
        if not isinstance(self.lines, list):
            raise TypeError("a streamed plan starts from a list of lines (the ones so far)")
        self.lines.append(text)
        number = len(self.lines)
        if detect and not self._dialect_found:
            self._detect_streamed()
        try:
            if self.dialect is Dialect.MASSO:
                evaluated: EvaluatedLine | None = EvaluatedLine(number, _strip_hash_comment(text))
            else:
                if self._ngc is None:
                    self._ngc = NgcProgram([], hal=self._hal)
                evaluated = self._ngc.evaluate_streamed(number, text)
            if evaluated is None or not evaluated.text.strip():
                return []
            steps = list(self._line(number, evaluated.text))
        except NgcError as exc:
            return [Refused(number, text.strip(), f"{exc.text}: {exc.reason}")]
        except (CommandError, GcodeSyntaxError, ValueError) as exc:
            return [Refused(number, text.strip(), str(exc))]
        self._check_filter_params()
        return steps

    def _detect_streamed(self) -> None:
        dialect, why = detect_dialect(self.lines)
        if not why.startswith("found"):
            return
        self._dialect_found = True
        if dialect is not self.dialect:
            self.warnings.append(f"dialect {dialect} from line {len(self.lines)} on ({why})")
            self.dialect = dialect
            self._codes = {**DEFAULT_CODES.get(dialect, {}), **self.codes}

    def _written(self, number: int) -> str:
        """Line ``number`` (1-based) of the program as the user wrote it."""
        return self.lines[number - 1].strip() if 0 < number <= len(self.lines) else ""

    def _check_filter_params(self) -> None:
        if self._warned_filter or self._ngc is None:
            return
        for name in _FILTER_PARAMS:
            value = self.parameter(name)
            if value:
                self._warned_filter = True
                self.warnings.append(
                    f"#<{name}> = {value:g}: QtPlasmaC's hole handling is not applied here; "
                    "the program's own M67 E3 and M62 P3 lines are"
                )
                return

    def _line(self, number: int, text: str) -> Iterator[Step]:
        here = text.strip()  # as written: a mapped code is reported as the user wrote it
        text = self._mapped(text)
        if self.tube_cut:
            text = _TUBE_MATERIAL.sub(_with_tube_defaults, text)
        words = list(tokenize(text).words)
        gs = {w.value for w in words if w.letter == "G"}
        ms = {w.value for w in words if w.letter == "M"}
        self._track_modal(words)

        if 4.0 in gs:
            yield from self._dwell(number, here, words)
            return
        if 66.0 in ms:
            self._check_m66(words)
            return  # the M190 before it was answered once the material was applied
        probe = gs & _PROBE_G
        origin = (92.0 in gs or 10.0 in gs) and any(w.letter == "Z" for w in words)
        if probe and not self.keep_z_motion:
            # PlasmaC strips the Z moves that would lift the torch off the work again, and
            # its M3 touches off by itself (and refuses to start on a closed switch).
            raise CommandError(
                f"G{min(probe):g}", "a PlasmaC program's Z moves are stripped, so the torch "
                "would stay on the work after this probe and M3 would refuse to start: M3 "
                "touches off by itself (remove the probe), or set #<keep-z-motion> = 1 to run "
                "the program's own Z moves")  # fmt: skip
        if origin and self._stopped_by_probe_down:
            self._warn_zero_at_the_switch(number, words)
        self._probed = self._probed or bool(probe)
        self._touched_off = self._touched_off or (origin and self._probed)
        if probe or origin:
            self._stopped_by_probe_down = bool(probe) and not probe & {38.4, 38.5}
        elif any(w.letter == "Z" for w in words):
            self._stopped_by_probe_down = False  # Z moved on from where the probe stopped
        if probe or origin or 92.1 in gs:
            yield from self._board_z_line(number, here, words, bool(probe))
            return
        z_word = next((w for w in words if w.letter == "Z"), None)
        z_step: DaemonStep | None = None
        going_down = False
        if z_word is not None:
            z_step, going_down = self._z_move(number, here, words, z_word)
            words = [w for w in words if w is not z_word and not _is_g(w, 53.0)]
            text = _rebuild(text, words)
        parsed = parse_line(text, line_number=number, dialect=self.dialect)
        yield from self._split(number, here, text.strip(), parsed, (z_step, going_down))

    def _daemon(self, line: str, number: int, here: str, *, feed_note: bool = False) -> DaemonStep:
        """A line the plan writes for the daemon (Z in mm, a feed note), parsed as the
        daemon will parse it."""
        parsed = parse_line(line, line_number=number, dialect=self.dialect)
        return DaemonStep(line, number, here, parsed, feed_note=feed_note)

    def _warn_zero_at_the_switch(self, number: int, words: Sequence[Word]) -> None:
        """``G92 Z0`` right where a probe down stopped: on a float switch that is its travel
        below the surface, so every height after it is that much lower (a post for an ohmic
        probe needs no offset; one that knows its switch writes it: ``G92 Z-1.5``). A
        warning, not a refusal: the table may probe ohmically."""
        z = next(w for w in words if w.letter == "Z")
        if z.value != 0.0 or self._warned_zero_at_switch:
            return
        self._warned_zero_at_switch = True
        self.warnings.append(
            f"line {number}: Z0 set where the probe stopped; a float switch stops the probe "
            "its travel (controller.float_travel_mm) below the surface, so the program's "
            "heights are that much lower unless it probes ohmically (set the origin to minus "
            "the travel, e.g. G92 Z-1.5)"
        )

    def _mapped(self, text: str) -> str:
        if not self._codes:
            return text
        words = tokenize(text).words
        out, kept = [], 0
        for word in words:
            target = self._codes.get(code_key(word.letter, word.value)) if word.number else None
            if target is not None:
                out += [text[kept : word.start], target]
                kept = word.end
        return "".join(out) + text[kept:]

    def _track_modal(self, words: Sequence[Word]) -> None:
        self._modal.apply((w.letter, w.value) for w in words)

    def _dwell(self, number: int, here: str, words: Sequence[Word]) -> Iterator[Step]:
        p = next((w for w in words if w.letter == "P"), None)
        if p is None or p.value < 0:
            raise CommandError("G4 P", "a dwell needs P >= 0")
        others = [w for w in words if w.letter not in "GPN"]
        if others:
            raise CommandError(f"G4 {others[0].letter}", "put the dwell on its own line")
        yield DwellStep(p.value * self.dialect.dwell_unit_s, number, here)

    def _check_m66(self, words: Sequence[Word]) -> None:
        p = next((w for w in words if w.letter == "P"), None)
        if self.dialect is not Dialect.PLASMAC or p is None or p.value != 3.0:
            raise CommandError("M66", "only PlasmaC's M66 P3 (wait for the material) is understood")

    def _board_z_line(
        self, number: int, here: str, words: Sequence[Word], probe: bool
    ) -> Iterator[Step]:
        """G38.2/G31 probes and G92/G10 L20 Z origins: to the daemon, in mm. The line's
        other words (``G20 G90 G92.1`` in a preamble) still reach the motion backend."""
        units = self._modal.mm_per_unit
        parts: list[str] = []
        xy = [w for w in words if w.letter in "XYABC"]
        board = [
            w for w in words
            if (w.letter == "G" and w.value in _PROBE_G | _ORIGIN_G) or w.letter in "LPZ"
            or (w.letter == "F" and probe)
        ]  # fmt: skip
        for w in board:
            if w.letter == "F":
                parts.append(f"F{_fmt(w.value * units)}")
            else:
                scale = units if w.letter == "Z" else 1.0
                parts.append(f"{w.letter}{_fmt(w.value * scale)}")
        modal = [w for w in words if w not in board and w not in xy and w.letter != "N"]
        if modal:
            yield MotionStep(" ".join(f"{w.letter}{w.number}" for w in modal), number, here)
        self._z_mm = None  # where a probe stops, or what an origin makes Z read
        yield self._daemon(" ".join(parts), number, here)
        if any(_is_g(w, 92.1) for w in words):
            yield MotionStep("G92.1", number, here)  # the XY offsets go too
        if xy and not probe:
            g = next(w for w in words if w.letter == "G")
            rest = [g, *[w for w in words if w.letter in "LP"], *xy]
            yield MotionStep(" ".join(f"{w.letter}{w.number}" for w in rest), number, here)

    def _z_move(
        self, number: int, here: str, words: Sequence[Word], z: Word
    ) -> tuple[DaemonStep | None, bool]:
        """The daemon's Z line, and whether it goes down (then it runs after the XY move;
        from an unknown height a move counts as going up: Z first)."""
        modal = self._modal
        machine = any(_is_g(w, 53.0) for w in words)
        if modal.motion in (2, 3):
            raise CommandError(f"Z{z.number}", "Z belongs to the board: no helical arcs")
        value = modal.to_mm(z.value)
        if not modal.absolute and not machine:
            if self._z_mm is None:
                raise CommandError(f"Z{z.number}", "incremental Z (G91) from an unknown height")
            value += self._z_mm
        if not self.keep_z_motion:
            self.z_stripped += 1
            return None, False
        previous = self._z_mm
        self._z_mm = None if machine else value
        going_down = previous is not None and self._z_mm is not None and self._z_mm < previous
        if modal.motion == 1:
            if modal.feed_mm_min is None:
                raise CommandError("G1 Z", "no feed programmed (F)")
            line = f"G1 Z{_fmt(value)} F{_fmt(modal.feed_mm_min)}"
        else:
            line = f"{'G53 ' if machine else ''}G0 Z{_fmt(value)}"
        return self._daemon(line, number, here), going_down

    def _split(
        self,
        number: int,
        here: str,
        text: str,
        parsed: ParsedLine,
        z: tuple[DaemonStep | None, bool],
    ) -> Iterator[Step]:
        z_step, going_down = z
        commands = parsed.commands
        plasma = [c for c in commands if not isinstance(c, ProgramZMove | ProbeSurface | SetWorkZ)]
        motion = parsed.motion
        if self._pierce_only_skip and not plasma:
            return  # the cut of a pierce-only program: its motion is skipped
        if z_step is not None and not going_down:
            yield z_step
        if plasma:
            yield from self._plasma(number, here, text, parsed)
        if motion is not None:
            yield MotionStep(motion, number, here)
            note = self._feed_note(motion)
            if note is not None:
                yield self._daemon(note, number, here, feed_note=True)
        if z_step is not None and going_down:
            yield z_step

    def _plasma(self, number: int, here: str, text: str, parsed: ParsedLine) -> Iterator[Step]:
        starts = any(isinstance(c, TorchStart) for c in parsed.commands)
        if any(isinstance(c, TorchStart) and c.relay for c in parsed.commands) \
                and not self._touched_off:  # fmt: skip
            raise CommandError(
                _torch_word(here), "in the relay dialect this only switches the torch on, "
                "and the program has not touched off before it (a G38.2/G31 probe, then "
                "G92 Z or G10 L20 Z): the torch would fire at an unknown height. Leave the "
                "dialect to detection, or touch off in the program first")  # fmt: skip
        stops = any(isinstance(c, TorchStop) for c in parsed.commands)
        if stops and self._pierce_only_skip:
            self._pierce_only_skip = False
            return  # its M5 was sent right after the pierce
        yield DaemonStep(text, number, here, parsed)
        if starts or stops:
            self._z_mm = None  # the daemon moves Z in its sequence
        if starts and self.pierce_only and self.dialect is Dialect.PLASMAC:
            yield self._daemon("M5 $0", number, "(pierce only) M5 $0")
            self._pierce_only_skip = True

    def _feed_note(self, motion: str) -> str | None:
        """``G1 F<mm/min>`` for the daemon when the programmed cutting feed changes."""
        modal = self._modal
        words = tokenize(motion).words
        feed_mm_min = modal.feed_mm_min
        if modal.motion not in (1, 2, 3) or feed_mm_min is None:
            return None
        if not any(w.letter in "XYIJ" for w in words):
            return None  # a Z-only feed (G1 Z1.5 F600) is not the cutting feed
        if feed_mm_min == self._noted_feed_mm_min:
            return None
        self._noted_feed_mm_min = feed_mm_min
        return f"G1 F{_fmt(feed_mm_min)}"


def _torch_word(here: str) -> str:
    """The torch start as the user wrote it (``M3``, or a shop's own code mapped to it)."""
    try:
        words = tokenize(here).words
    except GcodeSyntaxError:
        return "M3"
    return next((f"{w.letter}{w.number}" for w in words if w.letter == "M"), "M3")


def _is_g(word: Word, value: float) -> bool:
    return word.letter == "G" and word.value == value


def _rebuild(text: str, words: Sequence[Word]) -> str:
    """The line with only ``words`` (comments dropped: they stay in the step's ``text``)."""
    return " ".join(text[w.start : w.end] for w in words)
