"""grbl's ``$`` settings: the ``$$`` listing and ``$N=value`` writes.

The numbers and their meaning are grbl 1.1's. The emulator honours the ones that shape what
a sender sees: ``$10`` (status report mask: bit 0 machine position, bit 1 buffer state),
``$11`` junction deviation, ``$13`` report in inches, ``$20`` soft limits, ``$22`` homing
(off: ``$H`` answers ``error:5``), ``$110``/``$111`` max rates, ``$120``/``$121``
accelerations and ``$130``/``$131`` travel. The others are stored and listed only.
"""

from __future__ import annotations

from dataclasses import dataclass

from .codes import GcodeRefused, Status
from .config import EmulatorConfig

__all__ = ["MOTION_SETTINGS", "Settings"]

# Settings printed without decimals (masks, booleans, times in µs/ms, rpm).
_INTEGER = frozenset({0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32})
# Changing these rebuilds the motion planner (only possible when the planner is empty).
MOTION_SETTINGS = frozenset({11, 110, 111, 120, 121})
REPORT_MPOS = 1
REPORT_BUFFER = 2


def _defaults(config: EmulatorConfig) -> dict[int, float]:
    return {
        0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0,
        10: (0 if config.report_wpos else REPORT_MPOS) | REPORT_BUFFER,
        11: config.junction_deviation_mm, 12: 0.002, 13: 0,
        20: 1 if config.soft_limits else 0, 21: 0, 22: 0, 23: 0,
        24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
        100: 250.0, 101: 250.0, 102: 250.0,
        110: config.max_rate_mm_min, 111: config.max_rate_mm_min, 112: 500.0,
        120: config.accel_mm_s2, 121: config.accel_mm_s2, 122: 10.0,
        130: config.max_travel_mm[0], 131: config.max_travel_mm[1], 132: 200.0,
    }  # fmt: skip


@dataclass(slots=True)
class Settings:
    """The settings table, initialised from the command line's configuration."""

    values: dict[int, float]

    @classmethod
    def from_config(cls, config: EmulatorConfig) -> Settings:
        """Defaults for this configuration."""
        return cls(_defaults(config))

    def listing(self) -> list[str]:
        """``$$`` lines: ``$110=10000.000``."""
        return [
            f"${n}={int(v)}" if n in _INTEGER else f"${n}={v:.3f}"
            for n, v in sorted(self.values.items())
        ]

    def assign(self, number: float, value: float) -> int:
        """``$N=value``; return the setting's number. Raises grbl's error for a bad write."""
        if number != int(number) or int(number) not in self.values:
            raise GcodeRefused(Status.INVALID_STATEMENT, f"no setting ${number:g}")
        if value < 0.0:
            raise GcodeRefused(Status.NEGATIVE_VALUE)
        key = int(number)
        if key == 0 and value < 3:
            raise GcodeRefused(Status.SETTING_STEP_PULSE_MIN)
        if key in (110, 111, 120, 121, 130, 131) and value <= 0.0:
            raise GcodeRefused(Status.NEGATIVE_VALUE, "must be positive")
        self.values[key] = float(int(value)) if key in _INTEGER else value
        return key

    # Named views of the settings the firmware acts on.
    @property
    def report_mpos(self) -> bool:
        """``$10`` bit 0: report MPos (else WPos)."""
        return bool(int(self.values[10]) & REPORT_MPOS)

    @property
    def report_buffer(self) -> bool:
        """``$10`` bit 1: report ``Bf:``."""
        return bool(int(self.values[10]) & REPORT_BUFFER)

    @property
    def report_inches(self) -> bool:
        """``$13``."""
        return bool(self.values[13])

    @property
    def soft_limits(self) -> bool:
        """``$20``."""
        return bool(self.values[20])

    @property
    def homing(self) -> bool:
        """``$22``."""
        return bool(self.values[22])

    @property
    def travel_mm(self) -> tuple[float, float]:
        """``$130``, ``$131``: X and Y travel from machine zero."""
        return self.values[130], self.values[131]

    @property
    def max_rate_mm_min(self) -> float:
        """Path speed cap: the lower of ``$110`` and ``$111``."""
        return min(self.values[110], self.values[111])

    @property
    def accel_mm_s2(self) -> float:
        """Path acceleration: the lower of ``$120`` and ``$121``."""
        return min(self.values[120], self.values[121])

    @property
    def junction_deviation_mm(self) -> float:
        """``$11``."""
        return self.values[11]
