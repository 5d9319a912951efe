"""The cut sequence's states, one handler each (STYLE.md 22): what a state does with a
batch of samples, the passing of time (the arc watch, its timer running out), a finished Z
move or probe, and an input edge is read in one class (the state diagram: :mod:`.sequence`).

The handlers hold no state of their own: the cut's data is the sequence's (``CutSequence``),
and the steps they take (``_torch_on``, ``_fault``, ...) are its methods, shared by the
commands. Events every state treats alike (a breakaway, an E-stop, a board fault, the link
going down) are the sequence's, before any handler.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from enum import StrEnum
from typing import TYPE_CHECKING

from firmware_protocol.constants import InputMask

from . import actions as act
from .commands import ThcMode
from .debounce import Edge
from .thc import Lock

if TYPE_CHECKING:
    from .sequence import CutSequence

__all__ = ["HANDLERS", "IN_A_CUT", "State", "StateHandler"]


class State(StrEnum):
    IDLE = "idle"
    TO_PROBE_HEIGHT = "to_probe_height"
    PROBING = "probing"
    CREEP_UP = "creep_up"
    TO_PIERCE = "to_pierce_height"
    ARC_WAIT = "arc_wait"
    RETRY_DELAY = "arc_retry_delay"
    PIERCE_DELAY = "pierce_delay"
    S1_RAISE = "s1_raise"
    S1_WAIT = "s1_wait_cycle_start"
    S1_LOWER = "s1_lower"
    PUDDLE_JUMP = "puddle_jump"
    TO_CUT_HEIGHT = "to_cut_height"
    CUTTING = "cutting"
    PAUSE_AT_END = "pause_at_end"
    TO_SAFE = "to_safe_height"
    FAULTED = "faulted"
    OHMIC_TEST = "ohmic_test"
    Z_MOVE = "program_z_move"
    PROGRAM_PROBE = "program_probe"
    PROBE_TEST = "probe_test"


# From the M3 to the end of the cut: the states a pause ends (invariant 7). A cut's start
# sequence is ended too, lit or not yet: its M3 is answered "paused" and sent again on resume.
IN_A_CUT = frozenset({
    State.TO_PROBE_HEIGHT, State.PROBING, State.CREEP_UP, State.TO_PIERCE, State.ARC_WAIT,
    State.RETRY_DELAY, State.PIERCE_DELAY, State.S1_RAISE, State.S1_WAIT, State.S1_LOWER,
    State.PUDDLE_JUMP, State.TO_CUT_HEIGHT, State.CUTTING, State.PAUSE_AT_END,
})  # fmt: skip

_CONTACT = (InputMask.FLOAT, InputMask.OHMIC)


class StateHandler:
    """A state that ignores every event: the THC filter still follows the voltage."""

    # The torch may be burning: a torch disable (over-cut) puts it out.
    torch_lit = False
    # Float or ohmic contact once the arc was OK is a crash: a fault (invariant 3).
    contact_is_fault = False

    def on_batch(
        self, seq: CutSequence, volts: Sequence[float], period_s: float, dt: float
    ) -> None:
        seq.thc.filter(volts, period_s, seq.now)

    def watch(self, seq: CutSequence, now: float) -> bool:
        """Every batch and tick, before the timer: True when the state was left."""
        return False

    def on_timeout(self, seq: CutSequence) -> None:
        """The timer set on entering ran out."""

    def on_motion_done(self, seq: CutSequence, reached: bool, z_mm: float) -> None:
        """The state's last Z move ended (superseded moves never come here)."""

    def on_probe_done(
        self, seq: CutSequence, contact: bool, ohmic: bool, contact_z_mm: float, stop_z_mm: float
    ) -> None:
        """A board probe ended."""

    def on_edge(self, seq: CutSequence, edge: Edge) -> None:
        if (
            self.contact_is_fault
            and edge.active
            and edge.bit in _CONTACT
            and seq.cut is not None
            and seq.cut.arc_ok_since is not None
        ):
            sensor = "float switch" if edge.bit == InputMask.FLOAT else "ohmic contact"
            seq._fault(f"{sensor} during the cut")


