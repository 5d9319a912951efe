"""The plasma arc: start sequence, arc-OK contact, arc voltage and arc loss.

States: ``OFF`` → (torch on) ``PILOT`` (open-circuit voltage) → ``TRANSFERRED`` once the
pilot time has passed with the tip within transfer range over metal. A pilot that never
transfers is timed out by the cutter (``NO_TRANSFER``, 0 V). A transferred arc is lost
(``LOST``, open-circuit voltage while the torch stays on; no automatic re-fire) above the
stand-off limit, over a wide void, or by fault injection. Torch off → ``OFF`` and 0 V.
An arc that transferred above the stand-off limit (the pilot reaches down to the plate from
up to ``transfer_max_height_mm``) survives at up to its transfer height until the torch
has come down below the limit; from then on the limit applies.

Transferred voltage, noiseless::

    v = v_cut + slope·(h - h_cut) + transient + rise + gap + current term

- transient: ``overshoot_v`` at transfer, decaying exponentially (5 % left at ``settle_s``);
- rise: ``rise_v * clamp(1 - xy_speed/requested_feed, 0, 1)`` low-passed (``speed_filter_s``);
- gap: ramps towards ``kerf_spike_v`` at ``kerf_rise_v_per_s`` while the tip is over an old
  kerf or a void, back to 0 at ``kerf_fall_v_per_s`` over metal.
"""

import enum
import math
import random

from .scenario import ArcSpec, MaterialSpec
from .surface import GAP_METAL, GAP_WIDE

__all__ = ["Arc", "ArcEnd", "ArcState"]


class ArcState(enum.IntEnum):
    """Arc states (the int values are recorded by the truth recorder)."""

    OFF = 0
    PILOT = 1
    TRANSFERRED = 2
    LOST = 3
    NO_TRANSFER = 4


class ArcEnd(enum.StrEnum):
    """Why the last arc (pilot or transferred) ended."""

    TORCH_OFF = "torch_off"
    TOO_HIGH = "too_high"
    VOID = "void"
    INJECTED = "injected"
    NO_TRANSFER = "no_transfer"


