"""The THC controller: arc-voltage samples and motion state in, a Z velocity out.

A pure object, called once per sample batch. Design, against the complaints users have
about the open controllers (docs/plasma-facts.md):

- **Noise**: each batch goes through a median-of-three (kills the 1-2 sample spikes of
  high-frequency start; where it is further than ``spike_v`` from the median of five, a
  two-sample spike, the median of five) and a first-order low-pass; a small dead band
  (0.15 V, a sixth of the usual 1 V) is enough after that, so the height is held tighter.
  In a noise burst (the mean |second difference| of those samples above ``noise_ref_v``,
  rising within ``noise_attack_s``) the loop's command is scaled down by the square of
  the ratio, it acts on the filtered voltage averaged over ``burst_average_s``, and no
  slow-down target is measured.
- **Control law**: the voltage error is turned into a height error with the material's
  V/mm slope, and Z velocity = Kp·e + Ki·∫e (PI on height). The integral term follows
  tilted and warped sheets without the steady error a P-only law keeps on a ramp.
- **Hunting**: the command is limited in speed (M667 F) and in acceleration.
- **Corner dive**: velocity anti-dive locks below A % of the requested feed and unlocks
  only above 99 %; missing or stale XY speed counts as locked.
- **Back at speed**: the velocity lock holds ``anti_dive_unlock_hold_s`` longer while the
  slow-down's voltage rise decays; meanwhile the loop acts (P only) on the voltage less an
  estimate of the rise left (its excess at the hold's start, decaying exponentially), down
  only on what remains, up only on a voltage low by itself: a plate falling away after a
  corner is followed, the decaying rise is not.
- **Long slow-downs** (a velocity reduction, a slow lead or hole): the velocity lock holds
  Z while the XY speed changes. Once the speed has held steady below the lock threshold
  and the voltage rise of the slower cut has settled (two consecutive windows of the
  filtered voltage agree), the voltage measured then (never below the cut target: slowing
  down only raises it; plus what the plate moved under the held torch, extrapolated from
  the Z speed that followed it at full feed over the distance cut while held, less what Z
  moved meanwhile on that prediction) becomes a
  temporary target, and the loop follows the plate again,
  with its Z travel while following summed over the cut and bounded: ``slow_follow_max_mm``
  each way, and down no more than half the cut height (set by the sequence). A change of
  speed or a stale speed drops back to the plain lock, a void pauses it; at speed again,
  the cut target applies.
  While the rise settles, Z already follows the plate it predicts (that full-feed Z speed
  times the speed ratio, when above ``slow_settle_min_mm_s``), within the same bounds.
- **Kerf and void dive**: a rise of at least ``void_step_v`` at a mean slope of at least
  ``void_slope_v_s``, on a median-of-five and mean path of its own, locks the THC; it
  releases once the voltage is back near its level before the rise, or after a quiet
  period (``void_lock.VoidLockDetector``). Noise bursts and spikes do not lock.
- **Operator pause**: ``held`` locks until the program resumes (or the next cut starts).
- **Start transient and arc-lost delay**: the sequence keeps THC frozen (``frozen``);
  after the delay it hands over what is left of the transient (``transient_v``).
While locked, Z holds (velocity 0) and the integral is frozen, never wound up.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from .void_lock import VoidLockDetector

__all__ = ["Lock", "ThcConfig", "ThcController", "ThcOutput"]


class Lock(StrEnum):
    DISABLED = "disabled"  # M666 / P7 A0 / M62-M64 P2
    FROZEN = "frozen"  # THC delay, arc-lost delay running, no target yet
    VELOCITY = "velocity"  # anti-dive: XY below A % of the requested feed
    VOID = "void"  # kerf or void crossing: voltage slope too steep
    NO_SPEED = "no_speed"  # XY speed unknown or stale: counts as locked
    HELD = "held"  # the operator paused the program (thc_hold request)


@dataclass(frozen=True)
class ThcConfig:
    kp_per_s: float = 14.0  # Z mm/s per mm of height error (≈ 1.9 mm/s per volt at 7.5 V/mm)
    ki_per_s2: float = 60.0
    deadband_v: float = 0.15
    lowpass_hz: float = 40.0
    spike_v: float = 5.0  # median of three this far from the median of five: a spike
    # Noise bursts: the loop gain is scaled by (noise_ref_v / noise)^2 above noise_ref_v,
    # noise being the mean |second difference| of the spike-free samples over noise_tau_s.
    noise_ref_v: float = 1.2
    noise_tau_s: float = 0.05
    noise_attack_s: float = 0.005  # ...rising this much faster: a burst is held at once
    slope_v_per_mm: float = 7.5  # height per volt for the error conversion
    max_speed_mm_s: float = 30.0  # M667 F overrides
    max_accel_mm_s2: float = 500.0
    anti_dive_lock_percent: float = 90.0  # G200 A; 0 disables velocity anti-dive
    anti_dive_unlock_percent: float = 99.0
    # Void lock: a rise of void_step_v within void_step_v / void_slope_v_s seconds (on the
    # detector's own median-of-five and mean), on void_on_samples consecutive samples.
    void_slope_v_s: float = 250.0
    void_step_v: float = 4.0
    void_on_samples: int = 1
    void_hold_s: float = 0.06  # no step for this long: unlock (the plate moved meanwhile)
    void_back_v: float = 1.5  # unlock once this close to the level before the rise...
    void_back_samples: int = 5  # ...for this many samples
    # A rise of this much over the detector's window (not yet a void lock): Z does not go
    # down meanwhile (a kerf's first milliseconds), up is allowed. 0: off.
    void_guard_v: float = 2.0
    # After the machine is back at speed the arc still carries the slow-down's voltage rise
    # for some tens of ms: stay locked that much longer.
    anti_dive_unlock_hold_s: float = 0.1
    # During that hold the loop acts (P only) on the voltage less what is left of the rise:
    # the excess over the voltage at full speed when the hold began, decaying with this time
    # constant. 0: Z holds to the end of the hold.
    unlock_hold_rise_tau_s: float = 0.08
    # Steady slow-downs: follow the plate against the voltage measured once the rise has
    # settled (see the module docstring). Off: the velocity lock holds Z to the end.
    slow_follow: bool = True
    slow_min_settle_s: float = 0.2  # speed steady at least this long before measuring
    slow_max_settle_s: float = 0.5  # the voltage never settled by then: stay locked
    slow_window_s: float = 0.04  # the two windows compared for "settled", and averaged
    slow_settled_v: float = 0.4  # settled: window means differ by no more than this
    slow_steady_percent: float = 2.0  # "steady": within this % of the requested feed
    slow_min_percent: float = 20.0  # slower than this (a stop, a creep) stays locked
    slow_max_rise_v: float = 15.0  # a larger rise is no slow-down: stay locked
    slow_error_average_s: float = 0.1  # time constant of the full-speed error carried over
    slow_follow_max_mm: float = 1.5  # Z travel while following slow-downs, each way, per cut
    # The plate keeps moving under the held torch until the slow target is measured: add the
    # Z speed that followed it at full feed, times the time held (this fraction of it).
    slow_plate_feedforward: float = 1.0
    # While that rise settles Z already moves the same way (times this): it follows the
    # plate it predicts. 0: Z holds until the slow target is measured.
    slow_settle_feedforward: float = 1.0
    slow_settle_min_mm_s: float = 0.3  # a slower Z at full feed is noise: no prediction
    # A plate Z did not follow at full feed (|mean Z speed| below slow_flat_mm_s) is flat:
    # the slow target's own noise (a 40 ms window) is then the likelier error, and while
    # following Z acts only outside this wider dead band. 0: the cut's dead band.
    slow_flat_mm_s: float = 0.2
    slow_flat_deadband_v: float = 1.5
    # In a noise burst the loop acts on the filtered voltage averaged over this time
    # constant (about a quarter of the noise the 40 Hz low-pass leaves: 2 V of burst noise
    # then mostly inside the dead band). 0: the filtered voltage, as outside bursts.
    burst_average_s: float = 0.05
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
    averaged_v: float | None = None  # filtered_v averaged over burst_average_s
    despiked: deque[float] = field(default_factory=lambda: deque(maxlen=3))
    noise_v: float = 0.0
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=5))
    integral_mm_s: float = 0.0
    velocity_mm_s: float = 0.0
    velocity_locked: bool = True
    at_speed_since: float | None = None
    hold_rise_v: float | None = None  # the rise left when the unlock hold began
    void: VoidLockDetector | None = None
    void_config: ThcConfig | None = None  # the configuration ``void`` was built from
    next_sample_t: float | None = None
    last_speed_s: float = -1e9
    speed_ratio: float = 0.0
    # Steady-speed tracking for slow-down following.
    steady_speed_mm_s: float = -1.0
    steady_since_s: float = 0.0
    slow_recent: deque[tuple[float, float]] = field(default_factory=deque)  # (t, V filtered)
    slow_target_v: float | None = None  # set while following a slow-down
    # The filtered voltage error (V - target) while last at full speed and unlocked: how
    # far off the torch already was when the slow-down began.
    at_speed_error_v: float = 0.0
    at_speed_velocity_mm_s: float = 0.0  # Z speed at full feed, averaged the same way
    # Since the velocity lock last engaged: the time held weighted by the speed ratio (the
    # distance cut, in seconds at full feed). None: not locked from full speed.
    held_feed_s: float | None = None
    held_travel_mm: float = 0.0  # Z travel on the prediction while held
    full_speed_integral_mm_s: float = 0.0  # the integral to restore at speed
    slow_travel_mm: float = 0.0  # Z travel while following, summed over the cut
    slow_flat: bool = False  # the slow target was set on a flat plate (slow_flat_mm_s)


_DELAY_ONLY = frozenset({Lock.FROZEN})
_VELOCITY_ONLY = frozenset({Lock.VELOCITY})
_STEADY_S = 0.03  # a speed this steady below the lock is a slow-down, not a corner


class ThcController:
    def __init__(self, config: ThcConfig | None = None) -> None:
        self.config = config or ThcConfig()
        self.target_v: float | None = None
        # What the arc still carries on top of the cut's voltage for now, set by the sequence
        # each batch: the start transient's remnant, as the pierce and the THC delay's
        # voltages show it (start_transient.py). The loop holds target_v plus this, so a
        # decaying overshoot after the delay does not take the torch down (and back up).
        self.transient_v = 0.0
        self.enabled = True
        self.frozen = True
        self.held = False  # operator pause: Z holds until released or the next cut
        # During the THC delay (frozen, target known): raise the torch on a low voltage,
        # never lower it. The start transient only ever raises the voltage, so a low one is
        # the plate coming up under the held torch, the dangerous direction.
        self.rise_only = False
        self.max_speed_mm_s = self.config.max_speed_mm_s
        self.anti_dive_percent = self.config.anti_dive_lock_percent
        # Downward Z travel allowed while following slow-downs, over a whole cut: the
        # sequence sets half the cut height (lower is a dive); None: slow_follow_max_mm.
        self.slow_follow_max_down_mm: float | None = None
        self._s = self._new_state()

    def _new_state(self) -> _State:
        cfg = self.config
        detector = VoidLockDetector(
            slope_v_s=cfg.void_slope_v_s,
            step_v=cfg.void_step_v,
            on_samples=cfg.void_on_samples,
            hold_s=cfg.void_hold_s,
            back_v=cfg.void_back_v,
            back_samples=cfg.void_back_samples,
        )
        return _State(void=detector, void_config=cfg)

    def reset(self) -> None:
        """A new cut: forget filters, integral and locks; the sequence sets the target."""
        self._s = self._new_state()
        self.target_v = None
        self.transient_v = 0.0
        self.frozen = True
        self.held = False
        self.rise_only = False

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
        cfg = self.config
        s = self._s
        if xy_speed_mm_s is None or not requested_mm_s:
            s.velocity_locked = True
            return
        if s.held_feed_s is not None and s.velocity_locked:
            s.held_feed_s += s.speed_ratio * min(now_s - s.last_speed_s, cfg.speed_stale_s)
        s.last_speed_s = now_s
        ratio = 100.0 * xy_speed_mm_s / requested_mm_s
        s.speed_ratio = min(1.0, max(0.0, ratio / 100.0))
        band = self.config.slow_steady_percent / 100.0 * requested_mm_s
        if abs(xy_speed_mm_s - s.steady_speed_mm_s) > band:
            s.steady_speed_mm_s = xy_speed_mm_s
            s.steady_since_s = now_s
            s.slow_recent.clear()
            self._stop_following()
        if s.velocity_locked:
            if ratio < self.config.anti_dive_unlock_percent:
                s.at_speed_since = None
            else:
                if s.at_speed_since is None:
                    s.at_speed_since = now_s
                    s.hold_rise_v = None
                if now_s - s.at_speed_since >= self.config.anti_dive_unlock_hold_s:
                    s.velocity_locked = False
        elif ratio < self.anti_dive_percent:
            s.velocity_locked = True
            s.at_speed_since = None
            s.held_feed_s = 0.0
            s.held_travel_mm = 0.0

    def locks(self, now_s: float) -> frozenset[Lock]:
        s = self._s
        found: set[Lock] = set()
        if not self.enabled:
            found.add(Lock.DISABLED)
        if self.held:
            found.add(Lock.HELD)
        if self.frozen or self.target_v is None:
            found.add(Lock.FROZEN)
        if self.anti_dive_percent > 0.0:
            if now_s - s.last_speed_s > self.config.speed_stale_s:
                found.add(Lock.NO_SPEED)
            elif s.velocity_locked and s.slow_target_v is None:
                found.add(Lock.VELOCITY)
        if self._void_locked():
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
        if s.void_config is not self.config:  # the configuration was replaced
            s.void, s.void_config = self._new_state().void, self.config
        expected = s.next_sample_t
        if expected is not None and abs(t - expected) < 0.05:
            t = expected
        for raw in samples_v:
            s.recent.append(raw)
            v = raw
            if len(s.recent) >= 3:
                a, b, c = list(s.recent)[-3:]
                v = a + b + c - max(a, b, c) - min(a, b, c)  # median of three
                if len(s.recent) == 5:
                    # A two-sample spike passes the median of three, not that of five.
                    m5 = sorted(s.recent)[2]
                    if abs(v - m5) > cfg.spike_v:
                        v = m5
            s.filtered_v = v if s.filtered_v is None else s.filtered_v + alpha * (v - s.filtered_v)
            if cfg.burst_average_s > 0.0:
                beta = min(1.0, period_s / cfg.burst_average_s)
                s.averaged_v = (
                    s.filtered_v
                    if s.averaged_v is None
                    else s.averaged_v + beta * (s.filtered_v - s.averaged_v)
                )
            d = s.despiked
            d.append(v)
            if len(d) == 3 and cfg.noise_tau_s > 0.0:
                d2 = abs(d[2] - 2.0 * d[1] + d[0])
                tau = cfg.noise_attack_s if d2 > s.noise_v else cfg.noise_tau_s
                s.noise_v += min(1.0, period_s / max(tau, period_s)) * (d2 - s.noise_v)
            if s.void is not None:
                s.void.sample(raw, t, period_s)
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
        self._follow_slow_down(v_f, now_s)
        locks = self.locks(now_s)
        error_mm = 0.0
        command = 0.0
        predicting = False  # moving Z on the plate predicted while a slow-down settles
        cut_target_v = None if self.target_v is None else self.target_v + self.transient_v
        target_v = cut_target_v if s.slow_target_v is None else s.slow_target_v
        if cut_target_v is not None and not locks and s.slow_target_v is None:
            # Averaged over about 0.1 s: one noisy sample must not set the next slow target.
            a = min(1.0, dt_s / cfg.slow_error_average_s)
            s.at_speed_error_v += a * (v_f - cut_target_v - s.at_speed_error_v)
            s.at_speed_velocity_mm_s += a * (s.velocity_mm_s - s.at_speed_velocity_mm_s)
        if target_v is not None:
            seen_v = v_f
            if self.noise_burst and s.averaged_v is not None:  # None: burst_average_s 0
                seen_v = s.averaged_v  # a burst: the longer average
            error_v = target_v - seen_v  # positive: voltage low, torch too close
            deadband = cfg.deadband_v
            if s.slow_target_v is not None and s.slow_flat:
                deadband = max(deadband, cfg.slow_flat_deadband_v)
            if abs(error_v) <= deadband:
                error_v = 0.0
            else:
                error_v -= deadband if error_v > 0 else -deadband
            error_mm = error_v / cfg.slope_v_per_mm
            gain = 1.0
            if s.noise_v > cfg.noise_ref_v > 0.0:
                gain = (cfg.noise_ref_v / s.noise_v) ** 2  # a noise burst: act less on it
            if not locks:
                rising = self._rising()
                if not (rising and error_mm < 0.0):
                    s.integral_mm_s += cfg.ki_per_s2 * gain * error_mm * dt_s
                    lim = cfg.integral_limit_mm_s
                    s.integral_mm_s = max(-lim, min(lim, s.integral_mm_s))
                command = gain * (cfg.kp_per_s * error_mm + s.integral_mm_s)
                if rising:
                    # Perhaps a kerf's first milliseconds: never down before it is known.
                    command = max(0.0, command)
            elif self.rise_only and locks == _DELAY_ONLY and error_mm > 0.0:
                command = cfg.kp_per_s * error_mm  # up only, and no integral yet
            elif locks == _VELOCITY_ONLY and s.at_speed_since is not None:
                command = self._unlock_hold_command(v_f, target_v, now_s)
            elif locks == _VELOCITY_ONLY and self._settling_slow_down(now_s):
                v = s.at_speed_velocity_mm_s
                if abs(v) > cfg.slow_settle_min_mm_s:
                    command = cfg.slow_settle_feedforward * v * s.speed_ratio
                    predicting = True
        limit = self.max_speed_mm_s
        command = max(-limit, min(limit, command))
        bounded = s.slow_target_v is not None or predicting
        if bounded:
            # Following a slow-down (on a measured target, or predicted while it settles):
            # bounded travel over the cut, braking in time to stop at the bound.
            if command > 0.0:
                room = cfg.slow_follow_max_mm - s.slow_travel_mm
            else:
                down = cfg.slow_follow_max_mm
                if self.slow_follow_max_down_mm is not None:
                    down = min(down, self.slow_follow_max_down_mm)
                room = down + s.slow_travel_mm
            room = max(0.0, room)
            # The speed that still stops within ``room``: v·dt + v²/2a = room.
            a = cfg.max_accel_mm_s2
            braking = a * (math.sqrt(dt_s * dt_s + 2.0 * room / a) - dt_s)
            command = max(-braking, min(braking, command))
        step = cfg.max_accel_mm_s2 * dt_s
        s.velocity_mm_s = max(s.velocity_mm_s - step, min(s.velocity_mm_s + step, command))
        if bounded:
            s.slow_travel_mm += s.velocity_mm_s * dt_s
        if s.slow_target_v is None and Lock.VELOCITY in locks:
            s.held_travel_mm += s.velocity_mm_s * dt_s
        return ThcOutput(s.velocity_mm_s, locks, v_f, -error_mm)

    def _settling_slow_down(self, now_s: float) -> bool:
        """A steady slow-down whose rise is settling (following could start soon)."""
        cfg = self.config
        s = self._s
        return (
            cfg.slow_follow
            and s.held_feed_s is not None
            and s.slow_target_v is None
            and s.speed_ratio * 100.0 >= cfg.slow_min_percent
            and _STEADY_S <= now_s - s.steady_since_s <= cfg.slow_max_settle_s
        )

    def _unlock_hold_command(self, v_f: float, target_v: float, now_s: float) -> float:
        """Back at speed, before the velocity lock releases: P on the voltage less the rise
        still decaying (see ``unlock_hold_rise_tau_s``)."""
        cfg = self.config
        s = self._s
        tau = cfg.unlock_hold_rise_tau_s
        if tau <= 0.0 or s.at_speed_since is None:
            return 0.0
        if s.hold_rise_v is None:
            # The excess over the voltage at full speed before the slow-down (the plate's own
            # drift while locked is counted as rise: the estimate errs on the high side).
            s.hold_rise_v = max(0.0, v_f - target_v - s.at_speed_error_v)
        rise_v = s.hold_rise_v * math.exp(-(now_s - s.at_speed_since) / tau)
        error_v = target_v - (v_f - rise_v)
        if error_v > 0.0:
            # Up only on a voltage that is low by itself: an estimate of the rise too large
            # must not lift the torch.
            error_v = max(0.0, target_v - v_f)
        if abs(error_v) <= cfg.deadband_v:
            return 0.0
        error_v -= cfg.deadband_v if error_v > 0 else -cfg.deadband_v
        return cfg.kp_per_s * error_v / cfg.slope_v_per_mm

    def _rising(self) -> bool:
        void = self._s.void
        guard = self.config.void_guard_v
        quiet = self._s.noise_v <= self.config.noise_ref_v  # a burst rises and falls anyway
        return void is not None and guard > 0.0 and void.rise_v >= guard and quiet

    def _void_locked(self) -> bool:
        void = self._s.void
        return void is not None and void.locked

    @property
    def noise_burst(self) -> bool:
        """A noise burst is on (see ``noise_ref_v``): its voltages are no measurement."""
        ref = self.config.noise_ref_v
        return ref > 0.0 and self._s.noise_v > ref

    @property
    def slow_target_v(self) -> float | None:
        """The temporary target while following a steady slow-down, else None."""
        return self._s.slow_target_v

    def _stop_following(self) -> None:
        s = self._s
        if s.slow_target_v is not None:
            s.slow_target_v = None
            s.integral_mm_s = s.full_speed_integral_mm_s

    def _follow_slow_down(self, v_f: float, now_s: float) -> None:
        """Enter or leave slow-down following (see the module docstring)."""
        cfg = self.config
        s = self._s
        can_follow = (
            cfg.slow_follow
            and self.enabled
            and not self.held
            and not self.frozen
            and self.target_v is not None
            and self.anti_dive_percent > 0.0
            and s.velocity_locked
            and now_s - s.last_speed_s <= cfg.speed_stale_s
            and s.speed_ratio * 100.0 >= cfg.slow_min_percent
        )
        if not can_follow:
            self._stop_following()
            return
        # A void or a spike during the slow-down only pauses following (the VOID lock holds
        # Z): the target measured for this speed is kept, not measured again on noise.
        if s.slow_target_v is not None:
            return
        recent = s.slow_recent
        if self._void_locked() or s.noise_v > cfg.noise_ref_v > 0.0:
            # A void's voltage, or a noise burst's, must not enter the windows.
            recent.clear()
            return
        steady_s = now_s - s.steady_since_s
        if steady_s > cfg.slow_max_settle_s:
            return  # it never settled (a burst, a steep plate): the lock holds
        window = cfg.slow_window_s
        recent.append((now_s, v_f))
        while recent and recent[0][0] < now_s - 2.0 * window:
            recent.popleft()
        if steady_s < cfg.slow_min_settle_s or recent[0][0] > now_s - 1.5 * window:
            return
        older = [v for t, v in recent if t <= now_s - window]
        newer = [v for t, v in recent if t > now_s - window]
        if not older or not newer:
            return
        measured = sum(newer) / len(newer)
        if abs(measured - sum(older) / len(older)) > cfg.slow_settled_v:
            return
        assert self.target_v is not None
        if measured - self.target_v > cfg.slow_max_rise_v:
            return
        # Slowing down only raises the voltage: a measured value below the cut target
        # means the torch is already low, and the cut target is the safe one. The error
        # the torch already had at full speed is not kept.
        # A plate that rose under the held torch lowered the voltage measured: add it back.
        held_s = 0.0 if s.held_feed_s is None else s.held_feed_s
        plate_mm = cfg.slow_plate_feedforward * s.at_speed_velocity_mm_s * held_s
        plate_v = (plate_mm - s.held_travel_mm) * cfg.slope_v_per_mm
        s.slow_target_v = max(measured - s.at_speed_error_v + plate_v, self.target_v)
        s.slow_flat = abs(s.at_speed_velocity_mm_s) < cfg.slow_flat_mm_s
        s.full_speed_integral_mm_s = s.integral_mm_s
        # The integral is the Z speed that followed the plate at full feed: scale it (a
        # flat plate's is noise: none).
        s.integral_mm_s *= 0.0 if s.slow_flat and cfg.slow_flat_deadband_v > 0.0 else s.speed_ratio
