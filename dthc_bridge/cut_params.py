"""What a cut is made with: :class:`CutParams` (G200's words, and the same set from other
dialects and from a material), and :class:`CommandError`, which names the offending word.

Below both the controller and the material library, which share them: the library turns a
material into cut parameters, the controller cuts with them. Nothing of the project is
imported here.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CommandError", "CutParams", "check_range"]


class CommandError(ValueError):
    """A command or one of its words is invalid. ``word`` names it (e.g. ``"G200 P"``)."""

    def __init__(self, word: str, reason: str) -> None:
        super().__init__(f"{word}: {reason}" if word else reason)
        self.word = word
        self.reason = reason


def check_range(word: str, value: float, low: float, high: float) -> float:
    if not low <= value <= high:
        raise CommandError(word, f"{value:g} is out of range {low:g}..{high:g}")
    return value


@dataclass(frozen=True, slots=True)
class CutParams:
    """MASSO G200 F P D C V A O S, and the same set from other dialects."""

    touch_feed_mm_min: float = 200.0  # F: probing feed
    pierce_height_mm: float = 3.8  # P
    pierce_delay_ms: float = 500.0  # D (MASSO gives milliseconds)
    cut_height_mm: float = 1.5  # C
    cut_voltage_v: float | None = None  # V; None (V0) = auto voltage, sampled per cut
    anti_dive_percent: float = 90.0  # A; 0 = velocity anti-dive off
    ohmic: bool = False  # O1 = ohmic touch-off, O0 = float switch ("plasma touch")
    stop_after_pierce: bool = False  # S1 = stop after pierce, wait for cycle start

    def __post_init__(self) -> None:
        check_range("G200 F", self.touch_feed_mm_min, 1.0, 3000.0)
        check_range("G200 P", self.pierce_height_mm, 0.5, 25.0)
        check_range("G200 D", self.pierce_delay_ms, 0.0, 10_000.0)
        check_range("G200 C", self.cut_height_mm, 0.2, 10.0)
        if self.cut_voltage_v is not None:
            check_range("G200 V", self.cut_voltage_v, 50.0, 300.0)
        check_range("G200 A", self.anti_dive_percent, 0.0, 100.0)