class _MoveMustArrive(StateHandler):
    """A positioning move of the start sequence: stopping short of it is a fault."""

    def on_motion_done(self, seq: CutSequence, reached: bool, z_mm: float) -> None:
        if not reached:
            seq._fault(f"Z move did not complete ({seq.state})")
            return
        self.arrived(seq, z_mm)

    def arrived(self, seq: CutSequence, z_mm: float) -> None:
        raise NotImplementedError


class _Burning(StateHandler):
    """The arc is (or should be) burning: losing it for arc_lost_delay_s is a fault."""

    torch_lit = True
    contact_is_fault = True

    def watch(self, seq: CutSequence, now: float) -> bool:
        cut = seq.cut
        assert cut is not None
        if seq._arc_ok():
            cut.arc_lost_since = None
        elif cut.arc_lost_since is None:
            cut.arc_lost_since = now
        elif now - cut.arc_lost_since >= seq.config.arc_lost_delay_s:
            seq._fault("arc lost", act.PauseCause.ARC_LOST)
            return True
        return False


class _ToProbeHeight(_MoveMustArrive):
    def arrived(self, seq: CutSequence, z_mm: float) -> None:
        ohmic = seq.params.ohmic
        seq._enter(State.PROBING)
        if ohmic:
            seq._emit(act.SwitchOhmicSense(True))
        travel = max(0.5, z_mm - seq.config.z_min_mm)
        seq._emit(act.ProbeZ(seq.params.touch_feed_mm_min / 60.0, travel, ohmic))


class _Probing(StateHandler):
    def on_probe_done(
        self, seq: CutSequence, contact: bool, ohmic: bool, contact_z_mm: float, stop_z_mm: float
    ) -> None:
        cut = seq.cut
        if cut is None:
            return
        cfg = seq.config
        seq._z_mm = stop_z_mm
        if not contact:
            seq._fault("no contact while probing down (plate missing or Z min reached)")
            return
        if seq.params.ohmic and not ohmic and cut.ohmic_failed < cfg.ohmic_retries:
            # Float fired before ohmic: retry ohmic from the start height, then accept float.
            cut.ohmic_failed += 1
            seq._enter(State.TO_PROBE_HEIGHT)
            seq._move(stop_z_mm + cfg.probe_clearance_mm, cfg.setup_speed_mm_s)
            return
        cut.zero_mm = float("nan")
        seq._probe.sensor_ohmic = ohmic
        seq._probe.contact_z_mm = contact_z_mm
        seq._enter(State.CREEP_UP)
        seq._emit(act.SwitchOhmicSense(ohmic))
        seq._move(stop_z_mm + cfg.float_travel_mm + 2.0, cfg.creep_speed_mm_s)


class _CreepUp(StateHandler):
    """Up slowly off the plate until the touch-off sensor releases."""

    def on_edge(self, seq: CutSequence, edge: Edge) -> None:
        if edge.bit in _CONTACT and not edge.active:
            seq._released()

    def on_motion_done(self, seq: CutSequence, reached: bool, z_mm: float) -> None:
        seq._fault("touch-off sensor did not release while creeping up")


class _ToPierce(_MoveMustArrive):
    def arrived(self, seq: CutSequence, z_mm: float) -> None:
        seq._torch_on()


