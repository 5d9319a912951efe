"""plasmac in closed loop with our plant: LinuxCNC's motion emulated around the component.

Per 1 ms period (the order of LinuxCNC's servo thread):

1. the plant's sensors of the last period, debounced (5 periods, QtPlasmaC's ``dbounce``),
   and motion's feedback (Z position and external offset, current and requested velocity,
   motion type, program state, spindle 0 on/off) are written to the component's pins;
2. the component runs once;
3. its outputs drive the machine: ``torch-on`` the torch relay, ``ohmic-enable`` the ohmic
   circuit, ``feed-hold`` the gantry, ``program-pause`` a program pause (the gantry holds),
   ``z-offset-counts`` x ``offset-scale`` the external-offset planner;
4. the plant steps 1 ms.

Z: the program's own Z is the top of travel less ``max-offset`` (QtPlasmaC's G-code filter
strips Z moves and starts each job there), and the external offset moves the torch from it.

The settings are QtPlasmaC's GUI defaults in mode 1 (arc voltage THC, external arc OK):
THC delay 0.5 s, threshold 1 V, P 10 (I, D 0), velocity anti-dive on at 90 %, void lock
off, auto volts on (``use_auto_volts``; off for a run at the material's cut volts), plus
what a user sets per machine and material, matched to the other controllers' runs: pierce
and cut heights, pierce delay, probe speed, ohmic probing with the float switch as
fallback, and the THC speed (``thc-feed-rate``) equal to ours (``M667 F3000``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from mock_device.plant import ArcState, InputBit, Plant

from ..cuts import ControllerResult, CutPlan, VoidLockTally
from .component import PlasmacComponent
from .fetch import Provisioned
from .motion import Debounce, OffsetPlanner

__all__ = ["STATE_NAMES", "PlasmacHost", "PlasmacSettings", "run_plasmac"]

PERIOD_S = 0.001
STATE_NAMES = (  # plasmac's state-out values, in order
    *("IDLE", "PROBE_HEIGHT", "PROBE_DOWN", "PROBE_UP", "ZERO_HEIGHT", "PIERCE_HEIGHT"),
    *("TORCH_ON", "ARC_OK", "PIERCE_DELAY", "PUDDLE_JUMP", "CUT_HEIGHT", "CUT_MODE_01"),
    *("CUT_MODE_2", "PAUSE_AT_END", "SAFE_HEIGHT", "MAX_HEIGHT", "END_CUT", "END_JOB"),
    *("TORCHPULSE", "PAUSED_MOTION", "OHMIC_TEST", "PROBE_TEST", "SCRIBING"),
    *("CONSUMABLE_CHANGE_ON", "CONSUMABLE_CHANGE_OFF", "CUT_RECOVERY_ON", "CUT_RECOVERY_OFF"),
    "DEBUG",
)
_IDLE, _CUT_MODE_01 = 0, 11
_ARC_OK = int(InputBit.ARC_OK)
_OHMIC = int(InputBit.OHMIC)
_FLOAT = int(InputBit.FLOAT)
_BREAKAWAY = int(InputBit.BREAKAWAY)


@dataclass(frozen=True)
class PlasmacSettings:
    """Pin values (``pin name -> value``) beyond the component's own defaults."""

    use_auto_volts: bool = True
    thc_enable: bool = True
    thc_feed_rate_mm_min: float = 3000.0
    pierce_delay_s: float = 0.3
    probe_feed_rate_mm_min: float = 300.0
    ohmic: bool = True
    extra: tuple[tuple[str, float], ...] = ()  # any other pin, e.g. (("voidlock-enable", 1),)

    def pins(self, plant: Plant) -> dict[str, float]:
        material = plant.scenario.material
        z = plant.zaxis
        thc_feed = self.thc_feed_rate_mm_min
        values: dict[str, float] = {
            # The machine and motion.
            "machine-is-on": 1,
            "homed": 1,
            "units-per-mm": 1,
            "axis-z-min-limit": z.min_mm,
            "axis-z-max-limit": z.max_mm,
            "axis-x-min-limit": -1e6,
            "axis-x-max-limit": 1e6,
            "axis-y-min-limit": -1e6,
            "axis-y-max-limit": 1e6,
            "feed-override": 1.0,
            "feed-reduction": 100.0,
            "torch-enable": 1,
            "mode": 1,
            "arc-voltage-scale": 1.0,
            "arc-voltage-offset": 0.0,
            # QtPlasmaC's GUI defaults (qtplasmac_handler.py's preference fallbacks).
            "arc-fail-delay": 3.0,
            "arc-max-starts": 3,
            "restart-delay": 1.0,
            "arc-lost-delay": 0.0,
            "height-per-volt": 0.1,
            "float-switch-travel": 1.5,
            "probe-start-height": 25.0,
            "ohmic-probe-offset": 0.0,
            "ohmic-max-attempts": 0,
            "skip-ihs-distance": 0.0,
            "safe-height": 25.0,
            "thc-delay": 0.5,
            "thc-threshold": 1.0,
            "pid-p-gain": 10.0,
            "pid-i-gain": 0.0,
            "pid-d-gain": 0.0,
            "cornerlock-enable": 1,
            "cornerlock-threshold": 90.0,
            "voidlock-enable": 0,
            "thc-auto": 0,
            "thc-enable": 1 if self.thc_enable else 0,
            "use-auto-volts": 1 if self.use_auto_volts else 0,
            "thc-feed-rate": thc_feed,
            "setup-feed-rate": 0.8 * thc_feed,
            "probe-feed-rate": self.probe_feed_rate_mm_min,
            "ohmic-probe-enable": 1 if self.ohmic else 0,
            # The material.
            "pierce-height": material.pierce_height_mm,
            "pierce-delay": self.pierce_delay_s,
            "cut-height": material.cut_height_mm,
            "cut-volts": material.programmed_voltage_v,
            "cut-feed-rate": material.cut_feed_mm_min,
            "puddle-jump-height": 0.0,
            "puddle-jump-delay": 0.0,
            "pause-at-end": 0.0,
        }
        values.update(dict(self.extra))
        return values


