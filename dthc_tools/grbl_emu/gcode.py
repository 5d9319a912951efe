"""grbl 1.1's G-code parser, sans I/O: a block's words in, modal state and actions out.

Follows the published grbl 1.1 command set and its error rules: every word is checked
first (letter, number, modal group, repeats, negative values), then the block as a whole
(feed rate defined, arc geometry, unused words), and only a block without error changes any
state; a refused block raises :class:`GcodeRefused` with grbl's number and changes nothing.

Positions are machine millimetres (``MPos``); work offsets (G54-G59 table, G92, G43.1) are
kept here as grbl's parser keeps them. The parser runs ahead of the motion: ``position`` is
where the last planned block ends, not where the table is.

Deviations, because this machine is an XY table whose Z is another board's: arcs only in the
XY plane (G18/G19 are accepted as modes, an arc in them is ``error:20``); no probe input
(G38.x is ``error:20``); Z moves are tracked but take no time.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from dthc_bridge.program.modal import MM_PER_INCH, ModalState

from .blocks import Action, Dwell, Move, MoveKind, ProgramStop, Vec3, Word
from .codes import GcodeRefused, Status

__all__ = ["GcodeInterpreter", "Modal"]

MAX_LINE_NUMBER = 9_999_999
MAX_TOOL_NUMBER = 255
N_COORD_SYSTEMS = 6
ARC_RADIUS_TOLERANCE_MM = 0.005  # start and end radius may differ this much...
ARC_RADIUS_TOLERANCE_MAX_MM = 0.5  # ...and beyond it at most 0.1 % of the radius, up to this
ARC_RADIUS_TOLERANCE_REL = 0.001


@dataclass(slots=True)
class Modal(ModalState):
    """The parser's modal state (what ``$G`` shows): the program's units, distance mode,
    plane and motion (80 after G80) as every reader keeps them (ModalState; grbl sets
    them itself, after its modal-group checks), and grbl's other groups. grbl keeps the
    feed itself (``feed_value``: in G93 it is not a speed)."""

    inverse_time: bool = False
    wcs: int = 0  # 0..5: G54..G59
    tlo_dynamic: bool = False  # G43.1 (else G49)
    spindle: int = 5  # 3, 4 or 5
    mist: bool = False
    flood: bool = False


_VALUE_LETTERS = frozenset("FIJKLNPRSTXYZ")
_AXES = "XYZ"


def _split_code(value: float) -> tuple[int, int]:
    """grbl's command number and two-digit mantissa: G38.2 -> (38, 20)."""
    code = math.trunc(value)
    return code, round(100.0 * (value - code))


@dataclass(slots=True)
class _Block:
    """What one block asks for, before it is committed."""

    modal: Modal
    groups: set[str] = field(default_factory=set)
    values: dict[str, float] = field(default_factory=dict)
    non_modal: str = ""  # G4 G10 G28 G28.1 G30 G30.1 G53 G92 G92.1
    axis_command: str = ""  # "motion", "non_modal", "tlo"
    program_flow: int | None = None  # 0, 2, 30


