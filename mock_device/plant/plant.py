"""The plant: plate, gantry, Z axis, torch head, arc, noise and THC box, in simulated time.

The board (mock_device.board_logic: the firmware's C board logic) owns a ``Plant`` and,
once per sample period:

1. applies its outputs: ``set_torch``, ``set_ohmic_sense``, ``set_current_a``, and Z
   where its step generator has put it (``plant.zaxis.drive``; the axis also plans its own
   moves, ``jog``/``move_to``/``stop``, for tests of the plant alone); an operator's
   ``reset_breakaway``; XY motion through ``plant.gantry`` (``feed_line``/``hold``/``resume``);
2. calls ``step(dt_s)``;
3. reads ``measured_voltage_v()`` (the ADC sample of this period) and ``inputs()`` (an int
   bitmask, see ``InputBit``).

Everything is deterministic: one ``random.Random`` per component, all seeded from ``seed``.
"""

import math
import random

from .arc import Arc, ArcEnd, ArcState
from .gantry import Gantry
from .inputs import InputBit
from .noise import NoiseGenerator
from .scenario import Scenario, load_scenario
from .surface import PlateSurface
from .thc_box import ThcBox
from .torch import TorchHead
from .truth import TruthRecorder
from .zaxis import ZAxis

__all__ = ["DEFAULT_DT_S", "Plant"]

#: The board samples at 1 kHz.
DEFAULT_DT_S = 0.001

_TRANSFERRED = ArcState.TRANSFERRED
_LIVE = frozenset({ArcState.PILOT, ArcState.TRANSFERRED, ArcState.LOST})
_ARC_OK = int(InputBit.ARC_OK)
_OHMIC = int(InputBit.OHMIC)
_FLOAT = int(InputBit.FLOAT)
_BREAKAWAY = int(InputBit.BREAKAWAY)
_THC_UP = int(InputBit.THC_UP)
_THC_DOWN = int(InputBit.THC_DOWN)
_ESTOP = int(InputBit.ESTOP)
_Z_LIMIT_MIN = int(InputBit.Z_LIMIT_MIN)
_Z_LIMIT_MAX = int(InputBit.Z_LIMIT_MAX)


