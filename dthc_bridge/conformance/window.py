"""The motion window: every Z target the suite sends lies inside it, and Z is watched.

The torch relay and the Z axis of the bench may be live, so the suite moves Z only within
``half_width`` of a reference position the operator confirmed. Targets outside are refused
before anything is sent (:class:`OutsideWindow`); and should a faulty board run Z past the
window by itself (a probe that ignores its max travel, a velocity that never expires), the
guard sees it in the telemetry and sends Z_STOP at once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import firmware_protocol as fp

from .errors import OutsideWindow

__all__ = ["MotionWindow"]


@dataclass(slots=True)
class MotionWindow:
    ref_um: int
    half_width_um: int
    z_min_um: int  # the board's soft limits, from HELLO_INFO
    z_max_um: int
    guard_margin_um: int
    excursions: int = 0
    farthest_out_um: int = 0  # largest distance seen beyond the window
    suspended: bool = False  # the homing cycle (--home): Z leaves the window on purpose
    _outside: bool = False

    @property
    def low_um(self) -> int:
        return max(self.ref_um - self.half_width_um, self.z_min_um)

    @property
    def high_um(self) -> int:
        return min(self.ref_um + self.half_width_um, self.z_max_um)

    def check(self, target_um: int) -> int:
        """``target_um`` if it lies inside the window; OutsideWindow otherwise."""
        if not self.low_um <= target_um <= self.high_um:
            raise OutsideWindow(target_um, self.low_um, self.high_um)
        return target_um

    def guard(self, stop: Callable[[], None]) -> Callable[[fp.Samples], None]:
        """A SAMPLES callback that calls ``stop`` once per excursion beyond the window."""

        def on_samples(batch: fp.Samples) -> None:
            if self.suspended:
                return
            beyond = max(self.low_um - batch.z_um, batch.z_um - self.high_um, 0)
            self.farthest_out_um = max(self.farthest_out_um, beyond)
            if beyond > self.guard_margin_um:
                if not self._outside:
                    self._outside = True
                    self.excursions += 1
                    stop()
            else:
                self._outside = False

        return on_samples

    def describe(self) -> str:
        return f"{self.low_um / 1000:.3f}..{self.high_um / 1000:.3f} mm"
