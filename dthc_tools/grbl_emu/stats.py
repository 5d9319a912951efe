"""What the emulated controller saw: the figures a test asserts on and the exit line logs."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

__all__ = ["EmulatorStats"]


@dataclass(slots=True)
class EmulatorStats:
    """What the controller saw; the process logs it as its exit line."""

    rx_bytes: int = 0  # bytes received, real-time bytes included
    rx_overflow: int = 0  # bytes lost because the receive buffer was full
    rx_high_water: int = 0  # most bytes ever waiting in the receive buffer
    realtime_bytes: int = 0
    lines: int = 0  # lines answered (ok or error)
    ok: int = 0
    errors: Counter[int] = field(default_factory=Counter)
    alarms: Counter[int] = field(default_factory=Counter)
    moves: int = 0  # motion blocks given to the planner
    planner_high_water: int = 0  # most planner blocks ever in use
    status_reports: int = 0
    resets: int = 0
    stalls: int = 0  # host stalls longer than MAX_CATCH_UP_S
    z_words_received: int = 0
    spindle_words_received: int = 0  # M3, M4, M5 and S words

    def as_dict(self) -> dict[str, object]:
        """JSON-ready."""
        return {
            "rx_bytes": self.rx_bytes,
            "rx_overflow": self.rx_overflow,
            "rx_high_water": self.rx_high_water,
            "realtime_bytes": self.realtime_bytes,
            "lines": self.lines,
            "ok": self.ok,
            "errors": {str(k): v for k, v in sorted(self.errors.items())},
            "alarms": {str(k): v for k, v in sorted(self.alarms.items())},
            "moves": self.moves,
            "planner_high_water": self.planner_high_water,
            "status_reports": self.status_reports,
            "resets": self.resets,
            "stalls": self.stalls,
            "z_words_received": self.z_words_received,
            "spindle_words_received": self.spindle_words_received,
        }