class Plant:
    """The simulated machine and process behind a DTHC board."""

    def __init__(
        self,
        scenario: Scenario | str,
        seed: int = 0,
        *,
        record_truth: bool = True,
        truth_decimation: int = 1,
        truth_capacity: int = 120_000,
        thc_delay_s: float = 0.5,
    ) -> None:
        if isinstance(scenario, str):
            scenario = load_scenario(scenario)
        self.scenario = scenario
        self._material_feed_mm_s = scenario.material.cut_feed_mm_min / 60.0
        self.seed = seed
        master = random.Random(seed)
        # One stream per component, so e.g. enabling ohmic sensing does not shift the noise.
        rng_noise = random.Random(master.getrandbits(64))
        rng_arc = random.Random(master.getrandbits(64))
        rng_torch = random.Random(master.getrandbits(64))
        material = scenario.material
        self.surface = PlateSurface(
            scenario.plate,
            scenario.kerfs,
            scenario.voids,
            default_kerf_width_mm=material.kerf_width_mm,
            wide_void_mm=scenario.arc.void_lose_width_mm,
        )
        self.zaxis = ZAxis.from_spec(scenario.zaxis)
        self.gantry = Gantry.from_spec(scenario.gantry)
        self.head = TorchHead(scenario.torch, scenario.surface, rng_torch)
        self.arc = Arc(scenario.arc, material, rng_arc)
        self.noise = NoiseGenerator(scenario.noise, rng_noise)
        self.thc_box = ThcBox.from_spec(scenario.thc_box, material.cut_voltage_v)
        self.truth = TruthRecorder(
            cut_height_mm=material.cut_height_mm,
            thc_delay_s=thc_delay_s,
            decimation=truth_decimation,
            capacity=truth_capacity,
        )
        self._record_truth = record_truth
        self.t_s = 0.0
        self._torch_on = False
        self._ohmic_sense = False
        self._estop = False
        # Inputs held by hand (force_input): set bits on, cleared bits off, whatever the
        # physics says; the rest follow it.
        self._forced_on = 0
        self._forced_off = 0
        self._measured_v = 0.0
        self._first_transfer_t_s: float | None = None
        self._arc_lost_due_t_s = math.inf
        self._breakaway_due_t_s = math.inf
        x, y = self.gantry.x_mm, self.gantry.y_mm
        self._cache_x = x
        self._cache_y = y
        self._flex_mm = scenario.plate.flex_amplitude_mm
        self._flex_w = 2.0 * math.pi / scenario.plate.flex_period_s
        self._flex_start_s = scenario.plate.flex_start_s
        self._base_z_mm = self.surface.height_mm(x, y)
        self.surface_z_mm = self._base_z_mm
        self._gap_kind = self.surface.gap_kind(x, y)
        self.head.update(self.zaxis.position_mm, self.surface_z_mm, False, 0.0)

    # ------------------------------------------------------------------ inputs
    def set_torch(self, on: bool) -> None:
        """Torch relay. On fires the pilot (HF start); off kills the arc within one sample."""
        self._torch_on = on
        was_off = self.arc.state is ArcState.OFF
        self.arc.set_torch(on, self.t_s)
        if on and was_off:
            self.noise.start_hf(self.t_s)
        if not on:
            self._measured_v = 0.0

    def set_ohmic_sense(self, on: bool) -> None:
        """Enable the ohmic contact circuit (only then can OHMIC be seen)."""
        self._ohmic_sense = on

    def set_current_a(self, current_a: float) -> None:
        """Cutter current set point."""
        self.arc.set_current_a(current_a)

    def reset_breakaway(self) -> bool:
        """Try to clear the breakaway latch; return True if it is still tripped (or held
        active by ``force_input``)."""
        return self.head.reset_breakaway() or bool(self._forced_on & _BREAKAWAY)

    def set_estop(self, on: bool) -> None:
        """E-stop input (for tests); the plant only reports it."""
        self._estop = on

    def force_input(self, bit: int, on: bool | None) -> None:
        """Hold the input ``bit`` (an ``InputBit``) active (True) or inactive (False)
        whatever the physics says, as a switch wired to the pin would; None hands it back
        to the physics. OHMIC held active is seen only while ohmic sensing is on, as a
        contact is (its circuit is off otherwise)."""
        self._forced_on &= ~bit
        self._forced_off &= ~bit
        if on is True:
            self._forced_on |= bit
        elif on is False:
            self._forced_off |= bit

    @property
    def forced_inputs(self) -> tuple[int, int]:
        """The inputs held active and those held inactive by ``force_input``."""
        return self._forced_on, self._forced_off

    def load_default_program(self) -> int:
        """Queue the scenario's default program on the gantry; return the segments queued."""
        return self.gantry.feed_program(self.scenario.default_program)

    # ---------------------------------------------------------------- stepping
    def step(self, dt_s: float = DEFAULT_DT_S) -> None:
        """Advance the whole plant by one sample period of ``dt_s`` seconds."""
        t = self.t_s + dt_s
        self.t_s = t
        gantry = self.gantry
        gantry.step(dt_s)
        zaxis = self.zaxis
        zaxis.step(dt_s)
        x = gantry.x_mm
        y = gantry.y_mm
        if x != self._cache_x or y != self._cache_y:
            self._cache_x = x
            self._cache_y = y
            self._base_z_mm = self.surface_z_mm = self.surface.height_mm(x, y)
            self._gap_kind = self.surface.gap_kind(x, y)
        if self._flex_mm and self._first_transfer_t_s is not None:
            phase = self._flex_w * max(0.0, t - self._first_transfer_t_s - self._flex_start_s)
            self.surface_z_mm = self._base_z_mm + 0.5 * self._flex_mm * (1.0 - math.cos(phase))
        head = self.head
        head.update(zaxis.position_mm, self.surface_z_mm, self._ohmic_sense, dt_s)
        arc = self.arc
        arc.step(
            t,
            dt_s,
            head.true_height_mm,
            self._gap_kind,
            gantry.speed_mm_s,
            # The arc lengthens below the speed the material is cut at, whatever feed the
            # program asks for: a hole run at a reduced feed raises the voltage too.
            self._material_feed_mm_s,
        )
        state = arc.state
        if state is _TRANSFERRED:
            if self._first_transfer_t_s is None:
                self._arm_faults(arc.transfer_t_s)
            if t >= self._arc_lost_due_t_s:
                self._arc_lost_due_t_s = math.inf
                arc.lose(ArcEnd.INJECTED, t)
                state = arc.state
        if t >= self._breakaway_due_t_s:
            self._breakaway_due_t_s = math.inf
            head.trip_breakaway()
        measured = arc.voltage_v + self.noise.sample(t) if state in _LIVE else 0.0
        self._measured_v = measured
        self.thc_box.update(measured, arc.arc_ok, dt_s)
        if self._record_truth:
            self.truth.record(
                t,
                x,
                y,
                gantry.speed_mm_s,
                head.true_height_mm,
                zaxis.position_mm,
                self.surface_z_mm,
                self._torch_on,
                state,
                arc.voltage_v,
                measured,
            )

    def advance(self, duration_s: float, dt_s: float = DEFAULT_DT_S) -> None:
        """Step for ``duration_s`` (rounded to whole samples)."""
        for _ in range(round(duration_s / dt_s)):
            self.step(dt_s)

    def _arm_faults(self, transfer_t_s: float) -> None:
        self._first_transfer_t_s = transfer_t_s
        faults = self.scenario.faults
        if faults.arc_lost_at_s is not None:
            self._arc_lost_due_t_s = transfer_t_s + faults.arc_lost_at_s
        if faults.breakaway_at_s is not None:
            self._breakaway_due_t_s = transfer_t_s + faults.breakaway_at_s

    # ----------------------------------------------------------------- outputs
    def measured_voltage_v(self) -> float:
        """The arc-voltage sample the board's ADC sees this period (volts, noisy)."""
        return self._measured_v

    def inputs(self) -> int:
        """Digital inputs as an int bitmask (bit positions of ``InputBit``)."""
        head = self.head
        bits = 0
        if self.arc.arc_ok:
            bits |= _ARC_OK
        if head.ohmic_contact:
            bits |= _OHMIC
        if head.float_switch:
            bits |= _FLOAT
        if head.breakaway:
            bits |= _BREAKAWAY
        if self.thc_box.up:
            bits |= _THC_UP
        if self.thc_box.down:
            bits |= _THC_DOWN
        if self._estop:
            bits |= _ESTOP
        limit = self.zaxis.limit_hit
        if limit == "min":
            bits |= _Z_LIMIT_MIN
        elif limit == "max":
            bits |= _Z_LIMIT_MAX
        if self._forced_on | self._forced_off:
            forced_on = self._forced_on if self._ohmic_sense else self._forced_on & ~_OHMIC
            bits = (bits & ~self._forced_off) | forced_on
        return bits

    input_bits = inputs

    def count_violation(self, kind: str) -> None:
        """Count a safety violation seen by the board firmware (e.g. ``VIOLATION_LEASE``)."""
        self.truth.count_violation(kind)

    @property
    def torch_on(self) -> bool:
        """The torch relay as last set by the board."""
        return self._torch_on

    @property
    def arc_state(self) -> ArcState:
        """The arc's state."""
        return self.arc.state

    @property
    def arc_voltage_v(self) -> float:
        """The true (noiseless) arc voltage."""
        return self.arc.voltage_v

    @property
    def arc_ok(self) -> bool:
        """The arc-OK contact as the board sees it (with bounce)."""
        return self.arc.arc_ok

    @property
    def true_height_mm(self) -> float:
        """Tip height above the plate surface under it (0 while resting on the plate)."""
        return self.head.true_height_mm

    @property
    def carriage_z_mm(self) -> float:
        """Z axis position (the tip's machine Z when uncompressed)."""
        return self.zaxis.position_mm

    @property
    def xy_speed_mm_s(self) -> float:
        """Actual XY path speed."""
        return self.gantry.speed_mm_s
