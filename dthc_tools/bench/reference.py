"""The reference THC: the control law the open controllers share, as a drop-in controller.

Built from docs/plasma-facts.md (how the open controllers control height, plasmac among
them), so the ``control`` benchmark compares control laws on the
same plant, with the same sequence, THC delay, target voltage and anti-dive hysteresis:

- **Voltage**: the plain mean of each sample batch; no median, no low-pass.
- **Dead band**: hard, 1 V: inside it the error is zero, outside it is used in full.
- **Law**: Z speed = 1 mm/s per volt of (target - V), clamped to the THC speed limit
  (``M667 F``); no acceleration limit beyond what the board's Z axis does.
- **Velocity anti-dive**: lock below 90 % (``G200 A``) of the requested feed, unlock above
  99 %; missing or stale XY speed counts as locked (inherited from :class:`ThcController`).
- **Void lock**: lock when |dV| between consecutive samples exceeds
  ``slope x period x threshold_cycles`` on ``on_samples`` consecutive samples, unlock after
  ``off_samples`` quiet ones, with plasmac's counter rules (the on-counter is cleared only by
  a quiet sample while unlocked; an exceedance while locked restarts the quiet count).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from dthc_bridge.controller.thc import Lock, ThcConfig, ThcController, ThcOutput

__all__ = ["ReferenceConfig", "ReferenceThc"]


@dataclass(frozen=True)
class ReferenceConfig:
    deadband_v: float = 1.0
    gain_mm_s_per_v: float = 1.0
    void_slope_v_s: float = 500.0
    # docs/plasma-facts.md: threshold per sample = slope x period. plasmac's code multiplies by
    # its on_cycles (2), i.e. 1 V per 1 ms sample: set 2.0 for that variant.
    void_threshold_cycles: float = 2.0
    void_on_samples: int = 3
    void_off_samples: int = 10


class ReferenceThc(ThcController):
    """Same interface as :class:`ThcController`; only ``filter``/``update``/``locks`` differ."""

    def __init__(self, reference: ReferenceConfig | None = None, config: ThcConfig | None = None):
        # The open controllers unlock the moment the speed is back at 99 %: no hold, and
        # hold Z through a whole slow-down.
        super().__init__(
            replace(config or ThcConfig(), anti_dive_unlock_hold_s=0.0, slow_follow=False)
        )
        self.reference = reference or ReferenceConfig()
        self._mean_v: float | None = None
        self._last_raw: float | None = None
        self._on = 0
        self._off = 0
        self._void = False

    def reset(self) -> None:
        super().reset()
        self._mean_v = None
        self._last_raw = None
        self._on = 0
        self._off = 0
        self._void = False

    @property
    def filtered_v(self) -> float | None:
        return self._mean_v

    @property
    def void_locked(self) -> bool:
        return self._void

    def locks(self, now_s: float) -> frozenset[Lock]:
        found = set(super().locks(now_s))
        found.discard(Lock.VOID)  # the parent's slope detector never runs here
        if self._void:
            found.add(Lock.VOID)
        return frozenset(found)

    def filter(self, samples_v: Sequence[float], period_s: float, now_s: float) -> float:
        """Batch mean; per-sample void detection on the raw samples."""
        ref = self.reference
        threshold = ref.void_slope_v_s * period_s * ref.void_threshold_cycles
        last = self._last_raw
        for raw in samples_v:
            if last is not None:
                if abs(raw - last) > threshold:
                    self._on += 1
                    if self._on >= ref.void_on_samples:
                        self._void = True
                        self._off = 0
                elif self._void:
                    self._off += 1
                    if self._off >= ref.void_off_samples:
                        self._void = False
                else:
                    self._on = 0
            last = raw
        self._last_raw = last
        self._mean_v = sum(samples_v) / len(samples_v)
        return self._mean_v

    def update(
        self,
        samples_v: Sequence[float],
        period_s: float,
        now_s: float,
        dt_s: float,
    ) -> ThcOutput:
        v = self.filter(samples_v, period_s, now_s)
        locks = self.locks(now_s)
        error_v = 0.0
        command = 0.0
        if self.target_v is not None:
            error_v = self.target_v - v
            if abs(error_v) < self.reference.deadband_v:
                error_v = 0.0
            if not locks:
                command = self.reference.gain_mm_s_per_v * error_v
        limit = self.max_speed_mm_s
        command = max(-limit, min(limit, command))
        return ThcOutput(command, locks, v, -error_v / self.config.slope_v_per_mm)
