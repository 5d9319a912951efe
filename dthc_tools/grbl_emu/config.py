"""What the emulated controller is: flavour, buffer sizes, motion limits, travel.

One closed, frozen configuration; the defaults follow the flavour (classic grbl on an
ATmega328: 128-byte receive buffer, 15 usable planner blocks, 80-character line buffer;
grblHAL: 1024 bytes, 35 blocks, 256 characters) and the mock board's gantry
(:class:`mock_device.plant.scenario.GantrySpec`), so a mirrored plant moves the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

from mock_device.plant.scenario import GantrySpec

__all__ = ["ConfigError", "EmulatorConfig", "Flavor"]

_GANTRY = GantrySpec()


class Flavor(StrEnum):
    """Which firmware the emulator plays."""

    GRBL = "grbl"
    GRBLHAL = "grblhal"


class ConfigError(ValueError):
    """A configuration value out of bounds; ``key`` names it."""

    def __init__(self, key: str, reason: str) -> None:
        self.key = key
        super().__init__(f"{key}: {reason}")


@dataclass(frozen=True, slots=True)
class _FlavorDefaults:
    rx_buffer_bytes: int
    planner_blocks: int
    line_buffer_chars: int  # characters a line may have after spaces and comments are removed
    banner: str
    version: str  # [VER:...] build
    option_codes: str  # [OPT:...] letters
    mist_coolant: bool  # M7 available (OPT letter M)
    merge_crlf: bool  # a CR LF pair is one line end (grblHAL), not two (classic grbl)
    line_numbers: bool  # Ln: in status reports (OPT letter N)
    status_in_critical_alarm: bool  # answers '?' while waiting for a reset after a limit alarm


_DEFAULTS = {
    Flavor.GRBL: _FlavorDefaults(
        rx_buffer_bytes=128,
        planner_blocks=15,
        line_buffer_chars=79,  # LINE_BUFFER_SIZE 80, one byte for the terminator
        banner="Grbl 1.1f ['$' for help]",
        version="1.1f.20170801",
        option_codes="V",
        mist_coolant=False,
        merge_crlf=False,
        line_numbers=False,
        status_in_critical_alarm=False,
    ),
    Flavor.GRBLHAL: _FlavorDefaults(
        rx_buffer_bytes=1024,
        planner_blocks=35,
        line_buffer_chars=256,
        banner="GrblHAL 1.1f ['$' or '$HELP' for help]",
        version="1.1f.20260801",
        option_codes="VNML+",
        mist_coolant=True,
        merge_crlf=True,
        line_numbers=True,
        status_in_critical_alarm=True,
    ),
}


def _check(key: str, value: float, lo: float, hi: float) -> None:
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ConfigError(key, f"must be between {lo:g} and {hi:g}, got {value!r}")


@dataclass(frozen=True, slots=True)
class EmulatorConfig:
    """Everything fixed at start-up; sizes and the max rate left at 0 take the defaults."""

    flavor: Flavor = Flavor.GRBL
    rx_buffer_bytes: int = 0  # 0: the flavour's
    planner_blocks: int = 0  # 0: the flavour's
    accel_mm_s2: float = _GANTRY.accel_mm_s2
    rapid_mm_min: float = _GANTRY.rapid_mm_min
    junction_deviation_mm: float = _GANTRY.junction_deviation_mm
    max_rate_mm_min: float = 0.0  # 0: the rapid rate
    arc_chord_mm: float = _GANTRY.arc_chord_mm
    max_travel_mm: tuple[float, float] = (1200.0, 1200.0)  # X, Y: machine travel is [0, max]
    soft_limits: bool = True
    report_wpos: bool = False
    start_mm: tuple[float, float] = field(default=(_GANTRY.start_x_mm, _GANTRY.start_y_mm))

    def __post_init__(self) -> None:
        defaults = _DEFAULTS[Flavor(self.flavor)]
        if self.rx_buffer_bytes == 0:
            object.__setattr__(self, "rx_buffer_bytes", defaults.rx_buffer_bytes)
        if self.planner_blocks == 0:
            object.__setattr__(self, "planner_blocks", defaults.planner_blocks)
        if self.max_rate_mm_min == 0.0:
            object.__setattr__(self, "max_rate_mm_min", self.rapid_mm_min)
        _check("rx_buffer_bytes", self.rx_buffer_bytes, 16, 65536)
        _check("planner_blocks", self.planner_blocks, 1, 1024)
        _check("accel_mm_s2", self.accel_mm_s2, 1.0, 100_000.0)
        _check("rapid_mm_min", self.rapid_mm_min, 1.0, 1_000_000.0)
        _check("junction_deviation_mm", self.junction_deviation_mm, 0.0001, 10.0)
        _check("max_rate_mm_min", self.max_rate_mm_min, 1.0, 1_000_000.0)
        _check("arc_chord_mm", self.arc_chord_mm, 0.01, 10.0)
        for axis, travel in zip("XY", self.max_travel_mm, strict=True):
            _check(f"max_travel_mm.{axis}", travel, 1.0, 100_000.0)

    @property
    def defaults(self) -> _FlavorDefaults:
        """The flavour's fixed traits (banner, version, line buffer, CR LF handling)."""
        return _DEFAULTS[self.flavor]

    @property
    def line_buffer_chars(self) -> int:
        """Longest line (spaces and comments removed) before ``error:11``."""
        return self.defaults.line_buffer_chars
