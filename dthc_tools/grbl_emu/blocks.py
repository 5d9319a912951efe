"""What a G-code block asks the machine to do, and grbl's word reader.

Moves are in machine millimetres (arcs with their XY centre), dwells in seconds; program
stops mark M0 and M2/M30. The reader takes a prepared line (upper case, no blanks, no
comments) apart into letter-number words the way grbl does, with grbl's first error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from .codes import GcodeRefused, Status

__all__ = [
    "Action",
    "Dwell",
    "Move",
    "MoveKind",
    "ProgramStop",
    "Vec3",
    "Word",
    "read_number",
    "scan_words",
]

Vec3 = tuple[float, float, float]


class MoveKind(Enum):
    """How a move is executed."""

    RAPID = "G0"
    LINEAR = "G1"
    ARC_CW = "G2"
    ARC_CCW = "G3"


@dataclass(frozen=True, slots=True)
class Word:
    """One letter and its number, as grbl reads them."""

    letter: str
    value: float


@dataclass(frozen=True, slots=True)
class Move:
    """A motion in machine millimetres; arcs carry their XY centre."""

    kind: MoveKind
    start: Vec3
    end: Vec3
    feed_mm_min: float = 0.0  # the programmed feed (G93 resolved); 0 for rapids
    center: tuple[float, float] | None = None
    line_number: int = 0
    jog: bool = False

    @property
    def is_arc(self) -> bool:
        """G2 or G3."""
        return self.kind in (MoveKind.ARC_CW, MoveKind.ARC_CCW)

    @property
    def radius_mm(self) -> float:
        """Arc radius from the start point (0 for straight moves)."""
        if self.center is None:
            return 0.0
        return math.hypot(self.start[0] - self.center[0], self.start[1] - self.center[1])

    def sweep_rad(self) -> float:
        """Signed arc angle (negative clockwise); a closed arc is a full turn."""
        if self.center is None:
            return 0.0
        cx, cy = self.center
        a0 = math.atan2(self.start[1] - cy, self.start[0] - cx)
        a1 = math.atan2(self.end[1] - cy, self.end[0] - cx)
        sweep = a1 - a0
        if self.kind is MoveKind.ARC_CW:
            if sweep >= -1e-12:
                sweep -= 2.0 * math.pi
        elif sweep <= 1e-12:
            sweep += 2.0 * math.pi
        return sweep

    def xy_length_mm(self) -> float:
        """Path length in the XY plane."""
        if self.is_arc:
            return self.radius_mm * abs(self.sweep_rad())
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])

    def xy_extents(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` the move sweeps, arcs' bulges included."""
        xs = [self.start[0], self.end[0]]
        ys = [self.start[1], self.end[1]]
        if self.is_arc and self.center is not None:
            cx, cy = self.center
            r = self.radius_mm
            a0 = math.atan2(self.start[1] - cy, self.start[0] - cx)
            sweep = self.sweep_rad()
            for k in range(-8, 9):  # every axis crossing the sweep passes
                angle = k * math.pi / 2.0
                rel = (angle - a0) / sweep if sweep else -1.0
                if 0.0 < rel < 1.0:
                    xs.append(cx + r * math.cos(angle))
                    ys.append(cy + r * math.sin(angle))
        return min(xs), max(xs), min(ys), max(ys)


@dataclass(frozen=True, slots=True)
class Dwell:
    """G4: wait for the planner to empty, then this long."""

    seconds: float


@dataclass(frozen=True, slots=True)
class ProgramStop:
    """M0 (pause until cycle start) or M2/M30 (program end); both wait for the planner."""

    end: bool


Action = Move | Dwell | ProgramStop


def read_number(line: str, i: int) -> tuple[float | None, int]:
    """grbl's number reader: optional sign, digits with at most one point; None if no digit."""
    n = len(line)
    j = i
    if j < n and line[j] in "+-":
        j += 1
    digits = 0
    point = False
    while j < n:
        ch = line[j]
        if "0" <= ch <= "9":
            digits += 1
        elif ch == "." and not point:
            point = True
        else:
            break
        j += 1
    if digits == 0:
        return None, j
    return float(line[i:j]), j


def scan_words(line: str) -> list[Word]:
    """Words of a prepared line (upper case, no blanks, no comments), in order.

    Raises ``error:1`` for a character where a letter must be and ``error:2`` for a
    letter without a valid number, at the first such place, as grbl does.
    """
    found: list[Word] = []
    i, n = 0, len(line)
    while i < n:
        letter = line[i]
        if not ("A" <= letter <= "Z"):
            raise GcodeRefused(Status.EXPECTED_COMMAND_LETTER, repr(letter))
        value, i = read_number(line, i + 1)
        if value is None:
            raise GcodeRefused(Status.BAD_NUMBER_FORMAT, letter)
        found.append(Word(letter, value))
    return found
