"""What LinuxCNC does around plasmac, emulated: the external-offset planner and dbounce.

- :class:`OffsetPlanner`: motion executes ``axis.z.eoffset-counts`` x ``eoffset-scale`` with
  its simple trapezoidal planner (LinuxCNC's ``simple_tp``: brake as late as the
  acceleration allows, ramp the velocity by at most ``a·dt`` per period), at
  ``OFFSET_AV_RATIO`` of the axis' velocity and acceleration, ``latency_periods`` after the
  component wrote the counts (the component runs after motion in the servo thread, and
  motion reads the counts at the start of its next cycle).
- :class:`Debounce`: QtPlasmaC's ``dbounce`` on arc OK, float, ohmic and breakaway
  (5 periods): an up/down counter, true at the top, false at zero.
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["OFFSET_AV_RATIO", "Debounce", "OffsetPlanner"]

# LinuxCNC's [AXIS_Z]OFFSET_AV_RATIO as plasmac's reference notes measured it: external
# offsets get this share of the axis' velocity and acceleration.
OFFSET_AV_RATIO = 0.9


class OffsetPlanner:
    """The Z external offset (mm): ``update(target_mm)`` once per period."""

    __slots__ = ("_a", "_dt", "_pending", "_v_max", "position_mm", "velocity_mm_s")

    def __init__(
        self, max_velocity_mm_s: float, accel_mm_s2: float, dt_s: float, latency_periods: int = 2
    ) -> None:
        self._v_max = max_velocity_mm_s * OFFSET_AV_RATIO
        self._a = accel_mm_s2 * OFFSET_AV_RATIO
        self._dt = dt_s
        self._pending: deque[float] = deque([0.0] * latency_periods)
        self.position_mm = 0.0
        self.velocity_mm_s = 0.0

    def update(self, target_mm: float) -> None:
        """Take this period's command; move towards the one ``latency_periods`` old."""
        pending = self._pending
        pending.append(target_mm)
        cmd = pending.popleft()
        a, dt = self._a, self._dt
        max_dv = a * dt
        tiny = max_dv * dt * 0.001
        err = cmd - self.position_mm
        if err > tiny:
            want = -max_dv + math.sqrt(2.0 * a * err + max_dv * max_dv)
        elif err < -tiny:
            want = max_dv - math.sqrt(-2.0 * a * err + max_dv * max_dv)
        else:
            want = 0.0
            self.position_mm = cmd
        want = max(-self._v_max, min(self._v_max, want))
        v = self.velocity_mm_s
        if want > v + max_dv:
            v += max_dv
        elif want < v - max_dv:
            v -= max_dv
        else:
            v = want
        self.velocity_mm_s = v
        self.position_mm += v * dt


class Debounce:
    """LinuxCNC ``dbounce``: the output follows the input once it held for ``delay`` periods
    (an up/down counter, so bounce delays the change instead of passing it through)."""

    __slots__ = ("_count", "_delay", "out")

    def __init__(self, delay: int = 5) -> None:
        self._delay = delay
        self._count = 0
        self.out = False

    def update(self, value: bool) -> bool:
        if value:
            if self._count < self._delay:
                self._count += 1
            if self._count >= self._delay:
                self.out = True
        else:
            if self._count > 0:
                self._count -= 1
            if self._count <= 0:
                self.out = False
        return self.out
