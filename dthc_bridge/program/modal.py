"""The modal state of a G-code program: one type for every reader of a program (STYLE 24).

The plan (what goes to the daemon, in mm), the path tracer (the XY path), the mock's gantry
and the emulated grbl each follow a program's units, distance modes, plane, motion mode and
feed. They used to keep five copies of the same few rules, which drifted (a feed kept in
program units by one and converted at the block by another). Each reader keeps its own
instance and checks what it alone refuses (the gantry's XY-only arcs, grbl's modal groups);
the state and how a line's words change it are here.

Feed is kept in mm/min, converted with the units in force on the block that sets it, as
LinuxCNC's interpreter and grbl both keep it: a later G20/G21 changes how the program
writes feeds, not how fast the machine moves.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from ..units import MM_PER_INCH

__all__ = ["MM_PER_INCH", "ModalState"]

_MOTION = (0.0, 1.0, 2.0, 3.0)


@dataclass(slots=True)
class ModalState:
    """Units (G20/G21), distance mode (G90/G91), arc centre mode (G90.1/G91.1), plane
    (G17-G19), motion mode (G0-G3) and feed (F), as a program sets them."""

    inches: bool = False
    absolute: bool = True
    arc_absolute: bool = False  # G90.1: I J are absolute (LinuxCNC); grbl has only G91.1
    plane: int = 17
    motion: int = 0
    feed_mm_min: float | None = None

    @property
    def mm_per_unit(self) -> float:
        return MM_PER_INCH if self.inches else 1.0

    def apply(self, words: Iterable[tuple[str, float]]) -> None:
        """A block's modal words, in force from this block on: G codes first (a ``G20 F10``
        block's feed is in inches), then a positive F. Other words are not modal state."""
        feed: float | None = None
        for letter, value in words:
            if letter == "G":
                self._g(value)
            elif letter == "F" and value > 0.0:
                feed = value
        if feed is not None:
            self.feed_mm_min = feed * self.mm_per_unit

    def _g(self, code: float) -> None:
        if code in _MOTION:
            self.motion = int(code)
        elif code in (20.0, 21.0):
            self.inches = code == 20.0
        elif code in (90.0, 91.0):
            self.absolute = code == 90.0
        elif code in (90.1, 91.1):
            self.arc_absolute = code == 90.1
        elif code in (17.0, 18.0, 19.0):
            self.plane = int(code)

    @property
    def feed_in_units(self) -> float | None:
        """The feed as the program writes it (its units per minute)."""
        return None if self.feed_mm_min is None else self.feed_mm_min / self.mm_per_unit

    def to_mm(self, value: float) -> float:
        return value * self.mm_per_unit

    def xy_target(
        self, x0_mm: float, y0_mm: float, coords: Mapping[str, float]
    ) -> tuple[float, float]:
        """Where a move's X and Y words take the tool from (x0, y0), in mm."""
        k = self.mm_per_unit
        if self.absolute:
            return coords["X"] * k if "X" in coords else x0_mm, (
                coords["Y"] * k if "Y" in coords else y0_mm
            )
        return x0_mm + coords.get("X", 0.0) * k, y0_mm + coords.get("Y", 0.0) * k

    def arc_centre(
        self, x0_mm: float, y0_mm: float, coords: Mapping[str, float]
    ) -> tuple[float, float]:
        """An I J arc's centre in mm: offsets from the start (G91.1), or absolute (G90.1)
        where an omitted word is the start's own coordinate."""
        k = self.mm_per_unit
        if self.arc_absolute:
            return coords.get("I", x0_mm / k) * k, coords.get("J", y0_mm / k) * k
        return x0_mm + coords.get("I", 0.0) * k, y0_mm + coords.get("J", 0.0) * k