@dataclass
class _Recording:
    """Every input and output pin, every period (for the halrun replay)."""

    inputs: list[str]
    outputs: list[str]
    rows_in: list[tuple[float, ...]] = field(default_factory=list)
    rows_out: list[tuple[float, ...]] = field(default_factory=list)


class PlasmacHost:
    """One plant, one private plasmac copy, LinuxCNC's motion around it."""

    def __init__(
        self,
        plant: Plant,
        component: PlasmacComponent,
        settings: PlasmacSettings,
        *,
        record: bool = False,
    ) -> None:
        self.plant = plant
        self.comp = component
        self.settings = settings
        for name, value in settings.pins(plant).items():
            component.pin(name).value = value
        z = plant.zaxis
        # QtPlasmaC's filter starts the job with Z at the top less max-offset.
        self.z_base_mm = z.max_mm - component.pin("max-offset").value
        z.stop()
        z.position_mm = self.z_base_mm
        z.velocity_mm_s = 0.0
        z.state = type(z.state).IDLE
        self.offset = OffsetPlanner(z.max_velocity_mm_s, z.accel_mm_s2, PERIOD_S)
        self.debounce = {bit: Debounce(5) for bit in (_ARC_OK, _OHMIC, _FLOAT, _BREAKAWAY)}
        self.t_s = 0.0
        self.cutting_start = False
        self.motion_type = 1
        self.running = False
        self.paused = False
        self.pauses: list[str] = []
        self.messages: list[str] = []
        self.feed_held = False
        self._torch = False
        self._ohmic_sense = False
        self.programmed_feed_mm_min: float | None = None
        self.slow_percent: float = 100.0
        # Per phase while the gantry moves in CUT_MODE_01: [s, s x squared error].
        self.phase_err: dict[str, list[float]] = {}
        self.cutting_s = 0.0
        self.locked_s = 0.0
        self.lock_s: dict[str, float] = {}
        self.thc_moved_mm = 0.0  # THC's own Z travel, summed (for tests)
        self.void = VoidLockTally()
        self.target_errors_v: list[float] = []  # target-volts less the true cut-height voltage
        p = component.pin
        self._in = {
            name: p(name)._cell
            for name in (
                "arc-voltage-in", "arc-ok-in", "float-switch", "ohmic-probe", "breakaway",
                "axis-z-position", "z-offset-current", "axis-x-position", "axis-y-position",
                "current-velocity", "feed-upm", "motion-type", "program-is-running",
                "program-is-paused", "program-is-idle", "cutting-start", "offsets-active",
                "feed-reduction",
            )
        }  # fmt: skip
        self._out = {
            name: p(name)._cell
            for name in (
                "torch-on", "ohmic-enable", "feed-hold", "program-pause", "program-resume",
                "program-stop", "z-offset-counts", "offset-scale", "state-out",
                "cornerlock-is-locked", "voidlock-is-locked", "target-volts", "z-offset-enable",
                "adaptive-feed", "thc-active",
            )
        }  # fmt: skip
        self.recording: _Recording | None = None
        if record:
            names = sorted(component.pins)
            self.recording = _Recording(
                [n for n in names if not component.pins[n].output],
                [n for n in names if component.pins[n].output],
            )

    # --- one period --------------------------------------------------------------------

    @property
    def state(self) -> int:
        return int(self._out["state-out"].value)

    def period(self) -> None:
        plant = self.plant
        gantry = plant.gantry
        i = self._in
        o = self._out
        bits = plant.inputs()
        db = self.debounce
        i["arc-voltage-in"].value = plant.measured_voltage_v()
        i["arc-ok-in"].value = db[_ARC_OK].update(bool(bits & _ARC_OK))
        i["float-switch"].value = db[_FLOAT].update(bool(bits & _FLOAT))
        i["ohmic-probe"].value = db[_OHMIC].update(bool(bits & _OHMIC))
        i["breakaway"].value = db[_BREAKAWAY].update(bool(bits & _BREAKAWAY))
        i["axis-z-position"].value = plant.zaxis.position_mm
        i["z-offset-current"].value = self.offset.position_mm
        i["offsets-active"].value = abs(self.offset.position_mm) > 1e-9
        i["axis-x-position"].value = gantry.x_mm
        i["axis-y-position"].value = gantry.y_mm
        i["current-velocity"].value = gantry.speed_mm_s
        # motion.feed-upm: the running move's feed with the adaptive feed applied (plasmac
        # divides it back out); a slowed tail runs at the programmed feed x M67 E3.
        i["feed-upm"].value = gantry.requested_feed_mm_s * 60.0
        i["feed-reduction"].value = self._feed_reduction()
        i["motion-type"].value = self.motion_type
        i["program-is-running"].value = self.running and not self.paused
        i["program-is-paused"].value = self.paused
        i["program-is-idle"].value = not self.running
        i["cutting-start"].value = self.cutting_start
        rec = self.recording
        if rec is not None:
            pins = self.comp.pins
            rec.rows_in.append(tuple(pins[n].value for n in rec.inputs))
        self.comp.run()
        if rec is not None:
            pins = self.comp.pins
            rec.rows_out.append(tuple(pins[n].value for n in rec.outputs))
        torch = bool(o["torch-on"].value)
        if torch != self._torch:
            self._torch = torch
            plant.set_torch(torch)
        ohmic = bool(o["ohmic-enable"].value)
        if ohmic != self._ohmic_sense:
            self._ohmic_sense = ohmic
            plant.set_ohmic_sense(ohmic)
        held = bool(o["feed-hold"].value) or self.paused
        if held != self.feed_held:
            self.feed_held = held
            if held:
                gantry.hold()
            else:
                gantry.resume()
        if o["program-pause"].value and not self.paused and self.running:
            self.paused = True  # halui pauses the program: motion holds
            gantry.hold()
            self.feed_held = True
            reason = " ".join(self.comp.messages()) or "program paused"
            self.pauses.append(reason)
        before = self.offset.position_mm
        self.offset.update(o["z-offset-counts"].value * o["offset-scale"].value)
        state = int(o["state-out"].value)
        if state == _CUT_MODE_01:
            self.thc_moved_mm += abs(self.offset.position_mm - before)
        z = plant.zaxis
        z.position_mm = min(z.max_mm, max(z.min_mm, self.z_base_mm + self.offset.position_mm))
        z.velocity_mm_s = self.offset.velocity_mm_s
        plant.step(PERIOD_S)
        self.t_s += PERIOD_S
        if state == _CUT_MODE_01 and plant.arc.state is ArcState.TRANSFERRED:
            self._account()

    def _feed_reduction(self) -> float:
        """``M67 E3``: the slowed tail is the last move of its cut."""
        if self.programmed_feed_mm_min and self.plant.gantry.queue_len == 1:
            return self.slow_percent
        return 100.0

    def _account(self) -> None:
        self.cutting_s += PERIOD_S
        corner = bool(self._out["cornerlock-is-locked"].value)
        void = bool(self._out["voidlock-is-locked"].value)
        delay = not self._out["target-volts"].value
        if delay:
            phase = "delay"
        elif corner or void:
            phase = "locked"
        else:
            phase = "active"
        if phase != "active":
            self.locked_s += PERIOD_S
            key = "delay" if delay else ("velocity" if corner else "void")
            self.lock_s[key] = self.lock_s.get(key, 0.0) + PERIOD_S
        self.void.update(void, self.plant.arc.gap_voltage_v, PERIOD_S)
        if self.plant.gantry.speed_mm_s > 0.0:
            err = self.plant.true_height_mm - self.plant.scenario.material.cut_height_mm
            acc = self.phase_err.setdefault(phase, [0.0, 0.0])
            acc[0] += PERIOD_S
            acc[1] += PERIOD_S * err * err

    def run_until(self, done: Callable[[], bool], max_s: float) -> bool:
        end = self.t_s + max_s - 1e-9
        while self.t_s < end:
            self.period()
            if done():
                return True
        return False

    # --- the program ---------------------------------------------------------------------

    def cut(self, plan: CutPlan, *, slow_percent: float) -> str | None:
        """One planned cut: rapid, M3, motion, M5; None when it completed, else why not."""
        gantry = self.plant.gantry
        self.running = True
        self.motion_type = 1
        gantry.feed_line(plan.approach)
        if not self.run_until(lambda: gantry.idle, 60.0):
            return "approach did not finish"
        self.motion_type = 2
        self.programmed_feed_mm_min = plan.programmed_feed_mm_min if plan.slow else None
        self.slow_percent = slow_percent
        self.cutting_start = True  # M3: spindle.0.on
        for line in (*plan.lines, *plan.slow):
            gantry.feed_line(line)
        finished = self.run_until(lambda: gantry.idle or self.paused, 600.0)
        if self.paused:
            # The operator's answer to a pause: once the torch is up, drop the rest of the
            # cut (as the other controllers' runs do), spindle off, resume with a rapid.
            self.run_until(lambda: self.state == _IDLE, 30.0)
            gantry.clear()
            self.cutting_start = False
            self.motion_type = 1
            self.paused = False
            self.run_until(lambda: not self._out["feed-hold"].value, 1.0)
            return f"paused: {self.pauses[-1]}"
        target_v = float(self._out["target-volts"].value)
        if target_v > 0.0:  # the cut's target: its auto volts, or the material's cut volts
            cut_height = self.plant.scenario.material.cut_height_mm
            self.target_errors_v.append(target_v - self.plant.arc.voltage_at_height_v(cut_height))
        self.cutting_start = False  # M5
        self.programmed_feed_mm_min = None
        ended = self.run_until(
            lambda: self.state == _IDLE and not self._out["feed-hold"].value, 30.0
        )
        if not finished:
            return "cut did not finish"
        return None if ended else "did not return to idle after M5"

    def end_job(self) -> None:
        """M2: program idle; plasmac ends the job and clears its offset."""
        self.running = False
        self.run_until(
            lambda: self.state == _IDLE and self._out["z-offset-counts"].value == 0, 30.0
        )