class GcodeInterpreter:
    """grbl's G-code parser state and its block execution (without the motion itself)."""

    def __init__(
        self,
        *,
        mist_coolant: bool = False,
        jog_travel_ok: Callable[[Move], bool] | None = None,
    ) -> None:
        self._mist_coolant = mist_coolant
        self._jog_travel_ok = jog_travel_ok
        self.modal = Modal()
        self.feed_value = 0.0  # mm/min in G94, 1/min in G93 (as grbl stores it)
        self.spindle_rpm = 0.0
        self.tool = 0
        self.position: list[float] = [0.0, 0.0, 0.0]
        # Persistent (EEPROM in grbl): survive a reset.
        self.wcs_offsets: list[list[float]] = [[0.0, 0.0, 0.0] for _ in range(N_COORD_SYSTEMS)]
        self.g28: list[float] = [0.0, 0.0, 0.0]
        self.g30: list[float] = [0.0, 0.0, 0.0]
        # Volatile: cleared by a reset.
        self.g92: list[float] = [0.0, 0.0, 0.0]
        self.tlo_z = 0.0

    # ----------------------------------------------------------------- state
    def reset(self, position: Sequence[float]) -> None:
        """grbl's parser initialisation after a (soft) reset: defaults, offsets kept in EEPROM."""
        self.modal = Modal()
        self.feed_value = 0.0
        self.spindle_rpm = 0.0
        self.tool = 0
        self.g92 = [0.0, 0.0, 0.0]
        self.tlo_z = 0.0
        self.sync_position(position)

    def sync_position(self, position: Sequence[float]) -> None:
        """Set the parser's position to where the machine is (after aborted motion)."""
        self.position = [float(position[0]), float(position[1]), float(position[2])]

    def scratch_copy(self) -> GcodeInterpreter:
        """An independent parser in the same state, to check a line without running it."""
        other = GcodeInterpreter(mist_coolant=self._mist_coolant)
        other.modal = dataclasses.replace(self.modal)
        other.feed_value, other.spindle_rpm, other.tool = (
            self.feed_value,
            self.spindle_rpm,
            self.tool,
        )
        other.position = list(self.position)
        other.wcs_offsets = [list(o) for o in self.wcs_offsets]
        other.g28, other.g30, other.g92 = list(self.g28), list(self.g30), list(self.g92)
        other.tlo_z = self.tlo_z
        return other

    def restore_parameters(self) -> None:
        """``$RST=#``: work offsets and G28/G30 positions back to zero."""
        self.wcs_offsets = [[0.0, 0.0, 0.0] for _ in range(N_COORD_SYSTEMS)]
        self.g28 = [0.0, 0.0, 0.0]
        self.g30 = [0.0, 0.0, 0.0]

    def work_offset(self) -> Vec3:
        """``WCO``: active work coordinate system plus G92 plus tool length offset."""
        wcs = self.wcs_offsets[self.modal.wcs]
        return (wcs[0] + self.g92[0], wcs[1] + self.g92[1], wcs[2] + self.g92[2] + self.tlo_z)

    # -------------------------------------------------------------- execution
    def execute(self, words: Sequence[Word], *, jog: bool = False) -> tuple[Action, ...]:
        """Check and commit one block; return what the machine must do, in order.

        ``jog``: a ``$J=`` block (G1 implied, F required, only G20/G21/G90/G91/G53 allowed;
        leaves the modal state alone).
        """
        block = _Block(dataclasses.replace(self.modal))
        if jog:
            block.modal.motion = 1
            block.modal.inverse_time = False
        for word in words:
            if word.letter == "G":
                self._g_word(block, word.value)
            elif word.letter == "M":
                self._m_word(block, word.value)
            else:
                self._value_word(block, word.letter, word.value)
        return self._check_and_commit(block, jog)

    def _g_word(self, block: _Block, value: float) -> None:
        code, mantissa = _split_code(value)
        group: str
        if code in (0, 1, 2, 3, 38):
            if block.axis_command:
                raise GcodeRefused(Status.AXIS_COMMAND_CONFLICT, f"G{code}")
            block.axis_command = "motion"
            if code == 38:  # this machine has no probe input
                raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"G{value:g}: no probe")
            group = "motion"
            block.modal.motion = code
        elif code == 80:
            group = "motion"
            block.modal.motion = 80
        elif code in (10, 28, 30, 92) or code in (4, 53):
            if code in (10, 28, 30, 92) and mantissa == 0:
                if block.axis_command:
                    raise GcodeRefused(Status.AXIS_COMMAND_CONFLICT, f"G{code}")
                block.axis_command = "non_modal"
            group = "non_modal"
            if code in (28, 30, 92):
                if mantissa not in (0, 10):
                    raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"G{value:g}")
                block.non_modal = f"G{code}.1" if mantissa else f"G{code}"
                mantissa = 0
            else:
                block.non_modal = f"G{code}"
        elif code in (17, 18, 19):
            group = "plane"
            block.modal.plane = code
        elif code in (90, 91):
            if mantissa == 0:
                group = "distance"
                block.modal.absolute = code == 90
            else:
                # Only G91.1 exists (incremental IJK, grbl's only arc mode); G90.1 is refused.
                if mantissa != 10 or code == 90:
                    raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"G{value:g}")
                group = "arc_distance"
                mantissa = 0
        elif code in (93, 94):
            group = "feed_mode"
            block.modal.inverse_time = code == 93
        elif code in (20, 21):
            group = "units"
            block.modal.inches = code == 20
        elif code == 40:
            group = "cutter_comp"
        elif code in (43, 49):
            if block.axis_command:
                raise GcodeRefused(Status.AXIS_COMMAND_CONFLICT, f"G{code}")
            block.axis_command = "tlo"
            group = "tlo"
            if code == 49:
                block.modal.tlo_dynamic = False
            elif mantissa == 10:
                block.modal.tlo_dynamic = True
                mantissa = 0
            else:
                raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"G{value:g}")
        elif 54 <= code <= 59:
            group = "wcs"
            block.modal.wcs = code - 54
        elif code == 61:
            if mantissa:
                raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"G{value:g}")
            group = "control"
        else:
            raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"G{value:g}")
        if mantissa:
            raise GcodeRefused(Status.COMMAND_VALUE_NOT_INTEGER, f"G{value:g}")
        if group in block.groups:
            raise GcodeRefused(Status.MODAL_GROUP_VIOLATION, f"G{value:g}")
        block.groups.add(group)

    def _m_word(self, block: _Block, value: float) -> None:
        code, mantissa = _split_code(value)
        if mantissa:
            raise GcodeRefused(Status.COMMAND_VALUE_NOT_INTEGER, f"M{value:g}")
        if code in (0, 1, 2, 30):
            group = "program"
            if code != 1:  # M1 (optional stop) is ignored by grbl
                block.program_flow = code
        elif code in (3, 4, 5):
            group = "spindle"
            block.modal.spindle = code
        elif code in (8, 9) or (code == 7 and self._mist_coolant):
            group = "coolant"
            if code == 9:
                block.modal.mist = block.modal.flood = False
            elif code == 8:
                block.modal.flood = True
            else:
                block.modal.mist = True
        else:
            raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"M{value:g}")
        if group in block.groups:
            raise GcodeRefused(Status.MODAL_GROUP_VIOLATION, f"M{value:g}")
        block.groups.add(group)

    @staticmethod
    def _value_word(block: _Block, letter: str, value: float) -> None:
        if letter not in _VALUE_LETTERS:
            raise GcodeRefused(Status.UNSUPPORTED_COMMAND, letter)
        if letter == "T" and value > MAX_TOOL_NUMBER:
            raise GcodeRefused(Status.MAX_VALUE_EXCEEDED, f"T{value:g}")
        if letter in block.values:
            raise GcodeRefused(Status.WORD_REPEATED, letter)
        if letter in "FNPTS" and value < 0.0:
            raise GcodeRefused(Status.NEGATIVE_VALUE, f"{letter}{value:g}")
        block.values[letter] = value

    def _check_and_commit(self, block: _Block, jog: bool) -> tuple[Action, ...]:
        modal, values = block.modal, block.values
        unit = modal.mm_per_unit
        axis_words = {a for a in _AXES if a in values}
        if axis_words and not block.axis_command:
            block.axis_command = "motion"
        if values.get("N", 0.0) > MAX_LINE_NUMBER:
            raise GcodeRefused(Status.INVALID_LINE_NUMBER)
        used: set[str] = {"N", "F"} if jog else {"N", "F", "S", "T"}

        # Feed rate (grbl's step 2): jog needs F; G93 needs F on every feed move; switching
        # back to G94 leaves the feed undefined until an F word.
        feed = 0.0
        if jog:
            if "F" not in values:
                raise GcodeRefused(Status.UNDEFINED_FEED_RATE)
            feed = values["F"] * unit
        elif modal.inverse_time:
            if block.axis_command == "motion" and modal.motion not in (0, 80) and "F" not in values:
                raise GcodeRefused(Status.UNDEFINED_FEED_RATE)
            feed = values.get("F", 0.0)
        elif "F" in values:
            feed = values["F"] * unit
        elif not self.modal.inverse_time:
            feed = self.feed_value

        if block.non_modal == "G4":
            if "P" not in values:
                raise GcodeRefused(Status.VALUE_WORD_MISSING, "G4 needs P")
            used.add("P")
        xyz_mm = [values.get(a, 0.0) * unit for a in _AXES]
        if block.axis_command == "tlo" and modal.tlo_dynamic and axis_words != {"Z"}:
            raise GcodeRefused(Status.G43_DYNAMIC_AXIS_ERROR)
        block_wcs = self.wcs_offsets[modal.wcs]

        target = list(self.position)
        wcs_update: tuple[int, list[float]] | None = None
        g92_update: list[float] | None = None
        home_moves: list[list[float]] = []
        if block.non_modal == "G10":
            wcs_update = self._g10(block, axis_words, xyz_mm, used)
        elif block.non_modal == "G92":
            if not axis_words:
                raise GcodeRefused(Status.NO_AXIS_WORDS, "G92")
            g92_update = list(self.g92)
            for i, axis in enumerate(_AXES):
                if axis in axis_words:
                    g92_update[i] = self.position[i] - block_wcs[i] - xyz_mm[i]
                    if axis == "Z":
                        g92_update[i] -= self.tlo_z
        else:
            if block.axis_command != "tlo" and axis_words:
                for i, axis in enumerate(_AXES):
                    if axis not in axis_words:
                        continue
                    if block.non_modal == "G53":
                        target[i] = xyz_mm[i]
                    elif not modal.absolute:
                        target[i] = self.position[i] + xyz_mm[i]
                    else:
                        target[i] = xyz_mm[i] + block_wcs[i] + self.g92[i]
                        if axis == "Z":
                            target[i] += self.tlo_z
            if block.non_modal in ("G28", "G30"):
                stored = self.g28 if block.non_modal == "G28" else self.g30
                if axis_words:
                    home = [
                        stored[i] if a in axis_words else target[i] for i, a in enumerate(_AXES)
                    ]
                    home_moves = [target, home]
                else:
                    block.axis_command = ""
                    home_moves = [list(stored)]
            elif block.non_modal == "G53" and modal.motion not in (0, 1):
                raise GcodeRefused(Status.G53_INVALID_MOTION_MODE)

        center: tuple[float, float] | None = None
        if modal.motion == 80:
            if axis_words:
                raise GcodeRefused(Status.AXIS_WORDS_EXIST)
        elif block.axis_command == "motion":
            if modal.motion == 0:
                if not axis_words:
                    block.axis_command = ""
            else:
                if feed == 0.0:
                    raise GcodeRefused(Status.UNDEFINED_FEED_RATE)
                if modal.motion == 1:
                    if not axis_words:
                        block.axis_command = ""
                else:
                    center = self._arc_center(block, axis_words, target, unit, used)

        # Unused words: what no command on the line consumed.
        if block.axis_command:
            used.update(_AXES)
        leftover = sorted(set(values) - used)
        if leftover:
            raise GcodeRefused(Status.UNUSED_WORDS, "".join(leftover))
        if jog:
            return self._commit_jog(block, target, feed)

        # ---- the block is valid: commit (grbl's execution order) and list the actions.
        actions: list[Action] = []
        line_number = int(values.get("N", 0.0))
        self.feed_value = feed
        if "S" in values:
            self.spindle_rpm = values["S"]
        if "T" in values:
            self.tool = int(values["T"])
        if block.non_modal == "G4":
            actions.append(Dwell(values["P"]))
        if block.axis_command == "tlo":
            self.tlo_z = xyz_mm[2] if modal.tlo_dynamic else 0.0
        self.modal = modal
        if wcs_update is not None:
            index, offsets = wcs_update
            self.wcs_offsets[index] = offsets
        if g92_update is not None:
            self.g92 = g92_update
        elif block.non_modal == "G92.1":
            self.g92 = [0.0, 0.0, 0.0]
        elif block.non_modal == "G28.1":
            self.g28 = list(self.position)
        elif block.non_modal == "G30.1":
            self.g30 = list(self.position)
        for point in home_moves:
            actions.append(self._move(MoveKind.RAPID, point, 0.0, None, line_number))
        if block.axis_command == "motion" and modal.motion != 80:
            kind = MoveKind(f"G{modal.motion}")
            actions.append(self._move(kind, target, feed, center, line_number))
        if block.program_flow is not None:
            if block.program_flow in (2, 30):
                self.program_end()
            actions.append(ProgramStop(end=block.program_flow != 0))
        return tuple(actions)

    def _g10(
        self, block: _Block, axis_words: set[str], xyz_mm: list[float], used: set[str]
    ) -> tuple[int, list[float]]:
        values = block.values
        if not axis_words:
            raise GcodeRefused(Status.NO_AXIS_WORDS, "G10")
        if "P" not in values and "L" not in values:
            raise GcodeRefused(Status.VALUE_WORD_MISSING, "G10 needs L and P")
        p = math.trunc(values.get("P", 0.0))
        if p > N_COORD_SYSTEMS:
            raise GcodeRefused(Status.UNSUPPORTED_COORD_SYS, f"P{p}")
        level = values.get("L", 0.0)
        if level != 20 and (level != 2 or "R" in values):
            raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"G10 L{level:g}")
        used.update("LP")
        index = p - 1 if p > 0 else block.modal.wcs
        offsets = list(self.wcs_offsets[index])
        for i, axis in enumerate(_AXES):
            if axis not in axis_words:
                continue
            if level == 20:
                offsets[i] = self.position[i] - self.g92[i] - xyz_mm[i]
                if axis == "Z":
                    offsets[i] -= self.tlo_z
            else:
                offsets[i] = xyz_mm[i]
        return index, offsets

    def _arc_center(
        self, block: _Block, axis_words: set[str], target: list[float], unit: float, used: set[str]
    ) -> tuple[float, float]:
        values = block.values
        if block.modal.plane != 17:  # this machine's arcs are XY arcs only
            raise GcodeRefused(Status.UNSUPPORTED_COMMAND, f"arc in G{block.modal.plane}")
        if not axis_words:
            raise GcodeRefused(Status.NO_AXIS_WORDS, "arc")
        if not axis_words & {"X", "Y"}:
            raise GcodeRefused(Status.NO_AXIS_WORDS_IN_PLANE)
        x0, y0 = self.position[0], self.position[1]
        dx, dy = target[0] - x0, target[1] - y0
        if "R" in values:
            used.add("R")
            if target == self.position or (dx == 0.0 and dy == 0.0):
                raise GcodeRefused(Status.INVALID_TARGET, "R arc to its own start")
            r = values["R"] * unit
            h2 = 4.0 * r * r - dx * dx - dy * dy
            if h2 < 0.0:
                raise GcodeRefused(Status.ARC_RADIUS_ERROR)
            d = math.hypot(dx, dy)
            h = 0.5 * math.sqrt(h2)
            # Left of the chord for a short counter-clockwise arc; a negative R takes the
            # long way round, which puts the centre on the other side.
            side = 1.0 if block.modal.motion == 3 else -1.0
            if r < 0.0:
                side = -side
            return (x0 + dx / 2.0 - side * h * dy / d, y0 + dy / 2.0 + side * h * dx / d)
        if "I" not in values and "J" not in values:
            raise GcodeRefused(Status.NO_OFFSETS_IN_PLANE)
        used.update("IJK")
        i_mm, j_mm = values.get("I", 0.0) * unit, values.get("J", 0.0) * unit
        cx, cy = x0 + i_mm, y0 + j_mm
        r_start = math.hypot(i_mm, j_mm)
        delta = abs(math.hypot(target[0] - cx, target[1] - cy) - r_start)
        if delta > ARC_RADIUS_TOLERANCE_MM and (
            delta > ARC_RADIUS_TOLERANCE_MAX_MM or delta > ARC_RADIUS_TOLERANCE_REL * r_start
        ):
            raise GcodeRefused(Status.INVALID_TARGET, f"radii differ by {delta:.4f} mm")
        return cx, cy

    def _commit_jog(self, block: _Block, target: list[float], feed: float) -> tuple[Action, ...]:
        if block.groups - {"distance", "units", "non_modal"} or block.non_modal not in ("", "G53"):
            raise GcodeRefused(Status.INVALID_JOG_COMMAND)
        if block.axis_command != "motion":
            return ()
        move = Move(
            MoveKind.LINEAR,
            (self.position[0], self.position[1], self.position[2]),
            (target[0], target[1], target[2]),
            feed,
            jog=True,
        )
        if self._jog_travel_ok is not None and not self._jog_travel_ok(move):
            raise GcodeRefused(Status.TRAVEL_EXCEEDED)
        self.position = target
        return (move,)

    def _move(
        self,
        kind: MoveKind,
        end: list[float],
        feed: float,
        center: tuple[float, float] | None,
        line_number: int,
    ) -> Move:
        start = (self.position[0], self.position[1], self.position[2])
        move = Move(kind, start, (end[0], end[1], end[2]), feed, center, line_number)
        if kind is not MoveKind.RAPID and self.modal.inverse_time:
            # G93: F is 1/minutes for this block; the path speed follows from its length.
            length = math.hypot(move.xy_length_mm(), end[2] - start[2])
            move = dataclasses.replace(move, feed_mm_min=length * feed)
        self.position = list(end)
        return move

    def program_end(self) -> None:
        """M2/M30: the modes grbl restores at program end (units and G92 stay)."""
        self.modal.motion = 1
        self.modal.plane = 17
        self.modal.absolute = True
        self.modal.inverse_time = False
        self.modal.wcs = 0
        self.modal.spindle = 5
        self.modal.mist = self.modal.flood = False

    # ---------------------------------------------------------------- reports
    def state_report(self, *, report_inches: bool) -> str:
        """``$G``: ``[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]``."""
        m = self.modal
        coolant = " ".join(c for c, on in (("M7", m.mist), ("M8", m.flood)) if on) or "M9"
        feed = self.feed_value
        if report_inches and not m.inverse_time:
            feed_text = f"{feed / MM_PER_INCH:.1f}"
        else:
            feed_text = f"{feed:.0f}"
        return (
            f"[GC:G{m.motion} G{54 + m.wcs} G{m.plane} G{20 if m.inches else 21} "
            f"G{90 if m.absolute else 91} G{93 if m.inverse_time else 94} M{m.spindle} "
            f"{coolant} T{self.tool} F{feed_text} S{self.spindle_rpm:.0f}]"
        )

    def parameter_report(self, *, report_inches: bool) -> list[str]:
        """``$#``: work offsets, G28/G30, G92, tool length offset and probe lines."""

        def vec(v: Sequence[float]) -> str:
            if report_inches:
                return ",".join(f"{c / MM_PER_INCH:.4f}" for c in v)
            return ",".join(f"{c:.3f}" for c in v)

        lines = [f"[G{54 + i}:{vec(o)}]" for i, o in enumerate(self.wcs_offsets)]
        tlo = self.tlo_z / MM_PER_INCH if report_inches else self.tlo_z
        lines += [
            f"[G28:{vec(self.g28)}]",
            f"[G30:{vec(self.g30)}]",
            f"[G92:{vec(self.g92)}]",
            f"[TLO:{tlo:.{4 if report_inches else 3}f}]",
            f"[PRB:{vec((0.0, 0.0, 0.0))}:0]",
        ]
        return lines
