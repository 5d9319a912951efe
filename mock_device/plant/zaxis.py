"""The Z stepper axis as the board's motion controller drives it.

Per-step integration with a discrete-time braking curve: the speed allowed at a distance
``d`` from where the axis must stop is the largest speed from which shedding ``accel·dt``
per step stops within ``d``. So positioning moves land on target without overshoot, the
acceleration never exceeds ``accel_mm_s2`` and the axis brakes in time before a soft
limit: it never passes one.
"""

import enum
import math

from .scenario import ZAxisSpec

__all__ = ["ZAxis", "ZState"]


class ZState(enum.Enum):
    """What the axis is doing."""

    IDLE = "idle"
    MOVING = "moving"
    JOGGING = "jogging"
    DRIVEN = "driven"  # by a step generator outside (the board's): see ``drive``


class ZAxis:
    """Trapezoidal positioning (``move_to``), velocity ramps (``jog``) and ``stop``."""

    __slots__ = (
        "_accel",
        "_eps",
        "_feed",
        "_jog_v",
        "_stopping",
        "home_switch_mm",
        "max_mm",
        "max_velocity_mm_s",
        "min_mm",
        "position_mm",
        "state",
        "step_mm",
        "target_mm",
        "velocity_mm_s",
    )

    def __init__(
        self,
        *,
        min_mm: float = 0.0,
        max_mm: float = 100.0,
        max_velocity_mm_s: float = 60.0,
        accel_mm_s2: float = 650.0,
        step_mm: float = 0.005,
        position_mm: float = 60.0,
        home_switch_mm: float | None = None,
    ) -> None:
        if max_mm <= min_mm:
            raise ValueError("max_mm must be greater than min_mm")
        if max_velocity_mm_s <= 0.0 or accel_mm_s2 <= 0.0:
            raise ValueError("max_velocity_mm_s and accel_mm_s2 must be positive")
        self.min_mm = min_mm
        self.max_mm = max_mm
        self.max_velocity_mm_s = max_velocity_mm_s
        self._accel = accel_mm_s2
        self.step_mm = step_mm
        self._eps = step_mm * 0.5
        self.position_mm = min(max(position_mm, min_mm), max_mm)
        # The home switch sits above the soft limits, as a table's does (2 mm by default).
        self.home_switch_mm = max_mm + 2.0 if home_switch_mm is None else home_switch_mm
        self.velocity_mm_s = 0.0
        self.target_mm = self.position_mm
        self.state = ZState.IDLE
        self._feed = max_velocity_mm_s
        self._jog_v = 0.0
        self._stopping = False

    @classmethod
    def from_spec(cls, spec: ZAxisSpec) -> "ZAxis":
        """An axis with the scenario's limits, at its start position."""
        return cls(
            min_mm=spec.min_mm,
            max_mm=spec.max_mm,
            max_velocity_mm_s=spec.max_velocity_mm_s,
            accel_mm_s2=spec.accel_mm_s2,
            step_mm=spec.step_mm,
            position_mm=spec.start_mm,
            home_switch_mm=spec.home_switch_mm,
        )

    @property
    def accel_mm_s2(self) -> float:
        """Acceleration limit."""
        return self._accel

    @property
    def is_idle(self) -> bool:
        """True when no motion is commanded and the axis stands still."""
        return self.state is ZState.IDLE

    @property
    def limit_hit(self) -> str | None:
        """``"min"``/``"max"`` while the axis is on that soft limit and not leaving it.

        The soft-limit switch: set when the axis stopped at (or rests on) the limit, cleared
        as soon as it moves away from it.
        """
        pos = self.position_mm
        if pos <= self.min_mm + self._eps and self.velocity_mm_s <= 0.0:
            return "min"
        if pos >= self.max_mm - self._eps and self.velocity_mm_s >= 0.0:
            return "max"
        return None

    @property
    def home_switch(self) -> bool:
        """The home switch (the Z_LIMIT_MAX input): closed at and above ``home_switch_mm``."""
        return self.position_mm >= self.home_switch_mm - self._eps

    def move_to(self, target_mm: float, feed_mm_s: float) -> None:
        """Position to ``target_mm`` (clamped to the soft limits) at up to ``feed_mm_s``."""
        if not feed_mm_s > 0.0:
            raise ValueError(f"feed_mm_s must be positive, got {feed_mm_s}")
        self.target_mm = min(max(target_mm, self.min_mm), self.max_mm)
        self._feed = min(feed_mm_s, self.max_velocity_mm_s)
        self._stopping = False
        self.state = ZState.MOVING

    def jog(self, velocity_mm_s: float) -> None:
        """Ramp to ``velocity_mm_s`` (clamped to ±max velocity) and hold it until told."""
        vmax = self.max_velocity_mm_s
        self._jog_v = min(max(velocity_mm_s, -vmax), vmax)
        self._stopping = False
        self.state = ZState.JOGGING

    def stop(self) -> None:
        """Decelerate to standstill at the acceleration limit, then go idle."""
        if self.state is ZState.IDLE:
            return
        self._jog_v = 0.0
        self._stopping = True
        self.state = ZState.JOGGING

    def drive(self, position_mm: float, velocity_mm_s: float) -> None:
        """Follow a step generator outside the axis (the board's, mock_device.board_logic):
        the position it has stepped to and its rate. ``step`` leaves both alone; the axis is
        idle while the rate is 0."""
        self.position_mm = position_mm
        self.velocity_mm_s = velocity_mm_s
        self.state = ZState.IDLE if velocity_mm_s == 0.0 else ZState.DRIVEN

    def _brake_speed(self, distance_mm: float, dt_s: float) -> float:
        """Largest speed from which shedding accel·dt per step stops within ``distance``."""
        if distance_mm <= 0.0:
            return 0.0
        adt = self._accel * dt_s
        return adt * 0.5 * (math.sqrt(8.0 * distance_mm / (adt * dt_s) + 1.0) - 1.0)

    def step(self, dt_s: float) -> None:
        """Advance the axis by ``dt_s`` seconds."""
        state = self.state
        if state is ZState.IDLE or state is ZState.DRIVEN:
            return
        v = self.velocity_mm_s
        pos = self.position_mm
        dv = self._accel * dt_s
        if state is ZState.MOVING:
            dist = self.target_mm - pos
            if dist >= 0.0:
                want = min(self._feed, self._brake_speed(dist, dt_s))
            else:
                want = -min(self._feed, self._brake_speed(-dist, dt_s))
        else:
            want = self._jog_v
            # Brake in time so a jog never runs through a soft limit.
            if want > 0.0:
                want = min(want, self._brake_speed(self.max_mm - pos, dt_s))
            elif want < 0.0:
                want = -min(-want, self._brake_speed(pos - self.min_mm, dt_s))
        if want > v + dv:
            v += dv
        elif want < v - dv:
            v -= dv
        else:
            v = want
        prev = pos
        pos += v * dt_s
        # The last creep step of a stop lands on the stop point; the speed (below accel·dt)
        # reaches zero on the next step, so the reported speed never jumps by more than dv.
        creep = -dv * 1.000001 <= v <= dv * 1.000001
        if state is ZState.MOVING:
            target = self.target_mm
            passed = (prev < target <= pos) or (prev > target >= pos)
            if passed and creep:
                pos = target
            elif v == 0.0 and abs(target - pos) <= self._eps:
                self.state = ZState.IDLE
        elif self._stopping and v == 0.0:
            self._stopping = False
            self.state = ZState.IDLE
        if pos <= self.min_mm:
            pos = self.min_mm
            if v < 0.0 and not creep:
                v = 0.0  # hard stop: only if a limit is reached faster than brakes allow
        elif pos >= self.max_mm:
            pos = self.max_mm
            if v > 0.0 and not creep:
                v = 0.0
        self.position_mm = pos
        self.velocity_mm_s = v