class Arc:
    """Arc state machine; ``step`` once per sample, after the torch head update."""

    __slots__ = (
        "_alpha",
        "_decay",
        "_decay_dt",
        "_fall",
        "_gap_v",
        "_lose_above_mm",
        "_ok_bounce_end_t",
        "_ok_switch_t",
        "_ok_switched",
        "_ok_target",
        "_rise_v",
        "_rng",
        "_settle_tau_s",
        "_slope",
        "_speed_tau_s",
        "_t_on_s",
        "_transient_v",
        "_v0",
        "_v0_base",
        "_void_s",
        "arc_ok",
        "arc_ok_bounce_s",
        "arc_ok_delay_s",
        "current_a",
        "end_reason",
        "pilot_to_transfer_s",
        "spec",
        "state",
        "transfer_t_s",
        "transfers",
        "voltage_v",
    )

    def __init__(self, spec: ArcSpec, material: MaterialSpec, rng: random.Random) -> None:
        self.spec = spec
        self._rng = rng
        self._slope = material.slope_v_per_mm
        self._v0_base = material.cut_voltage_v - material.slope_v_per_mm * material.cut_height_mm
        self.current_a = spec.nominal_current_a
        self._v0 = self._v0_base
        self._settle_tau_s = spec.settle_s / 3.0
        self._speed_tau_s = spec.speed_filter_s
        self._decay = self._alpha = 0.0
        self._decay_dt = -1.0
        self._fall = spec.kerf_fall_v_per_s
        self.state = ArcState.OFF
        self.voltage_v = 0.0
        self.arc_ok = False
        self.end_reason: ArcEnd | None = None
        self.transfer_t_s = math.nan
        self.transfers = 0
        self.pilot_to_transfer_s = 0.0
        self.arc_ok_delay_s = 0.0
        self.arc_ok_bounce_s = 0.0
        self._t_on_s = 0.0
        self._transient_v = 0.0
        self._rise_v = 0.0
        self._gap_v = 0.0
        self._void_s = 0.0
        self._lose_above_mm = spec.lose_above_height_mm
        self._ok_target = False
        self._ok_switch_t = math.inf
        self._ok_bounce_end_t = math.inf
        self._ok_switched = True

    def voltage_at_height_v(self, height_mm: float) -> float:
        """The settled voltage at ``height_mm`` over metal at full feed, without noise: the
        truth an auto-voltage estimate is judged against (benchmarks only)."""
        return self._v0 + self._slope * height_mm

    @property
    def gap_voltage_v(self) -> float:
        """What an old kerf or a void under the tip adds to the voltage now (0 over metal
        once the last gap's spike has decayed): the truth a void lock is judged against."""
        return self._gap_v

    def set_current_a(self, current_a: float) -> None:
        """Cutter current set point; shifts the voltage by ``current_v_per_a`` per amp."""
        self.current_a = current_a
        self._v0 = self._v0_base + self.spec.current_v_per_a * (
            current_a - self.spec.nominal_current_a
        )

    def set_torch(self, on: bool, t_s: float) -> None:
        """Torch relay at simulated time ``t_s`` (the time of the last completed sample)."""
        if on:
            if self.state is not ArcState.OFF:
                return
            rng = self._rng
            spec = self.spec
            self.state = ArcState.PILOT
            self._t_on_s = t_s
            self.pilot_to_transfer_s = rng.uniform(*spec.pilot_to_transfer_s)
            self.arc_ok_delay_s = rng.uniform(*spec.arc_ok_delay_ms) / 1000.0
            self.arc_ok_bounce_s = rng.uniform(*spec.arc_ok_bounce_ms) / 1000.0
            self.voltage_v = spec.open_circuit_v
            return
        if self.state is ArcState.OFF:
            return
        if self.state in _LIVE_STATES:
            self.end_reason = ArcEnd.TORCH_OFF
        self.state = ArcState.OFF
        self.voltage_v = 0.0
        self._open_arc_ok(t_s)

    def lose(self, reason: ArcEnd, t_s: float) -> None:
        """Lose a transferred arc now (the torch stays on, voltage goes open-circuit)."""
        if self.state is not ArcState.TRANSFERRED:
            return
        self.state = ArcState.LOST
        self.end_reason = reason
        self.voltage_v = self.spec.open_circuit_v
        self._open_arc_ok(t_s)

    def _open_arc_ok(self, t_s: float) -> None:
        self._ok_target = False
        if not self.arc_ok and not self._ok_switched:
            # Arc OK had not closed yet: it simply never will.
            self._ok_switch_t = math.inf
            self._ok_switched = True
            return
        self._ok_switch_t = t_s
        self._ok_bounce_end_t = t_s + self._rng.uniform(*self.spec.arc_ok_bounce_ms) / 1000.0
        self._ok_switched = False

    def _transfer(self, t_s: float, speed_target_v: float, height_mm: float) -> None:
        self.state = ArcState.TRANSFERRED
        self._lose_above_mm = max(self.spec.lose_above_height_mm, height_mm)
        self.transfer_t_s = t_s
        self.transfers += 1
        self._transient_v = self.spec.overshoot_v
        self._rise_v = speed_target_v
        self._gap_v = 0.0
        self._void_s = 0.0
        self._ok_target = True
        self._ok_switch_t = t_s + self.arc_ok_delay_s
        self._ok_bounce_end_t = self._ok_switch_t + self.arc_ok_bounce_s
        self._ok_switched = False

    def step(  # noqa: PLR0917 - hot path, once per sample: positional calls are cheapest
        self,
        t_s: float,
        dt_s: float,
        height_mm: float,
        gap_kind: int,
        xy_speed_mm_s: float,
        requested_feed_mm_s: float,
    ) -> None:
        """Advance to simulated time ``t_s`` (the end of this ``dt_s`` sample period)."""
        state = self.state
        if state is ArcState.TRANSFERRED or state is ArcState.PILOT:
            spec = self.spec
            if requested_feed_mm_s > 0.0 and xy_speed_mm_s < requested_feed_mm_s:
                speed_target = spec.rise_v * (1.0 - xy_speed_mm_s / requested_feed_mm_s)
            elif requested_feed_mm_s > 0.0:
                speed_target = 0.0
            else:
                speed_target = spec.rise_v
            if state is ArcState.PILOT:
                since_on = t_s - self._t_on_s
                if (
                    since_on >= self.pilot_to_transfer_s
                    and height_mm <= spec.transfer_max_height_mm
                    and gap_kind == GAP_METAL
                ):
                    self._transfer(t_s, speed_target, height_mm)
                    state = ArcState.TRANSFERRED
                elif since_on >= spec.pilot_timeout_s:
                    self.state = ArcState.NO_TRANSFER
                    self.end_reason = ArcEnd.NO_TRANSFER
                    self.voltage_v = 0.0
            elif height_mm > self._lose_above_mm:
                self.lose(ArcEnd.TOO_HIGH, t_s)
                state = ArcState.LOST
            elif gap_kind == GAP_WIDE:
                self._void_s += dt_s
                if self._void_s * 1000.0 >= spec.void_lose_ms:
                    self.lose(ArcEnd.VOID, t_s)
                    state = ArcState.LOST
            else:
                self._void_s = 0.0
            if state is ArcState.TRANSFERRED:
                if height_mm <= spec.lose_above_height_mm:
                    self._lose_above_mm = spec.lose_above_height_mm
                if dt_s != self._decay_dt:
                    self._decay = math.exp(-dt_s / self._settle_tau_s)
                    self._alpha = 1.0 - math.exp(-dt_s / self._speed_tau_s)
                    self._decay_dt = dt_s
                transient = self._transient_v
                if transient:
                    transient *= self._decay
                    if transient < 1e-3:
                        transient = 0.0
                    self._transient_v = transient
                rise = self._rise_v + (speed_target - self._rise_v) * self._alpha
                self._rise_v = rise
                gap = self._gap_v
                if gap_kind != GAP_METAL:
                    gap = min(spec.kerf_spike_v, gap + spec.kerf_rise_v_per_s * dt_s)
                elif gap:
                    gap = max(0.0, gap - self._fall * dt_s)
                self._gap_v = gap
                self.voltage_v = self._v0 + self._slope * height_mm + transient + rise + gap

        if t_s >= self._ok_switch_t:
            if not self._ok_switched:
                self._ok_switched = True
                self.arc_ok = self._ok_target
            elif t_s < self._ok_bounce_end_t:
                self.arc_ok = self._rng.random() < 0.5
            else:
                self.arc_ok = self._ok_target
                self._ok_switch_t = math.inf


_LIVE_STATES = frozenset({ArcState.PILOT, ArcState.TRANSFERRED, ArcState.LOST})