def run_plasmac(
    provisioned: Provisioned,
    scenario: str,
    seed: int,
    plans: Sequence[CutPlan],
    settings: PlasmacSettings,
    *,
    slow_percent: float = 50.0,
) -> ControllerResult:
    """Every planned cut of ``scenario`` with plasmac; ground truth per cut, as for ours."""
    plant = Plant(scenario, seed=seed)
    with PlasmacComponent(provisioned.component, provisioned.shim) as component:
        return _run(PlasmacHost(plant, component, settings), plans, slow_percent)


def _run(host: PlasmacHost, plans: Sequence[CutPlan], slow_percent: float) -> ControllerResult:
    plant = host.plant
    plant.gantry.feed_line("G21 G90")
    result = ControllerResult(planned_cuts=len(plans))
    for plan in plans:
        error = host.cut(plan, slow_percent=slow_percent)
        if error is None:
            result.completed_cuts += 1
        else:
            result.errors.append(error)
    host.end_job()
    result.cuts = list(plant.truth.summary().cuts)
    result.cutting_s = host.cutting_s
    result.locked_s = host.locked_s
    result.lock_s = host.lock_s
    result.phase_err = host.phase_err
    result.pauses = host.pauses
    result.void = host.void
    result.target_errors_v = host.target_errors_v
    if not math.isfinite(host.t_s):
        raise RuntimeError("time ran away")
    return result
