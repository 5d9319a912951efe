"""The THC's height window, pure: how far below (and above) cut height the THC may drive
the torch before the cut ends through the fault path.

A warped plate moves the torch's Z by millimetres while its height above the plate stays
at cut height, so the window is not a Z range: the height is the arc's, the voltage now
against the voltage measured at cut height over the probed point at the start of the cut
(``CutSequence`` measures it on every cut, fixed or auto voltage), through the THC slope.
A cut voltage well below the arc's at cut height (a wrong material, a typo in ``G200 V``)
drives the torch down until the voltage matches: the window stops it there, before the
plate, where the float switch used to (PlasmaC's THC limits end such a cut with an error,
but only at the Z axis's limits). Above: the same toward the arc-loss height.

Near an edge the THC's speed that way is limited to what still stops at the edge (so a
dive arrives there slowly instead of overrunning it); reaching it is a fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["HeightWindow"]


@dataclass(frozen=True)
class HeightWindow:
    below_mm: float  # SequenceConfig.thc_window_below_mm
    above_mm: float  # SequenceConfig.thc_window_above_mm
    slope_v_per_mm: float  # the THC's volts per mm

    def offset_mm(self, voltage_v: float, cut_height_v: float) -> float:
        """The torch's height over cut height by the arc: positive above, negative below."""
        return (voltage_v - cut_height_v) / self.slope_v_per_mm

    def limit(
        self, velocity_mm_s: float, offset_mm: float, dt_s: float, accel_mm_s2: float
    ) -> float:
        """``velocity_mm_s`` limited to what stops at the window's edge it moves towards:
        v·dt + v²/2a = room."""
        if velocity_mm_s < 0.0:
            room = max(0.0, self.below_mm + offset_mm)
        else:
            room = max(0.0, self.above_mm - offset_mm)
        a = accel_mm_s2
        braking = a * (math.sqrt(dt_s * dt_s + 2.0 * room / a) - dt_s)
        return max(-braking, min(braking, velocity_mm_s))

    def breach(self, offset_mm: float, command_mm_s: float) -> str | None:
        """The fault's reason when the THC, the torch at an edge, still commands Z past it
        (``command_mm_s`` before :meth:`limit`), else None. A locked THC commands nothing:
        what the plate does under a held torch is the float switch's and arc loss's."""
        if offset_mm <= -self.below_mm and command_mm_s < 0.0:
            return (
                f"THC height window: the arc voltage puts the torch {-offset_mm:.2f} mm below"
                f" cut height, the window's limit is {self.below_mm:g} mm"
                " (controller.thc_window_below_mm); is the cut voltage right?"
            )
        if offset_mm >= self.above_mm and command_mm_s > 0.0:
            return (
                f"THC height window: the arc voltage puts the torch {offset_mm:.2f} mm above"
                f" cut height, the window's limit is {self.above_mm:g} mm"
                " (controller.thc_window_above_mm, toward the arc-loss height);"
                " is the cut voltage right?"
            )
        return None