class _ArcWait(StateHandler):
    """Torch on, waiting for arc OK; out of time: off, then another attempt or a fault."""

    torch_lit = True
    contact_is_fault = True

    def watch(self, seq: CutSequence, now: float) -> bool:
        cut = seq.cut
        assert cut is not None
        if not seq._arc_ok():
            return False
        cut.arc_ok_since = now
        seq.pierce_count += 1
        if cut.relay and seq.relay_pierce_delay_s > 0:
            seq._enter(State.PIERCE_DELAY, seq.relay_pierce_delay_s)
        elif cut.relay:
            seq._start_cutting()  # the program does its own pierce delay
        elif cut.relit:
            seq._start_cutting()
        else:
            seq._enter(State.PIERCE_DELAY, seq.params.pierce_delay_ms / 1000.0)
        return True

    def on_timeout(self, seq: CutSequence) -> None:
        cut = seq.cut
        assert cut is not None
        seq._emit(act.SwitchTorch(False))
        if cut.attempts >= seq.config.arc_start_attempts:
            seq._fault(f"no arc OK after {cut.attempts} start attempts")
        else:
            seq._enter(State.RETRY_DELAY, seq.config.arc_retry_delay_s)


class _RetryDelay(StateHandler):
    def on_timeout(self, seq: CutSequence) -> None:
        seq._torch_on()


class _PierceDelay(_Burning):
    def on_timeout(self, seq: CutSequence) -> None:
        seq._after_pierce()


class _S1Raise(StateHandler):
    """G200 S1: torch out, up to safe height, then the sender paused for cleaning."""

    def on_motion_done(self, seq: CutSequence, reached: bool, z_mm: float) -> None:
        seq._enter(State.S1_WAIT)
        seq._emit(
            act.PauseProgram(
                "stop after pierce: clean the surface, then cycle start",
                act.PauseCause.STOP_AFTER_PIERCE,
            )
        )


class _S1Lower(_MoveMustArrive):
    def arrived(self, seq: CutSequence, z_mm: float) -> None:
        cut = seq.cut
        assert cut is not None
        cut.relit = True
        cut.arc_ok_since = None
        seq._torch_on()


class _PuddleJump(_Burning):
    def on_timeout(self, seq: CutSequence) -> None:
        seq._enter(State.TO_CUT_HEIGHT)
        seq._move(seq._cut_z(), seq.config.setup_speed_mm_s)


class _ToCutHeight(_Burning, _MoveMustArrive):
    def arrived(self, seq: CutSequence, z_mm: float) -> None:
        seq._start_cutting()


class _Cutting(_Burning):
    """The THC loop; a relay cut also runs the program's own Z moves (answered here)."""

    def on_batch(
        self, seq: CutSequence, volts: Sequence[float], period_s: float, dt: float
    ) -> None:
        if seq._z_is_programs():
            seq.thc.filter(volts, period_s, seq.now)
        else:
            _thc_step(seq, volts, period_s, dt)

    def on_motion_done(self, seq: CutSequence, reached: bool, z_mm: float) -> None:
        if seq._pending_reply == "Z":
            seq._answer_z_move(reached, z_mm)


class _PauseAtEnd(StateHandler):
    contact_is_fault = True

    def on_timeout(self, seq: CutSequence) -> None:
        seq._end_cut()


class _ToSafe(StateHandler):
    def on_motion_done(self, seq: CutSequence, reached: bool, z_mm: float) -> None:
        seq._enter(State.IDLE)
        seq._reply(True)


class _OhmicTest(StateHandler):
    """Ohmic sense on with the torch in the air for a moment: contact is a shorted torch."""

    def on_edge(self, seq: CutSequence, edge: Edge) -> None:
        if edge.bit == InputMask.OHMIC and edge.active:
            seq._emit(act.SwitchOhmicSense(False))
            seq._fault("ohmic test: contact with the torch in the air (shorted torch?)")

    def on_timeout(self, seq: CutSequence) -> None:
        seq._emit(act.SwitchOhmicSense(False))
        seq._enter(State.IDLE)


class _ZMove(StateHandler):
    """A program's Z move, or a probe test going back: answered when done."""

    def on_motion_done(self, seq: CutSequence, reached: bool, z_mm: float) -> None:
        seq._enter(State.IDLE)
        seq._answer_z_move(reached, z_mm)


