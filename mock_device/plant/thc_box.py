"""An external THC box (LinuxCNC PlasmaC mode 2): up/down outputs from the arc voltage.

The box low-passes the measured voltage (``filter_ms``) and, only while arc OK is closed,
asserts ``up`` when the voltage is below ``set - deadband`` (torch too close) and ``down``
when it is above ``set + deadband`` (torch too high).
"""

import math

from .scenario import ThcBoxSpec

__all__ = ["ThcBox"]


class ThcBox:
    """Comparator with a dead band; ``update`` once per sample."""

    __slots__ = (
        "_alpha",
        "_alpha_dt",
        "_filter_s",
        "deadband_v",
        "down",
        "filtered_v",
        "set_voltage_v",
        "up",
    )

    def __init__(
        self, set_voltage_v: float, deadband_v: float = 1.0, filter_ms: float = 10.0
    ) -> None:
        self.set_voltage_v = set_voltage_v
        self.deadband_v = deadband_v
        self._filter_s = filter_ms / 1000.0
        self._alpha = 1.0
        self._alpha_dt = -1.0
        self.filtered_v = 0.0
        self.up = False
        self.down = False

    @classmethod
    def from_spec(cls, spec: ThcBoxSpec, default_set_voltage_v: float) -> "ThcBox":
        """A box with the scenario's settings; ``default_set_voltage_v`` if none is set."""
        set_v = spec.set_voltage_v if spec.set_voltage_v is not None else default_set_voltage_v
        return cls(set_v, spec.deadband_v, spec.filter_ms)

    def update(self, voltage_v: float, arc_ok: bool, dt_s: float) -> None:
        """Feed one voltage sample and the arc-OK state."""
        if not arc_ok:
            self.filtered_v = voltage_v
            self.up = self.down = False
            return
        if dt_s != self._alpha_dt:
            self._alpha = 1.0 - math.exp(-dt_s / self._filter_s) if self._filter_s > 0.0 else 1.0
            self._alpha_dt = dt_s
        v = self.filtered_v + (voltage_v - self.filtered_v) * self._alpha
        self.filtered_v = v
        self.up = v < self.set_voltage_v - self.deadband_v
        self.down = v > self.set_voltage_v + self.deadband_v
