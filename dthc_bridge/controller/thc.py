"""The THC controller: arc-voltage samples and motion state in, a Z velocity out.

A pure object, called once per sample batch. Design, against the complaints users have
about the open controllers (plasma-facts.md):

- **Noise**: each batch goes through a median-of-three (kills the 1-2 sample spikes of
  high-frequency start) and a first-order low-pass; a small dead band (0.3 V, a third of
  the usual 1 V) is enough after that, so the height is held tighter.
- **Control law**: the voltage error is turned into a height error with the material's
  V/mm slope, and Z velocity = Kp·e + Ki·∫e (PI on height). The integral term follows
  tilted and warped sheets without the steady error a P-only law keeps on a ramp.
- **Hunting**: the command is limited in speed (M667 F) and in acceleration.
- **Corner dive**: velocity anti-dive locks below A % of the requested feed and unlocks
  only above 99 %; missing or stale XY speed counts as locked.
- **Kerf and void dive**: the slope of the filtered voltage locks the THC above
  ``void_slope_v_s`` and holds the lock for a quiet period after the spike.
- **Start transient and arc-lost delay**: the sequence keeps THC frozen (``frozen``).
While locked, Z holds (velocity 0) and the integral is frozen, never wound up.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

__all__ = ["Lock", "ThcConfig", "ThcController", "ThcOutput"]


class Lock(StrEnum):
    DISABLED = "disabled"  # M666 / P7 A0 / M62-M64 P2
    FROZEN = "frozen"  # THC delay, arc-lost delay running, no target yet
    VELOCITY = "velocity"  # anti-dive: XY below A % of the requested feed
    VOID = "void"  # kerf or void crossing: voltage slope too steep
    NO_SPEED = "no_speed"  # XY speed unknown or stale: counts as locked


_FOLLOW_THROUGH = frozenset({Lock.VELOCITY})


@dataclass(frozen=True)
class ThcConfig:
    kp_per_s: float = 14.0  # Z mm/s per mm of height error (≈ 1.9 mm/s per volt at 7.5 V/mm)
    ki_per_s2: float = 40.0
    deadband_v: float = 0.3
    lowpass_hz: float = 40.0
    slope_v_per_mm: float = 7.5  # height per volt for the error conversion
    max_speed_mm_s: float = 30.0  # M667 F overrides
    max_accel_mm_s2: float = 500.0
    anti_dive_lock_percent: float = 90.0  # G200 A; 0 disables velocity anti-dive
    anti_dive_unlock_percent: float = 99.0
    void_slope_v_s: float = 250.0
    void_on_samples: int = 1  # consecutive steep samples (after the filters) before locking
    void_hold_s: float = 0.06  # quiet time after the last steep sample before unlocking
    # After the machine is back at speed the arc still carries the slow-down's voltage rise
    # for some tens of ms: stay locked that much longer.
    anti_dive_unlock_hold_s: float = 0.1
    # While locked by anti-dive, keep following the plate's slope (learned by the
    # integral term) scaled by the XY speed, instead of freezing Z on a rising sheet.
    # Off by default: it helps on long slow-downs on a tilted sheet (masso_warped RMS
    # 0.18 -> 0.15 mm) but the slope it learned belongs to the direction before a corner,
    # and on the warped sheet it raised the worst error from 0.37 to 0.62 mm.
    follow_plate_when_locked: bool = False
    integral_limit_mm_s: float = 15.0
    speed_stale_s: float = 0.05


@dataclass
class ThcOutput:
    velocity_mm_s: float
    locks: frozenset[Lock]
    voltage_v: float  # filtered arc voltage
    height_error_mm: float  # estimated: positive = torch too high


@dataclass
class _State:
    filtered_v: float | None = None
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=3))
    slope_ref: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=8))
    integral_mm_s: float = 0.0
    velocity_mm_s: float = 0.0
    velocity_locked: bool = True
    at_speed_since: float | None = None
    void_until_s: float = -1.0
    steep_samples: int = 0
    next_sample_t: float | None = None
    last_speed_s: float = -1e9
    speed_ratio: float = 0.0


class ThcController:
    def __init__(self, config: ThcConfig | None = None) -> None:
        self.config = config or ThcConfig()
        self.target_v: float | None = None
        self.enabled = True
        self.frozen = True
        self.max_speed_mm_s = self.config.max_speed_mm_s
        self.anti_dive_percent = self.config.anti_dive_lock_percent
        self._s = _State()

    def reset(self) -> None:
        """A new cut: forget filters, integral and locks; the sequence sets the target."""
        self._s = _State()
        self.target_v = None
        self.frozen = True

    def set_speed_limit(self, z_feed_mm_min: float | None) -> None:
        self.max_speed_mm_s = (
            self.config.max_speed_mm_s if z_feed_mm_min is None else z_feed_mm_min / 60.0
        )

    @property
    def filtered_v(self) -> float | None:
        return self._s.filtered_v

    def observe_speed(
        self, xy_speed_mm_s: float | None, requested_mm_s: float | None, now_s: float
    ) -> None:
        """Velocity anti-dive with hysteresis; unknown speed locks."""
        s = self._s
        if xy_speed_mm_s is None or not requested_mm_s:
            s.velocity_locked = True
            return
        s.last_speed_s = now_s
        ratio = 100.0 * xy_speed_mm_s / requested_mm_s
        s.speed_ratio = min(1.0, max(0.0, ratio / 100.0))
        if s.velocity_locked:
            if ratio < self.config.anti_dive_unlock_percent:
                s.at_speed_since = None
            else:
                if s.at_speed_since is None:
                    s.at_speed_since = now_s
                if now_s - s.at_speed_since >= self.config.anti_dive_unlock_hold_s:
                    s.velocity_locked = False
        elif ratio < self.anti_dive_percent:
            s.velocity_locked = True
            s.at_speed_since = None

    def locks(self, now_s: float) -> frozenset[Lock]:
        s = self._s
        found: set[Lock] = set()
        if not self.enabled:
            found.add(Lock.DISABLED)
        if self.frozen or self.target_v is None:
            found.add(Lock.FROZEN)
        if self.anti_dive_percent > 0.0:
            if now_s - s.last_speed_s > self.config.speed_stale_s:
                found.add(Lock.NO_SPEED)
            elif s.velocity_locked:
                found.add(Lock.VELOCITY)
        if now_s < s.void_until_s:
            found.add(Lock.VOID)
        return frozenset(found)

    def filter(self, samples_v: Sequence[float], period_s: float, now_s: float) -> float:
        """Spike rejection, low-pass and void detection over one batch; returns the filtered V."""
        cfg = self.config
        s = self._s
        alpha = 1.0 - math.exp(-2.0 * math.pi * cfg.lowpass_hz * period_s)
        # Sample times come from the sample count, not from when the batch arrived: two
        # batches read together must not look like a steep slope.
        t = now_s - period_s * (len(samples_v) - 1)
        expected = s.next_sample_t
        if expected is not None and abs(t - expected) < 0.05:
            t = expected
        for raw in samples_v:
            s.recent.append(raw)
            v = raw
            if len(s.recent) == 3:
                a, b, c = s.recent
                v = a + b + c - max(a, b, c) - min(a, b, c)  # median of three
            s.filtered_v = v if s.filtered_v is None else s.filtered_v + alpha * (v - s.filtered_v)
            s.slope_ref.append((t, s.filtered_v))
            t0, v0 = s.slope_ref[0]
            if t > t0:
                slope = (s.filtered_v - v0) / (t - t0)
                if abs(slope) > cfg.void_slope_v_s:
                    s.steep_samples += 1
                    if s.steep_samples >= cfg.void_on_samples:
                        s.void_until_s = t + cfg.void_hold_s
                else:
                    s.steep_samples = 0
            t += period_s
        s.next_sample_t = t
        assert s.filtered_v is not None
        return s.filtered_v

    def update(
        self,
        samples_v: Sequence[float],
        period_s: float,
        now_s: float,
        dt_s: float,
    ) -> ThcOutput:
        """One control step per batch. ``dt_s`` is the time since the previous step."""
        cfg = self.config
        s = self._s
        v_f = self.filter(samples_v, period_s, now_s)
        locks = self.locks(now_s)
        error_mm = 0.0
        command = 0.0
        if self.target_v is not None:
            error_v = self.target_v - v_f  # positive: voltage low, torch too close
            if abs(error_v) <= cfg.deadband_v:
                error_v = 0.0
            else:
                error_v -= cfg.deadband_v if error_v > 0 else -cfg.deadband_v
            error_mm = error_v / cfg.slope_v_per_mm
            if not locks:
                s.integral_mm_s += cfg.ki_per_s2 * error_mm * dt_s
                lim = cfg.integral_limit_mm_s
                s.integral_mm_s = max(-lim, min(lim, s.integral_mm_s))
                command = cfg.kp_per_s * error_mm + s.integral_mm_s
            elif locks <= _FOLLOW_THROUGH and cfg.follow_plate_when_locked:
                # The voltage cannot be trusted, but the plate's slope can: the integral is
                # the Z speed that followed it at full feed; scale it to the speed now.
                command = s.integral_mm_s * s.speed_ratio
        limit = self.max_speed_mm_s
        command = max(-limit, min(limit, command))
        step = cfg.max_accel_mm_s2 * dt_s
        s.velocity_mm_s = max(s.velocity_mm_s - step, min(s.velocity_mm_s + step, command))
        return ThcOutput(s.velocity_mm_s, locks, v_f, -error_mm)