class _ProgramProbe(StateHandler):
    def on_probe_done(
        self, seq: CutSequence, contact: bool, ohmic: bool, contact_z_mm: float, stop_z_mm: float
    ) -> None:
        seq._z_mm = stop_z_mm
        if seq.params.ohmic:
            seq._emit(act.SwitchOhmicSense(False))
        seq._enter(State.IDLE)
        if contact or not seq._probe.requires_contact:
            seq._reply(True)
        elif seq._probe.away:
            seq._reply(False, "the sensors never released while probing away (G38.4)")
        else:
            seq._reply(False, "no contact while probing (plate missing or Z min reached)")


class _ProbeTest(StateHandler):
    def on_probe_done(
        self, seq: CutSequence, contact: bool, ohmic: bool, contact_z_mm: float, stop_z_mm: float
    ) -> None:
        seq._z_mm = stop_z_mm
        if seq.params.ohmic:
            seq._emit(act.SwitchOhmicSense(False))
        if contact:
            offset = seq.config.ohmic_offset_mm if ohmic else seq.config.float_travel_mm
            seq.last_zero_mm = contact_z_mm + offset
        else:
            seq._probe.error = "no contact while probing (plate missing or Z min reached)"
        seq._enter(State.Z_MOVE)  # back where it started; answered there
        seq._move(seq._probe.return_z_mm, seq.config.setup_speed_mm_s)


_IDLE = StateHandler()

HANDLERS: Mapping[State, StateHandler] = {
    State.IDLE: _IDLE,
    State.TO_PROBE_HEIGHT: _ToProbeHeight(),
    State.PROBING: _Probing(),
    State.CREEP_UP: _CreepUp(),
    State.TO_PIERCE: _ToPierce(),
    State.ARC_WAIT: _ArcWait(),
    State.RETRY_DELAY: _RetryDelay(),
    State.PIERCE_DELAY: _PierceDelay(),
    State.S1_RAISE: _S1Raise(),
    State.S1_WAIT: _IDLE,  # waits for the cycle-start command
    State.S1_LOWER: _S1Lower(),
    State.PUDDLE_JUMP: _PuddleJump(),
    State.TO_CUT_HEIGHT: _ToCutHeight(),
    State.CUTTING: _Cutting(),
    State.PAUSE_AT_END: _PauseAtEnd(),
    State.TO_SAFE: _ToSafe(),
    State.FAULTED: _IDLE,  # left only by an explicit re-arm (invariant 3)
    State.OHMIC_TEST: _OhmicTest(),
    State.Z_MOVE: _ZMove(),
    State.PROGRAM_PROBE: _ProgramProbe(),
    State.PROBE_TEST: _ProbeTest(),
}


