"""The plasma cut sequence: one state machine, events and a clock in, actions out.

    IDLE -M3-> TO_PROBE_HEIGHT -> PROBING -> CREEP_UP -> TO_PIERCE -> ARC_WAIT
      -> PIERCE_DELAY -> [S1: S1_RAISE -> S1_WAIT -(cycle start)-> S1_LOWER -> ARC_WAIT]
      -> [PUDDLE_JUMP] -> TO_CUT_HEIGHT -> CUTTING -M5-> [PAUSE_AT_END] -> TO_SAFE -> IDLE

A relay cut (relay dialect, MASSO legacy mode) is only IDLE -M3-> ARC_WAIT -> CUTTING -M5->
IDLE: the program probes (PROGRAM_PROBE), sets its Z origin and moves Z itself (Z_MOVE, or
a move inside the relay cut), and the THC acts only while the program has it switched on.

Every fault while the torch may be lit (arc lost, breakaway, float/ohmic contact after arc
OK, Z limit, board fault, link down) ends in FAULTED: torch off, the sender told to pause,
Z to safe height, touch-off required next time. FAULTED leaves only on an explicit re-arm
(docs/DESIGN.md invariant 3). No I/O here: the driver executes the actions and reports back.

What each state does with the board's events and with time is its handler's
(:mod:`.states`); here: the commands (each one method, which owns its guard and raises
:class:`CommandError` when refused), the events every state treats alike, and the steps the
handlers and commands share. The target voltage is derived (:attr:`CutSequence.target_v`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from firmware_protocol.constants import InputMask

from . import actions as act
from .auto_voltage import AutoVoltage, FitLimits
from .commands import (
    CommandError,
    CutParams,
    ProbeAndStart,
    ProbeSurface,
    ProgramZMove,
    SetWorkZ,
    ThcMode,
)
from .debounce import Edge, InputDebouncer
from .height_window import HeightWindow
from .start_transient import StartTransient, refit_decay
from .states import HANDLERS, IN_A_CUT, State, StateHandler
from .thc import Lock, ThcController

__all__ = ["IN_A_CUT", "CutSequence", "SequenceConfig", "State"]

_Z_UNKNOWN = "the torch's Z is not known yet (is the board online?)"


@dataclass(frozen=True)
class SequenceConfig:
    z_min_mm: float = 0.0
    z_max_mm: float = 100.0
    top_margin_mm: float = 5.0  # THC and safe height stay this far below the top of travel
    setup_speed_mm_s: float = 40.0
    probe_height_mm: float = 25.0  # first probe starts here above Z min (slats + plate)
    probe_clearance_mm: float = 5.0  # later probes start this far above the last surface
    creep_speed_mm_s: float = 1.0
    float_travel_mm: float = 1.5
    ohmic_offset_mm: float = 0.0
    ohmic_retries: int = 1  # then fall back to the float switch
    arc_ok_timeout_s: float = 3.0
    arc_start_attempts: int = 3
    arc_retry_delay_s: float = 1.0
    input_debounce_s: float = 0.005
    arc_lost_delay_s: float = 0.02
    thc_delay_s: float = 1.0  # from arc OK: the start transient settles within it
    safe_height_mm: float = 20.0  # above the surface
    pause_at_end_s: float = 0.0
    puddle_height_percent: float = 100.0  # of pierce height; 100 = no puddle jump
    puddle_delay_s: float = 0.0
    ihs_skip_distance_mm: float = 0.0  # 0: always touch off
    ihs_skip_type: int = 0  # 0: from the end of the last cut (THC on), 1: from its start
    # Auto voltage: the mean filtered voltage over this window, taken as soon as the machine
    # is at speed (and at least auto_voltage_after_s after arc OK), not after the THC delay.
    auto_voltage_window_s: float = 0.05
    auto_voltage_fit_window_s: float = 0.3
    auto_voltage_after_s: float = 0.5  # from arc OK: past the start transient's peak
    # Then, auto_voltage_fit_window_s from the window's start, the target is corrected once:
    # the voltages since the window began, less what the THC moved Z from cut height (what
    # a held torch would read), are fitted against the distance cut (V = a + b * d) and
    # the target becomes a, the voltage where XY started over the probed point at cut
    # height, so a plate drifting linearly under the held torch leaves the target. The
    # mean is kept when the fit's plate slope exceeds auto_voltage_max_plate_slope (mm per
    # mm), the samples span less than auto_voltage_min_span_mm, scatter beyond
    # auto_voltage_max_residual_v, or the two halves' slopes differ by more than
    # auto_voltage_max_slope_change (not a line: a start transient still decaying).
    auto_voltage_fit: bool = True
    auto_voltage_max_plate_slope: float = 0.02
    auto_voltage_min_span_mm: float = 1.0
    auto_voltage_max_residual_v: float = 1.0
    auto_voltage_max_slope_change: float = 0.05  # V/mm, first half - second half
    # ...and where the fitted slope is within this many standard errors of 0 (a flat
    # plate), the mean of all those voltages: the line's value at 0 is a few times noisier.
    # 5, not 2: the standard error takes the batches as independent, but the 40 Hz filter
    # makes neighbours share noise, and a small hole's window is short: at 1300 mm/min
    # 6.6 mm, 15-25 mm in. At 2, 6 % of such windows over a flat plate gave a slope
    # (extrapolated 0.3 V and more off; at 3, 1.5 %); in programs, a hole 0.6 V low at
    # t 2.2 and one 0.77 V high at t 3.7 (tests/sim/test_auto_voltage_program.py). The
    # warped plates' slopes stand at t 10 and more; a warped plate's small hole loses its
    # slope (t 3-4, 0.3 V) to the mean.
    auto_voltage_min_slope_t: float = 5.0
    auto_voltage_min_slope_v_per_mm: float = 0.025  # 0.33 % of plate slope at 7.5 V/mm
    # ...and there (or where the fit through the start transient found no slope) the
    # window goes on to auto_voltage_flat_window_s from its start: if the plate is still
    # flat over all of it, the target becomes the same fit over all of it (a held torch
    # over a flat plate reads the same voltage all along: less noise, measured in
    # docs/benchmarks.md). At most auto_voltage_fit_window_s: off.
    auto_voltage_flat_window_s: float = 2.0
    # The start transient, measured over the pierce delay (controller/start_transient.py):
    # measuring waits until what is left of it is below auto_voltage_max_transient_v (at
    # most auto_voltage_max_wait_s from arc OK), and what is left is subtracted.
    auto_voltage_max_transient_v: float = 0.3
    auto_voltage_max_wait_s: float = 2.0
    auto_voltage_transient_tau_margin: float = 1.5  # the wait uses 1.5 x the fitted tau
    at_speed_settle_s: float = 0.15
    # Once the THC delay is over the THC holds the target plus what is left of the start
    # transient, as the pierce and the delay's voltages show it together
    # (start_transient.refit_decay): a decaying overshoot is the arc's, not a torch too high.
    thc_discounts_transient: bool = True
    # The THC's height window (controller/height_window.py): the THC never takes the torch
    # more than this far below cut height, nor above it (toward the arc-loss height, 6-8 mm
    # stand-off), by the arc voltage against the voltage measured at cut height; reaching
    # an edge ends the cut through the fault path. 1 mm below a 1.5 mm cut height leaves
    # 0.5 mm above the plate; 4 mm above stays under the arc loss and over a kerf's rise.
    thc_window_below_mm: float = 1.0
    thc_window_above_mm: float = 4.0
    dry_run: bool = False
    # Mode 0 (arc OK from voltage): window and agreement, docs/plasma-facts.md
    arc_ok_low_v: float = 60.0
    arc_ok_high_v: float = 250.0
    arc_ok_agree_v: float = 10.0
    thc_updown_speed_mm_s: float = 5.0  # mode 2: constant Z speed while up/down is asserted


@dataclass
class _Cut:
    zero_mm: float  # surface, in carriage Z
    start_xy: tuple[float, float] | None
    attempts: int = 0
    arc_ok_since: float | None = None
    arc_lost_since: float | None = None
    at_speed_since: float | None = None
    thc_lift_mm: float = 0.0  # how far THC raised the torch above the cut datum
    # The voltage at cut height over the probed point, measured on every cut (the auto
    # target, and the height window's reference under a G200 V voltage).
    auto_voltage: AutoVoltage | None = None
    cut_height_v: float | None = None  # its estimate, once taken
    transient: StartTransient = field(default_factory=StartTransient)  # fitted at CUTTING
    start_z_mm: float = math.nan  # Z when CUTTING began at cut height (NaN: a relay cut)
    distance_mm: float = 0.0  # XY travel since the cut started (from the probed point)
    relit: bool = False
    # The start transient's tail during the THC delay (a held torch's voltage), and the
    # decay fitted through it and the pierce: (overshoot, tau) for the THC, or None.
    tail_times_s: list[float] = field(default_factory=list)
    tail_volts: list[float] = field(default_factory=list)
    tail_fitted: bool = False
    tail_decay: tuple[float, float] | None = None
    ohmic_failed: int = 0
    relay: bool = False  # the program does the start sequence; M3 is the torch relay
    z_warned: bool = False  # a program Z move was ignored during this cut (warned once)
    torch_out: bool = False  # put out by a torch disable (over-cut): stays out until M5


@dataclass
class _ProbeRun:
    """The last probe (a touch-off, the program's, the operator's test): what its end needs."""

    sensor_ohmic: bool = False  # a touch-off's sensor: creep up until it releases
    contact_z_mm: float = math.nan  # where the sensor fired
    requires_contact: bool = True  # the program's G38.2/G38.4 (G38.3/G38.5: no error)
    away: bool = False  # the program's probe runs up (G38.4/G38.5)
    return_z_mm: float = math.nan  # a probe test goes back to this Z
    error: str = ""  # a probe test without contact: the answer once back


class CutSequence:
    def __init__(
        self, config: SequenceConfig | None = None, thc: ThcController | None = None
    ) -> None:
        self.config = config or SequenceConfig()
        self.thc = thc or ThcController()
        self.params = CutParams()
        self.g200_active = True  # MASSO power-on default
        self.relay_pierce_delay_s = 0.0  # a tube material's pierce delay (program_positions)
        self.plasma_mode = False
        self.mode = ThcMode.ARC_OK_AND_VOLTAGE
        self.thc_enabled = False  # M667 turns it on
        self.thc_z_feed_mm_min: float | None = None
        self.voltage_offset_v = 0.0  # torch up / torch down
        # PlasmaC's height override: the cut height raised (+) or lowered, as a change of the
        # target voltage through the THC slope; kept from cut to cut until the program ends.
        self.height_override_mm = 0.0
        self._base_v: float | None = None  # the cut's voltage (G200 V, or auto), see target_v
        self.state = State.IDLE
        self.cut: _Cut | None = None
        self.last_zero_mm: float | None = None
        self.last_cut_end_xy: tuple[float, float] | None = None
        self.last_cut_start_xy: tuple[float, float] | None = None
        self.last_thc_active = False
        self.probe_required = True
        self.error = ""
        self.now = 0.0
        self._timer: float | None = None
        self._debouncer = InputDebouncer()
        self._z_mm = math.nan
        # Z at the ohmic input's last raw change (the board's input-change event carries Z
        # at that moment): a creep up's release point, a debounce before it is confirmed.
        self._ohmic_changed_z_mm = math.nan
        self._requested_mm_s: float | None = None
        self._xy_speed_mm_s: float | None = None
        self._last_thc_t: float | None = None
        self._voltages: deque[float] = deque(maxlen=10)
        self._actions: list[act.Action] = []
        self._move_token = 0
        self._probe = _ProbeRun()
        self._pending_reply: str | None = None
        self.safe_z_mm = self.config.z_max_mm - self.config.top_margin_mm
        self.warnings: list[str] = []
        self.pierce_count = 0
        self.torch_enabled = True  # PlasmaC M62/M64 P3 disable it (hole over-cut)
        self.work_origin_mm: float | None = None  # machine Z of work Z 0 (G92, G10 L20)
        # Why a torch start is refused until Z is homed ("": it is not), set by the
        # service: while the board homes, and unhomed when [board.homing] requires it.
        self.unhomed = ""
        self.homing = False  # the board is homing Z: no command may move Z meanwhile

    # --- plumbing --------------------------------------------------------------------------

    def drain(self) -> list[act.Action]:
        out, self._actions = self._actions, []
        return out

    def _emit(self, *actions: act.Action) -> None:
        self._actions.extend(actions)

    def _move(self, target_mm: float, feed_mm_s: float) -> None:
        self._move_token += 1
        self._emit(act.MoveZ(target_mm, feed_mm_s, self._move_token))

    def _reply(self, ok: bool, error: str = "") -> None:
        if self._pending_reply is not None:
            self._emit(act.CommandReply(self._pending_reply, ok, error))
            self._pending_reply = None

    def _enter(self, state: State, timer_s: float | None = None) -> None:
        self.state = state
        self._timer = None if timer_s is None else self.now + timer_s

    @property
    def _handler(self) -> StateHandler:
        return HANDLERS[self.state]

    @property
    def busy(self) -> bool:
        return self.state not in (State.IDLE, State.FAULTED)

    @property
    def inputs(self) -> int:
        """The debounced inputs (InputMask bits)."""
        return self._debouncer.stable

    def require_idle(self, word: str) -> None:
        """The guard of every command that may not run during a cut."""
        if self.busy:
            raise CommandError(word, f"not during a cut ({self.state})")

    def _require_armed(self, word: str) -> None:
        if self.state is State.FAULTED:
            raise CommandError(word, f"re-arm required after: {self.error}")
        if self.homing:
            # A Z command would end the board's homing cycle (ABORTED), unhomed.
            raise CommandError(word, "Z is homing: wait until it has found its home switch")

    def snapshot(self) -> dict[str, Any]:
        p = self.params
        surface = self.surface_mm
        return {
            "state": str(self.state),
            "mode": int(self.mode),
            "plasma_mode": self.plasma_mode,
            "unhomed": self.unhomed,
            "g200_active": self.g200_active,
            "thc_enabled": self.thc_enabled,
            "target_v": self.target_v,
            "height_override_mm": self.height_override_mm,
            "slow_target_v": self.thc.slow_target_v,
            "voltage_v": self.thc.filtered_v,
            "z_mm": None if math.isnan(self._z_mm) else round(self._z_mm, 3),
            "height_mm": (  # above the plate (surface_mm)
                None if surface is None or math.isnan(self._z_mm)
                else round(self._z_mm - surface, 3)
            ),
            "locks": sorted(str(lock) for lock in self.thc.locks(self.now)),
            "probe_required": self.probe_required,
            "torch_enabled": self.torch_enabled,
            "work_z_mm": (
                None if math.isnan(self._z_mm) else round(self._z_mm - self.work_zero_mm, 3)
            ),
            "error": self.error,
            "params": {
                "touch_feed_mm_min": p.touch_feed_mm_min, "pierce_height_mm": p.pierce_height_mm,
                "pierce_delay_ms": p.pierce_delay_ms, "cut_height_mm": p.cut_height_mm,
                "cut_voltage_v": p.cut_voltage_v, "anti_dive_percent": p.anti_dive_percent,
                "ohmic": p.ohmic, "stop_after_pierce": p.stop_after_pierce,
            },
        }  # fmt: skip

    # --- the target voltage ----------------------------------------------------------------

    @property
    def base_v(self) -> float | None:
        """The cut's own voltage: G200 V, or what auto voltage measured; None until known."""
        return self._base_v

    @base_v.setter
    def base_v(self, volts: float | None) -> None:
        self._base_v = volts
        self._apply_target()

    @property
    def target_v(self) -> float | None:
        """The voltage the THC holds: the cut's own voltage, plus the operator's offset
        (torch up/down) and the height override through the THC slope."""
        if self._base_v is None:
            return None
        return self._base_v + self._override_v()

    def _override_v(self) -> float:
        return self.voltage_offset_v + self.height_override_mm * self.thc.config.slope_v_per_mm

    def _apply_target(self) -> None:
        """The one place the THC's target is written."""
        self.thc.target_v = self.target_v

    def _reset_thc(self) -> None:
        """The THC starts afresh, the target with it (taken again for this cut)."""
        self.thc.reset()
        self.base_v = None

    # --- commands from the sender ----------------------------------------------------------

    def set_params(self, params: CutParams) -> None:
        """G200 and its kin: takes effect at the next cut."""
        self.params = params
        self.g200_active = True
        self.relay_pierce_delay_s = 0.0
        self.thc.anti_dive_percent = params.anti_dive_percent

    def set_cut_voltage(self, volts: float | None) -> None:
        """A fixed cut voltage, or None for auto voltage."""
        self.set_params(replace(self.params, cut_voltage_v=volts))

    def program_positions(self, pierce_delay_s: float, word: str) -> None:
        """A material that positions nothing (QtPlasmaC's tube cutting): cuts start as the
        program's own (it probes and sets Z), with this pierce delay before M3 is answered."""
        self.require_idle(word)
        self.g200_active = False
        self.relay_pierce_delay_s = pierce_delay_s

    def set_material_timing(
        self, pause_at_end_s: float, puddle_height_percent: float, puddle_delay_s: float
    ) -> None:
        """A material's pause at the end of a cut and puddle jump."""
        self.config = replace(
            self.config,
            pause_at_end_s=pause_at_end_s,
            puddle_height_percent=puddle_height_percent,
            puddle_delay_s=puddle_delay_s,
        )

    def set_probe_and_start(self, p6: ProbeAndStart) -> bool:
        """Everything ``G100 P6`` sets before its start sequence; False for the special
        modes I2/I3, which only (re)set the values and start nothing."""
        self.set_params(
            replace(
                self.params,
                touch_feed_mm_min=p6.touch_feed_mm_min,
                pierce_height_mm=p6.pierce_height_mm,
                pierce_delay_ms=p6.pierce_delay_s * 1000.0,
                cut_height_mm=p6.cut_height_mm,
            )
        )
        if p6.mode in (2, 3):  # special modes: only (re)set the values the PLC shows
            return False
        self.config = replace(self.config, arc_ok_timeout_s=p6.arc_ok_timeout_s)
        # RosettaCNC has no T112 M6: P6 itself says the plasma tool is active.
        self.plasma_mode = True
        # I0: THC armed but its comparator stays off until G100 P7 A1; I1: no THC.
        self.set_thc(False)
        return True

    def set_plasma_mode(self, enabled: bool, word: str) -> None:
        if self.busy and not enabled:
            raise CommandError(word, "cannot leave plasma mode during a cut")
        self.plasma_mode = enabled

    def legacy_mode(self) -> None:
        """MASSO's bare G200: the program does its own start sequence from now on."""
        if self.busy:
            raise CommandError("G200", "cannot switch to legacy mode during a cut")
        self.g200_active = False

    def set_operating_mode(self, mode: ThcMode) -> None:
        if self.busy:
            raise CommandError("operating_mode", "cannot change the mode during a cut")
        self.mode = mode

    def begin_program(self) -> None:
        """A program starts: the torch enabled, no work Z origin, no height override."""
        self.torch_enabled = True
        self.work_origin_mm = None
        self.override_height(0.0)  # the last program's override ends with it

    def set_thc(self, enabled: bool, z_feed_mm_min: float | None = None) -> None:
        if enabled and not self.thc_enabled and self.in_relay_cut:
            # A relay program switches the THC on at its cut height: the target is taken
            # afresh, once the THC delay has passed from now.
            assert self.cut is not None
            self._reset_thc()
            self.cut.arc_ok_since = self.now
            self.cut.at_speed_since = None
            self._last_thc_t = None
        self.thc_enabled = enabled
        if z_feed_mm_min is not None:
            self.thc_z_feed_mm_min = z_feed_mm_min  # remembered until overwritten
        self.thc.set_speed_limit(self.thc_z_feed_mm_min)
        self.thc.enabled = enabled

    def hold_thc(self, now: float, on: bool) -> bool:
        """The operator's pause holds Z; a lit cut is ended (docs/DESIGN.md invariant 7),
        whoever asks. True when a cut was ended."""
        self.thc.held = on
        return on and self.pause(now, "paused by the operator")

    def request_current(self, current_a: float) -> None:
        """Plasma current set point (analog output): passed to the board as it comes."""
        self._emit(act.ApplyCurrent(current_a))

    def override_height(self, height_mm: float) -> None:
        """Set the height override (step_height_override checks its bounds); a cut at
        height follows the new target at once."""
        self.height_override_mm = height_mm
        self._apply_target()

    def step_height_override(self, step_mm: float, reset: bool) -> float:
        """PlasmaC's height override, by a step or back to 0, within half the cut height;
        the new override."""
        height = 0.0 if reset else round(self.height_override_mm + step_mm, 1)
        bound = self.params.cut_height_mm / 2.0
        if abs(height) > bound + 1e-9:
            raise CommandError(
                "height_override mm",
                f"{height:+.1f} mm is beyond half the cut height (±{bound:.2f} mm)",
            )
        self.override_height(height)
        return height

    def adjust_voltage(self, delta_v: float) -> None:
        """Torch up / torch down: the offset stays until the next M3."""
        self.voltage_offset_v += delta_v
        self._apply_target()

    def start(
        self, now: float, xy_mm: tuple[float, float] | None = None, *, relay: bool = False
    ) -> None:
        """M3. Answered (CommandReply) when XY motion may start, or with the error.

        ``relay`` (or MASSO legacy mode): no automatic sequence, the torch relay only."""
        self.now = now
        self._pending_reply = "M3"
        if self.state is State.FAULTED:
            self._reply(False, f"re-arm required after: {self.error}")
            return
        if self.busy:
            self._reply(False, f"a cut is already running ({self.state})")
            return
        if self.unhomed:
            self._reply(False, self.unhomed)
            return
        if not self.plasma_mode and not relay:
            self._reply(False, "not in plasma mode: send T112 M6 first")
            return
        if self.inputs & (InputMask.OHMIC | InputMask.FLOAT | InputMask.BREAKAWAY):
            self._fault("float, ohmic or breakaway active before the torch start")
            return
        self.error = ""
        self.voltage_offset_v = 0.0
        self._reset_thc()
        if relay or not self.g200_active:
            # The program did its own probe and Z moves: the torch relay, and the THC if the
            # program switches it on. The work Z origin is the cut's datum.
            self.cut = self._new_cut(self.work_zero_mm, xy_mm, relay=True)
            self._torch_on()
            return
        if self._may_skip_probe(xy_mm):
            assert self.last_zero_mm is not None
            self.cut = self._new_cut(self.last_zero_mm, xy_mm)
            self._to_pierce()
            return
        cfg = self.config
        start_z = (
            self.last_zero_mm + cfg.probe_clearance_mm
            if self.last_zero_mm is not None
            else cfg.z_min_mm + cfg.probe_height_mm
        )
        start_z = min(start_z, self.safe_z_mm)
        self.cut = self._new_cut(math.nan, xy_mm)
        self._enter(State.TO_PROBE_HEIGHT)
        self._move(start_z, cfg.setup_speed_mm_s)

    def _new_cut(
        self, zero_mm: float, xy_mm: tuple[float, float] | None, *, relay: bool = False
    ) -> _Cut:
        cfg = self.config
        limits = FitLimits(
            max_plate_slope_v_per_mm=(
                cfg.auto_voltage_max_plate_slope * self.thc.config.slope_v_per_mm
            ),
            min_span_mm=cfg.auto_voltage_min_span_mm,
            max_residual_v=cfg.auto_voltage_max_residual_v,
            max_slope_change_v_per_mm=cfg.auto_voltage_max_slope_change,
            min_slope_t=cfg.auto_voltage_min_slope_t,
            min_slope_v_per_mm=cfg.auto_voltage_min_slope_v_per_mm,
        )
        auto = AutoVoltage(
            window_s=cfg.auto_voltage_window_s,
            fit_window_s=cfg.auto_voltage_fit_window_s,
            limits=limits if cfg.auto_voltage_fit else None,
            flat_window_s=cfg.auto_voltage_flat_window_s,
        )
        return _Cut(zero_mm, start_xy=xy_mm, relay=relay, auto_voltage=auto)

    def _may_skip_probe(self, xy_mm: tuple[float, float] | None) -> bool:
        cfg = self.config
        if cfg.ihs_skip_distance_mm <= 0 or self.probe_required or self.last_zero_mm is None:
            return False
        ref = self.last_cut_start_xy if cfg.ihs_skip_type == 1 else self.last_cut_end_xy
        if ref is None or xy_mm is None:
            return False
        if cfg.ihs_skip_type == 0 and not self.last_thc_active:
            ref = self.last_cut_start_xy  # PlasmaC: from the probe point when THC was off
            if ref is None:
                return False
        return math.dist(ref, xy_mm) < cfg.ihs_skip_distance_mm

    def stop(self, now: float, xy_mm: tuple[float, float] | None = None) -> None:
        """M5: torch off (after the optional pause at end), then safe height; then answered."""
        self.now = now
        self._pending_reply = "M5"
        if self.state is State.FAULTED or not self.busy:
            self._emit(act.SwitchTorch(False))
            self._reply(True)
            return
        self.last_cut_end_xy = xy_mm
        if self.state is State.CUTTING and self.config.pause_at_end_s > 0:
            self._enter(State.PAUSE_AT_END, self.config.pause_at_end_s)
            return
        self._end_cut()

    def cycle_start(self, now: float) -> None:
        """After a stop after pierce (G200 S1): down to cut height and relight."""
        if self.state is not State.S1_WAIT:
            raise CommandError("cycle_start", f"nothing waits for cycle start ({self.state})")
        self.now = now
        self._enter(State.S1_LOWER)
        self._move(self._cut_z(), self.config.setup_speed_mm_s)

    def rearm(self, now: float) -> None:
        """Leave FAULTED explicitly (the operator has seen the error, which is then cleared);
        touch-off will follow."""
        if self.state is not State.FAULTED:
            raise CommandError("rearm", f"nothing to re-arm ({self.state})")
        self.now = now
        self._emit(act.ResetFaults())
        self._enter(State.IDLE)
        self.probe_required = True
        self.error = ""

    def pause(self, now: float, reason: str) -> bool:
        """The operator paused the program (docs/DESIGN.md invariant 7): a cut, lit or in its
        start sequence, ends now: torch off, Z held then raised to safe height, the sender
        told to pause (every sender holds its motion); its waiting M3 is answered with the
        reason. Not a fault: nothing to re-arm. The resume touches off again where the
        torch then stands. False (nothing done) when no cut runs."""
        self.now = now
        if self.state not in IN_A_CUT:
            return False
        if self.cut is not None and self.state is State.CUTTING:
            self.last_thc_active = self.thc_enabled and self.target_v is not None
        self.probe_required = True
        self._enter(State.TO_SAFE)
        self._torch_out_and_raise()
        self._reply(False, f"paused: {reason}")
        self._emit(act.PauseProgram(reason, act.PauseCause.OPERATOR))
        return True

    def probe_test(self, now: float) -> None:
        """The operator's probe test, idle: touch off where the torch stands (the cut's
        sensors and feed), then back to the Z it started from; the surface found becomes
        the plate's. Answered (CommandReply) once back."""
        self._require_armed("probe_test")
        self.require_idle("probe_test")
        self.now = now
        if math.isnan(self._z_mm):
            raise CommandError("probe_test", _Z_UNKNOWN)
        travel = self._z_mm - self.config.z_min_mm
        if travel <= 0.5:
            raise CommandError("probe_test", "the torch is at the bottom of its travel")
        self._probe.return_z_mm = self._z_mm
        self._probe.error = ""
        self._pending_reply = "probe_test"
        self._enter(State.PROBE_TEST)
        ohmic = self.params.ohmic
        if ohmic:
            self._emit(act.SwitchOhmicSense(True))
        self._emit(act.ProbeZ(self.params.touch_feed_mm_min / 60.0, travel, ohmic))

    def jog_z(self, now: float, mm: float, feed_mm_min: float | None) -> None:
        """The operator's Z jog, idle: ``mm`` from where Z is (inside the travel); answered
        when done."""
        self._require_armed("jog_z")
        self.require_idle("jog_z")
        if math.isnan(self._z_mm):
            raise CommandError("jog_z", _Z_UNKNOWN)
        self._probe.error = ""
        self._move_z(now, self._z_mm + mm, self._feed_mm_s(feed_mm_min))

    def ohmic_test(self, now: float) -> None:
        """Ohmic sense on with the torch in the air: contact means a shorted torch."""
        self._require_armed("ohmic_test")
        self.require_idle("ohmic_test")
        self.now = now
        self._emit(act.SwitchOhmicSense(True))
        self._enter(State.OHMIC_TEST, 0.1)

    @property
    def work_zero_mm(self) -> float:
        """Machine Z of work Z 0: the program's origin (G92, G10 L20), else the last probed
        surface, else the highest the surface may be (``probe_height_mm`` above Z min, where
        the first probe starts): with the surface unknown, a program's Z never goes lower."""
        if self.work_origin_mm is not None:
            return self.work_origin_mm
        if self.last_zero_mm is not None:
            return self.last_zero_mm
        return self.config.z_min_mm + self.config.probe_height_mm

    @property
    def surface_mm(self) -> float | None:
        """Machine Z of the plate under the torch: the surface this cut probed (or its datum),
        else the last one probed; None before any touch-off."""
        cut = self.cut
        if cut is not None and not math.isnan(cut.zero_mm):
            return cut.zero_mm
        return self.last_zero_mm

    @property
    def in_relay_cut(self) -> bool:
        return self.cut is not None and self.cut.relay and self.state is State.CUTTING

    def _feed_mm_s(self, feed_mm_min: float | None) -> float:
        """A program's or the operator's Z feed, never above the setup speed."""
        setup = self.config.setup_speed_mm_s
        return setup if feed_mm_min is None else min(feed_mm_min / 60.0, setup)

    def program_z_move(self, now: float, command: ProgramZMove) -> str | None:
        """A program's Z word (work Z, or machine Z with G53): answered (CommandReply "Z")
        when done. Returns why it was ignored instead: during an automatic cut (PlasmaC
        strips them), or while the THC holds the height of a relay cut; warned once per
        cut."""
        self._require_armed("Z")
        target = command.z_mm if command.machine else self.work_zero_mm + command.z_mm
        return self._move_z(now, target, self._feed_mm_s(command.feed_mm_min))

    def _move_z(self, now: float, target_mm: float, feed_mm_s: float) -> str | None:
        self.now = now
        cut = self.cut
        if self.busy and not (self.in_relay_cut and not self.thc_enabled):
            reason = f"Z move ignored during the cut ({self.state})"
            if cut is not None and not cut.z_warned:
                cut.z_warned = True
                self.warnings.append(reason)
            return reason
        cfg = self.config
        top = cfg.z_max_mm - cfg.top_margin_mm
        clamped = min(max(target_mm, cfg.z_min_mm), top)
        if clamped != target_mm:
            self.warnings.append(f"Z {target_mm:.3f} outside travel: moved to {clamped:.3f}")
        self._pending_reply = "Z"
        if self.state is State.IDLE:
            self._enter(State.Z_MOVE)
        self._move(clamped, feed_mm_s)
        return None

    def probe_surface(self, now: float, command: ProbeSurface) -> None:
        """The program's own probe (G38.2/G38.3) to work Z ``command.z_mm``: the board
        probes down with the touch-off sensors and stops on contact; ``away`` (G38.4/G38.5):
        up until they release. Answered (CommandReply "probe") with the outcome."""
        word = "G38.2"
        if command.away:
            word = "G38.4" if command.require_contact else "G38.5"
        self._require_armed(word)
        self.require_idle(word)
        self.now = now
        self._pending_reply = "probe"
        target_mm = self.work_zero_mm + command.z_mm
        away = command.away
        if away:
            top = self.config.z_max_mm - self.config.top_margin_mm
            travel = min(target_mm, top) - self._z_mm
            where = "above"
        else:
            travel = self._z_mm - max(target_mm, self.config.z_min_mm)
            where = "below"
        if math.isnan(travel) or travel <= 0:
            self._reply(False, f"probe target {target_mm:.3f} is not {where} the torch")
            return
        if away and not self.inputs & (InputMask.FLOAT | InputMask.OHMIC):
            # As LinuxCNC: a probe away must start in contact, or it could never release.
            self._reply(False, "the touch-off sensors are already released: nothing to probe "
                        "away from (G38.4/G38.5 start in contact)")  # fmt: skip
            return
        self._probe.requires_contact = command.require_contact
        self._probe.away = away
        self._enter(State.PROGRAM_PROBE)
        ohmic = self.params.ohmic
        if ohmic:
            self._emit(act.SwitchOhmicSense(True))
        self._emit(act.ProbeZ(command.feed_mm_min / 60.0, travel, ohmic, away=away))

    def set_work_z(self, command: SetWorkZ) -> float:
        """G92 Z / G10 L20 Z: the current Z reads ``z_mm``; None (G92.1) clears the origin.
        The machine Z of work Z 0 after it."""
        word = "G92 Z"
        self._require_armed(word)
        if self.busy and not self.in_relay_cut:
            raise CommandError(word, f"not during a cut ({self.state})")
        if command.z_mm is None:
            self.work_origin_mm = None
        elif math.isnan(self._z_mm):
            raise CommandError(word, _Z_UNKNOWN)
        else:
            self.work_origin_mm = self._z_mm - command.z_mm
        return self.work_zero_mm

    def enable_torch(self, enabled: bool) -> None:
        """PlasmaC M62-M65 P3. Disabled during a cut: the torch goes off and motion goes on
        (the hole over-cut), the THC holds Z and a missing arc is expected until M5.
        Enabling never relights a cut: it counts from the next M3 (a disabled M3 runs the
        sequence without firing the torch, as PlasmaC's torch-disabled mode)."""
        self.torch_enabled = enabled
        if not enabled and self.cut is not None and self._handler.torch_lit:
            self.cut.torch_out = True
            self._emit(act.SwitchTorch(False), act.SetZVelocity(0.0))

    # --- events from the board: the state's handler, after what every state does -------------

    def on_inputs(self, bits: int, z_mm: float, now: float) -> None:
        """Raw input snapshot (from SAMPLES and EVENTs); debounced here."""
        self.now = now
        self._z_mm = z_mm
        if bits & InputMask.OHMIC != self._debouncer.raw & InputMask.OHMIC:
            # Where the contact changed, not where its debounce ended (the zero's Z).
            self._ohmic_changed_z_mm = z_mm
        self._on_edges(self._debouncer.feed(bits, now, self.config.input_debounce_s))

    def _on_edges(self, edges: list[Edge]) -> None:
        for edge in edges:
            if edge.bit == InputMask.BREAKAWAY and edge.active and self.busy:
                self._fault("breakaway switch tripped")
            elif edge.bit == InputMask.ESTOP and edge.active:
                self._fault("E-stop")
            else:
                self._handler.on_edge(self, edge)

    def _arc_ok(self) -> bool:
        if self.config.dry_run or not self.torch_enabled:
            return True
        if self.cut is not None and self.cut.torch_out:
            return True  # put out on purpose (over-cut): no arc is no arc loss
        if self.mode is ThcMode.VOLTAGE_ONLY:
            return self._voltage_arc_ok()
        return bool(self.inputs & InputMask.ARC_OK)

    def _voltage_arc_ok(self) -> bool:
        cfg = self.config
        if len(self._voltages) < self._voltages.maxlen:  # type: ignore[operator]
            return False
        v = self._voltages[-1]
        if not cfg.arc_ok_low_v <= v <= cfg.arc_ok_high_v:
            return False
        return all(abs(x - v) <= cfg.arc_ok_agree_v for x in self._voltages)

    def on_probe_done(
        self, contact: bool, ohmic: bool, contact_z_mm: float, stop_z_mm: float
    ) -> None:
        self._handler.on_probe_done(self, contact, ohmic, contact_z_mm, stop_z_mm)

    def on_motion_done(self, token: int, reached: bool, z_mm: float) -> None:
        self._z_mm = z_mm
        if token != self._move_token:
            return  # a move that a later one superseded
        self._handler.on_motion_done(self, reached, z_mm)

    def on_board_fault(self, reason: str) -> None:
        if self.state is not State.FAULTED:
            self._fault(f"board fault: {reason}")

    def on_link_down(self, reason: str) -> None:
        if self.busy:
            self._fault(f"board link down: {reason}")

    def abort(self, reason: str) -> bool:
        """Stop a running cut the safe way (sender lost, shutdown, the operator): the fault
        path. True when a cut was running."""
        if not self.busy:
            return False
        self._fault(reason)
        return True

    def on_action_failed(self, action: act.Action, error: str) -> None:
        if isinstance(action, act.SwitchTorch) and not action.on:
            return  # the board turns the torch off on any fault by itself
        if self.busy:
            self._fault(f"{type(action).__name__} failed: {error}")

    # --- samples and time ------------------------------------------------------------------

    def on_samples(  # noqa: PLR0917 - one batch's fields, in wire order
        self,
        volts: Sequence[float],
        period_s: float,
        z_mm: float,
        xy_speed_mm_s: float | None,
        requested_feed_mm_s: float | None,
        now: float,
    ) -> None:
        self.now = now
        self._z_mm = z_mm
        self._xy_speed_mm_s = xy_speed_mm_s
        self._voltages.extend(volts)
        if requested_feed_mm_s is not None:
            # The programmed feed, not the reduced one: an M67 E3 reduction locks THC (PlasmaC).
            self._requested_mm_s = requested_feed_mm_s
        self.thc.observe_speed(xy_speed_mm_s, self._requested_mm_s, now)
        if self.cut is not None and self.state is State.PIERCE_DELAY:
            self.cut.transient.add(now, volts)  # torch and gantry still: the transient alone
        dt = period_s * len(volts) if self._last_thc_t is None else now - self._last_thc_t
        self._last_thc_t = now
        cutting = self.cut is not None and self.state is State.CUTTING and not self.cut.relay
        if cutting:
            self.thc.transient_v = self._transient_left_v(now)
        self._handler.on_batch(self, volts, period_s, dt)
        if cutting:
            self._sample_transient_tail(now)
        self.tick(now)

    def tick(self, now: float) -> None:
        """Time passes: debounced edges, the state's watch (arc OK, arc lost), its timer."""
        self.now = now
        self._on_edges(self._debouncer.poll(now, self.config.input_debounce_s))
        handler = self._handler
        if handler.watch(self, now):
            return
        if self._timer is None or now < self._timer:
            return
        self._timer = None
        handler.on_timeout(self)

    def _z_is_programs(self) -> bool:
        """A relay cut with the THC off: Z is the program's (no velocity stream, which would
        supersede its moves on the board)."""
        return self.in_relay_cut and not self.thc_enabled

    def _held_v(self) -> float | None:
        """The filtered voltage less what Z moved since the cut began: what a torch held at
        cut height would read."""
        cut = self.cut
        filtered = self.thc.filtered_v
        if cut is None or filtered is None or math.isnan(cut.start_z_mm):
            return filtered
        return filtered - self.thc.config.slope_v_per_mm * (self._z_mm - cut.start_z_mm)

    def _delay_done(self, now: float) -> bool:
        cut = self.cut
        assert cut is not None
        return cut.arc_ok_since is not None and now - cut.arc_ok_since >= self.config.thc_delay_s

    def _settled(self, now: float) -> bool:
        """At speed a little while (a slow torch's voltage rise decays some tens of ms
        after the machine is back at speed)."""
        cut = self.cut
        assert cut is not None
        since = cut.at_speed_since
        return since is not None and now - since >= self.config.at_speed_settle_s

    def _sample_transient_tail(self, now: float) -> None:
        """During the THC delay, at speed, the voltage a held torch reads: the start
        transient's tail, fitted with the pierce's voltages when the delay ends."""
        cut = self.cut
        assert cut is not None
        if cut.tail_fitted or self._delay_done(now) or not self.config.thc_discounts_transient:
            return
        held_v = self._held_v()
        if (
            not self._settled(now)
            or held_v is None
            or self.thc.noise_burst
            or self.thc.locks(now) - {Lock.FROZEN}
        ):
            return
        cut.tail_times_s.append(now)
        cut.tail_volts.append(held_v)

    def _transient_left_v(self, now: float) -> float:
        """What is left of the start transient, for the THC once its delay is over: by the
        decay the pierce and the delay's voltages show together, and by the pierce's alone,
        the smaller (0 without the first)."""
        cut = self.cut
        assert cut is not None
        cfg = self.config
        if not cfg.thc_discounts_transient or not self._delay_done(now):
            return 0.0
        if not cut.tail_fitted:
            cut.tail_fitted = True
            fit = refit_decay(cut.transient, cut.tail_times_s, cut.tail_volts)
            if fit is not None and fit[0] > 0.0 and fit[2] <= cfg.auto_voltage_max_residual_v:
                cut.tail_decay = (fit[0], fit[1])
        t0 = cut.transient.t0_s
        if cut.tail_decay is None or t0 is None:
            return 0.0
        overshoot_v, tau_s = cut.tail_decay
        # The smaller of the two models' remnants: either may overestimate it by half or
        # more (noise on the tail's curvature), and too much would lift the torch; too
        # little only leaves some of the transient to the loop, as without a model.
        tail_v = overshoot_v * math.exp(-(now - t0) / tau_s)
        return min(tail_v, cut.transient.remnant_v(now))

    def _measure_cut_height_v(self, now: float) -> None:
        """One batch of the cut-height voltage's measurement (every cut): the mean first,
        then auto voltage's correction by the line fit (and on a flat plate the longer
        window's mean); an auto target follows it."""
        cut = self.cut
        assert cut is not None
        assert cut.auto_voltage is not None
        estimate = cut.auto_voltage
        void = Lock.VOID in self.thc.locks(now)
        # A noise burst's voltages are left out (the window goes on): 2 V of noise over
        # 50 ms moved the mean by half a volt.
        held_v = None if self.thc.noise_burst else self._held_v()
        estimate.transient = cut.transient
        if cut.cut_height_v is None:
            measured = estimate.sample(now, held_v, cut.distance_mm, void)
        elif estimate.wants_refining:
            measured = estimate.refine(now, held_v, cut.distance_mm, void)
        else:
            return
        if measured is None:
            return
        cut.cut_height_v = measured
        if self.params.cut_voltage_v is None:
            self.base_v = measured

    def height_window(self) -> HeightWindow:
        cfg = self.config
        return HeightWindow(
            cfg.thc_window_below_mm, cfg.thc_window_above_mm, self.thc.config.slope_v_per_mm
        )

    # --- steps -----------------------------------------------------------------------------

    def _cut_z(self) -> float:
        assert self.cut is not None
        return self.cut.zero_mm + self.params.cut_height_mm

    def _answer_z_move(self, reached: bool, z_mm: float) -> None:
        error = self._probe.error or ("" if reached else f"Z stopped at {z_mm:.3f} mm")
        self._probe.error = ""
        self._reply(not error, error)

    def _to_pierce(self) -> None:
        assert self.cut is not None
        cfg = self.config
        pierce_z = self.cut.zero_mm + self.params.pierce_height_mm
        if pierce_z + 1.0 > cfg.z_max_mm - cfg.top_margin_mm:
            self._fault("pierce height is above the top of Z travel (material too high)")
            return
        self._update_safe_z()
        self._enter(State.TO_PIERCE)
        self._move(pierce_z, cfg.setup_speed_mm_s)

    def _update_safe_z(self) -> None:
        cut = self.cut
        assert cut is not None
        cfg = self.config
        top = cfg.z_max_mm - cfg.top_margin_mm
        low = cut.zero_mm + self.params.pierce_height_mm + 1.0
        wanted = max(cut.zero_mm + cfg.safe_height_mm + cut.thc_lift_mm, low)
        if wanted > top:
            self.warnings.append(f"safe height reduced to {top:.1f} mm (top of Z travel)")
            wanted = top
        self.safe_z_mm = wanted

    def _released(self) -> None:
        """The touch-off sensor released while creeping up: the surface is known."""
        assert self.cut is not None
        cfg = self.config
        if self._probe.sensor_ohmic:
            # Where the contact opened: by the time its debounce confirms it, the creep has
            # taken the torch a debounce's travel (and a batch's) higher, 0.005-0.01 mm at
            # 1 mm/s, which every cut's height (and a target measured there) would keep.
            released = self._ohmic_changed_z_mm
            z = released if not math.isnan(released) else self._z_mm
            self.cut.zero_mm = z + cfg.ohmic_offset_mm
        else:
            # The float switch closes at its travel but opens lower (hysteresis): the zero
            # comes from where it closed, latched by the board on the way down; the creep
            # up only lifts the torch off the plate.
            self.cut.zero_mm = self._probe.contact_z_mm + cfg.float_travel_mm
        self.last_zero_mm = self.cut.zero_mm
        self.probe_required = False
        self._emit(act.SwitchOhmicSense(False))
        self._to_pierce()  # the pierce move supersedes the creep

    def _torch_on(self) -> None:
        cut = self.cut
        assert cut is not None
        cut.attempts += 1
        cut.transient = StartTransient()  # a new transfer, a new transient
        self._voltages.clear()
        if not self.config.dry_run and self.torch_enabled:
            self._emit(act.SwitchTorch(True))
        self._enter(State.ARC_WAIT, self.config.arc_ok_timeout_s)

    def _after_pierce(self) -> None:
        assert self.cut is not None
        cfg = self.config
        if self.cut.relay:  # the program's own heights: cutting where it put the torch
            self._start_cutting()
            return
        if self.params.stop_after_pierce and not self.cut.relit:
            self._emit(act.SwitchTorch(False))
            self._enter(State.S1_RAISE)
            self._move(self.safe_z_mm, cfg.setup_speed_mm_s)
            return
        if cfg.puddle_height_percent != 100.0 or cfg.puddle_delay_s > 0:
            self._reply(True)  # XY may start during the puddle jump
            puddle_z = (
                self.cut.zero_mm + self.params.pierce_height_mm * cfg.puddle_height_percent / 100
            )
            self._move(puddle_z, cfg.setup_speed_mm_s)
            self._enter(State.PUDDLE_JUMP, cfg.puddle_delay_s)
            return
        self._enter(State.TO_CUT_HEIGHT)
        self._move(self._cut_z(), cfg.setup_speed_mm_s)

    def _start_cutting(self) -> None:
        cut = self.cut
        assert cut is not None
        self._enter(State.CUTTING)
        self.last_cut_start_xy = cut.start_xy
        if not cut.relay:  # a relay cut's heights are the program's: no reference height
            cut.start_z_mm = self._z_mm
        cut.transient.fit()
        self._reset_thc()
        self.thc.set_speed_limit(self.thc_z_feed_mm_min)
        self.thc.enabled = self.thc_enabled
        self.thc.anti_dive_percent = self.params.anti_dive_percent
        # Following a slow-down may take the torch down by half the cut height at most.
        self.thc.slow_follow_max_down_mm = self.params.cut_height_mm / 2.0
        self._last_thc_t = None
        self._reply(True)  # M3 answered: XY motion may start

    def _end_cut(self) -> None:
        self.last_thc_active = self.thc_enabled and self.target_v is not None
        self._emit(act.SetZVelocity(0.0), act.SwitchTorch(False))
        if self.cut is not None and self.cut.relay:
            self._enter(State.IDLE)  # the program raises Z itself (its G0 Z after M5)
            self._reply(True)
            return
        if self.cut is not None and not math.isnan(self.cut.zero_mm):
            self._update_safe_z()
        self._enter(State.TO_SAFE)
        self._move(self.safe_z_mm, self.config.setup_speed_mm_s)

    def _fault(self, reason: str, cause: act.PauseCause = act.PauseCause.FAULT) -> None:
        """docs/DESIGN.md invariant 3: torch off, sender paused, Z to safe height, touch-off
        required."""
        self.error = reason
        self.probe_required = True
        self._enter(State.FAULTED)
        self._torch_out_and_raise()
        self._emit(act.PauseProgram(reason, cause))
        self._reply(False, reason)

    def _torch_out_and_raise(self) -> None:
        """Torch and ohmic sensing off and Z held at once, then up to safe height (or where
        Z is, if higher, below the top margin): the fault path's and a pause's."""
        self._emit(act.SwitchTorch(False), act.SetZVelocity(0.0), act.SwitchOhmicSense(False))
        if self.cut is not None and not math.isnan(self.cut.zero_mm):
            self._update_safe_z()
        z = self._z_mm if not math.isnan(self._z_mm) else self.safe_z_mm
        top = self.config.z_max_mm - self.config.top_margin_mm
        self._move(min(max(self.safe_z_mm, z), top), self.config.setup_speed_mm_s)


def with_board_limits(config: SequenceConfig, z_min_mm: float, z_max_mm: float) -> SequenceConfig:
    return replace(config, z_min_mm=z_min_mm, z_max_mm=z_max_mm)