def _thc_step(seq: CutSequence, volts: Sequence[float], period_s: float, dt: float) -> None:
    """One batch of a cut under THC: the target taken (fixed, or measured by auto voltage),
    the THC's locks set for the start transient and a lost arc, a Z velocity out (or a
    fault at the end of Z travel)."""
    cut = seq.cut
    assert cut is not None
    cfg = seq.config
    thc = seq.thc
    now = seq.now
    if seq._xy_speed_mm_s is not None:
        cut.distance_mm += seq._xy_speed_mm_s * dt
    locks = thc.locks(now)
    # Anti-dive off (G200 A0): locks() never holds VELOCITY or NO_SPEED.
    at_speed = Lock.VELOCITY not in locks and Lock.NO_SPEED not in locks
    if not at_speed:
        cut.at_speed_since = None
    elif cut.at_speed_since is None:
        cut.at_speed_since = now
    # The voltage rise of a slow torch decays only some tens of ms after the machine is
    # back at speed: take the target once it has been at speed a little while.
    settled = seq._settled(now)
    # The THC delay guards the start transient, so it counts from arc OK; until it is
    # over the THC may only raise the torch (ThcController.rise_only). A fixed target
    # applies from the start; an auto target is taken as early as the transient allows,
    # before the plate has drifted away from the height that was just probed
    # (dthc_bridge/controller/auto_voltage.py).
    arc_ok_since = cut.arc_ok_since if cut.arc_ok_since is not None else now
    delay_done = seq._delay_done(now)
    arc_lost_running = cut.arc_lost_since is not None or not seq.torch_enabled or cut.torch_out
    fixed_v = seq.params.cut_voltage_v
    if fixed_v is not None and seq.base_v is None:
        seq.base_v = fixed_v  # known from the start: the THC may raise the torch
    since_arc_ok = now - arc_ok_since
    # Past the fixed delay, and past the start transient as the pierce measured it.
    may_measure = (
        since_arc_ok >= cfg.auto_voltage_after_s
        and settled
        and (
            cut.transient.remnant_v(now, cfg.auto_voltage_transient_tau_margin)
            <= cfg.auto_voltage_max_transient_v
            or since_arc_ok >= cfg.auto_voltage_max_wait_s
        )
    )
    thc.frozen = seq.base_v is None or arc_lost_running or not delay_done
    thc.rise_only = not arc_lost_running and not delay_done
    if seq.base_v is None:
        # Auto voltage, no target yet: Z holds at cut height while it is measured.
        thc.filter(volts, period_s, now)
        if may_measure:
            seq._measure_cut_height_v(now)
        if seq.base_v is not None:
            thc.frozen = arc_lost_running or not delay_done
        velocity = 0.0
    else:
        if may_measure:
            seq._measure_cut_height_v(now)  # a refined target applies from this batch on
        if seq.mode is ThcMode.ARC_OK_AND_UPDOWN:
            thc.filter(volts, period_s, now)
            velocity = _updown_velocity(seq)
        else:
            velocity = thc.update(volts, period_s, now, dt).velocity_mm_s
        offset = _window_offset_mm(seq)
        if offset is not None:  # the height window: a breach ends the cut, else a limit
            window = seq.height_window()
            reason = window.breach(offset, velocity)
            if reason is not None:
                seq._fault(reason)
                return
            velocity = window.limit(velocity, offset, dt, thc.config.max_accel_mm_s2)
    z_next = seq._z_mm + velocity * dt
    if velocity < 0 and z_next <= cfg.z_min_mm:
        seq._fault("Z min limit reached during THC")
        return
    if velocity > 0 and z_next >= cfg.z_max_mm - cfg.top_margin_mm:
        seq._fault("Z max limit reached during THC")
        return
    cut.thc_lift_mm = max(cut.thc_lift_mm, seq._z_mm - seq._cut_z())
    seq._emit(act.SetZVelocity(velocity))


def _window_offset_mm(seq: CutSequence) -> float | None:
    """The torch's height over cut height by the arc, while the THC drives Z, else None."""
    cut = seq.cut
    thc = seq.thc
    voltage = thc.filtered_v
    if cut is None or cut.cut_height_v is None or voltage is None or math.isnan(cut.start_z_mm):
        return None  # not measured yet, or a relay cut (no cut height of ours)
    if not seq.thc_enabled or thc.frozen or thc.held:
        return None
    # The window is around the cut height in force: the operator's offset and height
    # override move it with the target.
    return seq.height_window().offset_mm(voltage, cut.cut_height_v + seq._override_v())


def _updown_velocity(seq: CutSequence) -> float:
    """Mode 2: the cutter's up/down inputs move Z at a constant speed."""
    if not seq.thc_enabled or seq.thc.frozen:
        return 0.0
    locks = seq.thc.locks(seq.now)
    if Lock.VELOCITY in locks or Lock.NO_SPEED in locks:
        return 0.0
    speed = seq.config.thc_updown_speed_mm_s
    if seq.inputs & InputMask.THC_UP:
        return speed
    if seq.inputs & InputMask.THC_DOWN:
        return -speed
    return 0.0
