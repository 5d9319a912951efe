"""PlasmaController: applies typed commands to the cut sequence (pure, no I/O).

One place decides what each command does in each state, so G-code over MQTT, structured
requests and tests all behave alike. A command either completes at once (``Outcome``), is
answered later by the sequence (``deferred``: M3 when XY may move, M5 at safe height), or
is refused with a :class:`CommandError` that changes nothing.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from ..materials import Material, MaterialError, MaterialTable, material_to_dict
from ..materials import parse_magic_comment as _parse_magic
from ..materials.library import MM_PER_INCH
from .commands import (
    Abort,
    Command,
    CommandError,
    CutParams,
    CycleStart,
    DefineMaterial,
    HeightOverride,
    JogZ,
    LegacyMode,
    OhmicTest,
    OperatingMode,
    PlasmaMode,
    ProbeAndStart,
    ProbeSurface,
    ProbeTest,
    ProgramZMove,
    Rearm,
    ResumePoint,
    SelectCurrent,
    SelectMaterial,
    SetCutParams,
    SetWorkZ,
    ThcEnable,
    ThcHold,
    TorchEnable,
    TorchStart,
    TorchStop,
    VelocityReduction,
    VoltageAdjust,
    VoltageMode,
)
from .sequence import CutSequence, State

__all__ = ["TOOL_NOTE", "Outcome", "PlasmaController", "ResumeTrack"]

TOOL_NOTE = (
    "a tool note: plasma mode stays on (controller.plasma_mode_at_start; a table with other "
    "tools sets it false)"
)


@dataclass(frozen=True)
class ResumeTrack:
    line: int | None
    index: int  # the how-many-th P0 of the program


@dataclass(frozen=True)
class Outcome:
    deferred: bool = False  # the sequence answers later with a CommandReply
    data: dict[str, Any] = field(default_factory=dict)
    resume_point: ResumeTrack | None = None  # a G100 P0 just marked one
    store: Material | None = None  # a magic comment (o=1, o=2) changed the library


def default_material(feed_mm_min: float) -> Material:
    """Material 0, the default material: the daemon's default cut parameters (the values
    of a bare ``G200`` line) and its default cut feed. QtPlasmaC keeps it in its settings,
    not in the material file, and so does the daemon."""
    p = CutParams()
    return Material(
        number=0,
        name="default",
        pierce_height=p.pierce_height_mm,
        pierce_delay_s=p.pierce_delay_ms / 1000.0,
        cut_height=p.cut_height_mm,
        cut_speed=feed_mm_min,
        cut_volts=p.cut_voltage_v or 0.0,
    )


class PlasmaController:
    def __init__(
        self,
        sequence: CutSequence | None = None,
        *,
        materials: Mapping[int, Material] | None = None,
        default: Material | None = None,
        inch_materials: bool = False,
        plasma_only: bool = False,
    ) -> None:
        self.sequence = sequence or CutSequence()
        # controller.plasma_mode_at_start: in plasma mode from the start, and a tool change
        # is a note (the torch is the only tool this board starts).
        self.plasma_only = plasma_only
        self.sequence.plasma_mode = self.sequence.plasma_mode or plasma_only
        self.resume_points: list[ResumeTrack] = []
        self.default_material = default or default_material(3000.0)
        self.inch_materials = inch_materials  # the library's lengths are inches
        self.materials = MaterialTable(materials or {}, self.default_material)

    # --- materials -------------------------------------------------------------------------

    def set_library(self, materials: Mapping[int, Material]) -> None:
        """The library changed (MQTT, a magic comment): same selection where it still is."""
        table = self.materials
        keep = {n: m for n, m in table.materials.items() if m.temporary}
        initial = table.initial if table.initial in materials or table.initial == 0 else 0
        self.materials = MaterialTable({**materials, **keep}, self.default_material,
                                       initial=initial)  # fmt: skip
        if table.selected_number in materials or table.selected_number in keep:
            self.materials.select(table.selected_number)

    def begin_program(self) -> dict[str, Any]:
        """A program starts: its ``M190 P-1`` returns to the material in force now, and the
        temporary materials of an earlier program are gone (QtPlasmaC drops them on load).
        The answer carries that material's cut feed: PlasmaC's ``cut-feed-rate`` pin always
        reads the material in force, even before the program's first ``M190``."""
        table = self.materials
        selected = table.selected_number if not table.selected.temporary else 0
        library = {n: m for n, m in table.materials.items() if not m.temporary}
        self.materials = MaterialTable(library, self.default_material, initial=selected)
        self.sequence.torch_enabled = True
        self.sequence.work_origin_mm = None
        self.sequence.override_height(0.0)  # the last program's override ends with it
        material = self.materials.selected
        return {
            "material": selected,
            "cut_feed_mm_min": material.cut_speed_mm_min(inch=self._in_inches(material)),
            "pins": self.pins(material),
        }

    def pins(self, material: Material) -> dict[str, float]:
        """What a program's ``#<_hal[...]>`` reads (dthc_bridge/program/plan.READABLE_PINS),
        in mm: PlasmaC's cut feed and kerf width of the material in force (the 2019 pin name
        too), and the float switch's travel from the configuration."""
        scale = MM_PER_INCH if self._in_inches(material) else 1.0
        kerf = round(material.kerf_width * scale, 6)
        return {
            "plasmac.cut-feed-rate": material.cut_speed_mm_min(inch=self._in_inches(material)),
            "qtplasmac.kerf_width-f": kerf,
            "plasmac_run.kerf-width-f": kerf,
            "plasmac.float-switch-travel": self.sequence.config.float_travel_mm,
        }

    def end_program(self) -> dict[str, Any]:
        """The program ran to its end: PlasmaC resets the height override with it."""
        self.sequence.override_height(0.0)
        return {"height_override_mm": 0.0}

    def _override_height(self, command: HeightOverride) -> dict[str, Any]:
        sequence = self.sequence
        height = 0.0 if command.reset else round(sequence.height_override_mm + command.step_mm, 1)
        bound = sequence.params.cut_height_mm / 2.0
        if abs(height) > bound + 1e-9:
            raise CommandError(
                "height_override mm",
                f"{height:+.1f} mm is beyond half the cut height (±{bound:.2f} mm)",
            )
        sequence.override_height(height)
        return {"height_override_mm": height, "target_v": sequence.thc.target_v}

    def _in_inches(self, material: Material) -> bool:
        """Library and program materials are in the machine's units; material 0 is the
        daemon's own default, always mm."""
        return self.inch_materials and material.number != 0

    def _material_params(self, material: Material, word: str) -> CutParams:
        """The cut parameters ``material`` would put in force; refused during a cut or
        when the material is outside the controller's ranges. Changes nothing."""
        sequence = self.sequence
        if sequence.busy:
            raise CommandError(word, f"not during a cut ({sequence.state})")
        current = sequence.params
        try:
            params = material.as_cut_params(
                touch_feed_mm_min=current.touch_feed_mm_min,
                ohmic=current.ohmic,
                anti_dive_percent=current.anti_dive_percent,
                inch=self._in_inches(material),
            )
        except MaterialError as exc:
            raise CommandError(word, str(exc)) from None
        return replace(params, stop_after_pierce=current.stop_after_pierce)

    def _use_material(
        self, material: Material, word: str, params: CutParams | None = None
    ) -> dict[str, Any]:
        """Put ``material`` in force (``params``: already checked by _material_params)."""
        sequence = self.sequence
        if material.positions_nothing:
            # QtPlasmaC's tube cutting: the program probes and moves Z itself; the torch
            # starts where it put it, after the material's pierce delay.
            if sequence.busy:
                raise CommandError(word, f"not during a cut ({sequence.state})")
            sequence.program_positions(material.pierce_delay_s)
        else:
            sequence.set_params(params or self._material_params(material, word))
        sequence.set_thc(material.thc)
        sequence.config = replace(
            sequence.config,
            pause_at_end_s=material.pause_at_end_s,
            # 0 in the file: no puddle jump (100 % of the pierce height, no delay).
            puddle_height_percent=material.puddle_jump_height_percent or 100.0,
            puddle_delay_s=material.puddle_jump_delay_s,
        )
        if material.cut_amps > 0:
            sequence.request_current(material.cut_amps)
        return {
            "material": material.number,
            "name": material.name,
            "cut_feed_mm_min": material.cut_speed_mm_min(inch=self._in_inches(material)),
            "pins": self.pins(material),
            "params": material_to_dict(material),
        }

    @property
    def last_resume_point(self) -> ResumeTrack | None:
        return self.resume_points[-1] if self.resume_points else None

    def handle(
        self, command: Command, now: float, xy_mm: tuple[float, float] | None = None
    ) -> Outcome:
        sequence = self.sequence
        if isinstance(command, TorchStart):
            sequence.start(now, xy_mm, relay=command.relay)
            return Outcome(deferred=True)
        if isinstance(command, ProgramZMove | ProbeSurface | SetWorkZ):
            return self._program_z(command, now)
        if isinstance(command, TorchStop):
            sequence.stop(now, xy_mm)
            return Outcome(deferred=True)
        if isinstance(command, ProbeAndStart):
            return self._probe_and_start(command, now, xy_mm)
        if isinstance(command, PlasmaMode):
            if self.plasma_only and not command.enabled:
                return Outcome(data={"tool": command.tool, "note": TOOL_NOTE})
            if sequence.busy and not command.enabled:
                raise CommandError(f"T{command.tool} M6", "cannot leave plasma mode during a cut")
            sequence.plasma_mode = command.enabled
        elif isinstance(command, SetCutParams):
            sequence.set_params(command.params)  # a later G200 overwrites; takes effect next cut
        elif isinstance(command, LegacyMode):
            if sequence.busy:
                raise CommandError("G200", "cannot switch to legacy mode during a cut")
            sequence.g200_active = False
        elif isinstance(command, ThcEnable):
            sequence.set_thc(command.enabled, command.z_feed_mm_min)
        elif isinstance(command, TorchEnable):
            sequence.enable_torch(command.enabled)
        elif isinstance(command, SelectMaterial):
            word = command.word or f"M190 P{command.number}"
            try:
                material = self.materials.get(
                    self.materials.initial if command.number == -1 else command.number,
                    where=word,
                )
            except MaterialError as exc:
                raise CommandError(word, exc.reason) from None
            data = self._use_material(material, word)
            self.materials.select(command.number)
            return Outcome(data=data)
        elif isinstance(command, DefineMaterial):
            return self._define_material(command.comment)
        elif isinstance(command, VoltageAdjust):
            sequence.adjust_voltage(command.delta_v)
            return Outcome(
                data={"target_v": sequence.thc.target_v, "offset_v": sequence.voltage_offset_v}
            )
        elif isinstance(command, ResumePoint):
            point = ResumeTrack(command.line, len(self.resume_points))
            self.resume_points.append(point)
            return Outcome(
                data={"resume_line": point.line, "index": point.index}, resume_point=point
            )
        elif isinstance(command, SelectCurrent):
            sequence.request_current(command.current_a)
        elif isinstance(command, VoltageMode):
            volts = None if command.auto else command.volts
            sequence.set_params(replace(sequence.params, cut_voltage_v=volts))
        elif isinstance(command, OperatingMode):
            if sequence.busy:
                raise CommandError("operating_mode", "cannot change the mode during a cut")
            sequence.mode = command.mode
        elif isinstance(command, VelocityReduction):
            pass  # the sender slows its motion; the THC sees the slower speed as anti-dive
        elif isinstance(command, CycleStart):
            if sequence.state is not State.S1_WAIT:
                raise CommandError(
                    "cycle_start", f"nothing waits for cycle start ({sequence.state})"
                )
            sequence.cycle_start(now)
        elif isinstance(command, Rearm):
            if sequence.state is not State.FAULTED:
                raise CommandError("rearm", f"nothing to re-arm ({sequence.state})")
            sequence.rearm(now)
        elif isinstance(command, HeightOverride):
            return Outcome(data=self._override_height(command))
        elif isinstance(command, Abort):
            busy = sequence.busy
            sequence.abort("stopped by the operator")
            return Outcome(data={"aborted": busy})
        elif isinstance(command, ThcHold):
            # A pause holds Z; a lit cut is ended (docs/DESIGN.md invariant 7), whoever asks.
            sequence.thc.held = command.on
            ended = command.on and sequence.pause(now, "paused by the operator")
            return Outcome(data={"thc_held": command.on, "cut_ended": ended})
        elif isinstance(command, OhmicTest | ProbeTest | JogZ):
            return self._operator_test(command, now)
        return Outcome()

    def _operator_test(self, command: OhmicTest | ProbeTest | JogZ, now: float) -> Outcome:
        """The panel's ohmic test, probe test and Z jog: with the table idle only."""
        sequence = self.sequence
        name = {OhmicTest: "ohmic_test", ProbeTest: "probe_test", JogZ: "jog_z"}[type(command)]
        if sequence.state is State.FAULTED:
            raise CommandError(name, f"re-arm required after: {sequence.error}")
        if sequence.busy:
            raise CommandError(name, f"not during a cut ({sequence.state})")
        if isinstance(command, OhmicTest):
            sequence.ohmic_test(now)
            return Outcome()
        if isinstance(command, ProbeTest):
            error = sequence.probe_test(now)
        else:
            error = sequence.jog_z(now, command.mm, command.feed_mm_min)
        if error is not None:
            raise CommandError(name, error)
        return Outcome(deferred=True)

    def _define_material(self, comment: str) -> Outcome:
        word = f"({comment})"
        try:
            magic = _parse_magic(comment)
        except MaterialError as exc:
            raise CommandError(word, str(exc)) from None
        if magic is None:
            raise CommandError(word, "not a material comment (o=0, o=1 or o=2)")
        # A temporary material is used at once: check it can be before it is defined.
        params = None
        if magic.option == 0 and not magic.material.positions_nothing:
            params = self._material_params(magic.material, word)
        try:
            material = self.materials.apply(magic)
        except MaterialError as exc:
            raise CommandError(word, str(exc)) from None
        if magic.option == 0:
            data = self._use_material(material, word, params)
            return Outcome(data={**data, "defined": material.number})
        return Outcome(
            data={"defined": material.number, "name": material.name},
            store=material if magic.option in (1, 2) else None,
        )

    def _program_z(self, command: ProgramZMove | ProbeSurface | SetWorkZ, now: float) -> Outcome:
        """Z words of the program: Z belongs to the board, so they come here, not to motion."""
        sequence = self.sequence
        word = {ProgramZMove: "Z", ProbeSurface: "G38.2", SetWorkZ: "G92 Z"}[type(command)]
        if isinstance(command, ProbeSurface) and command.away:
            word = "G38.4" if command.require_contact else "G38.5"
        if sequence.state is State.FAULTED:
            raise CommandError(word, f"re-arm required after: {sequence.error}")
        if isinstance(command, SetWorkZ):
            if sequence.busy and not sequence.in_relay_cut:
                raise CommandError(word, f"not during a cut ({sequence.state})")
            try:
                sequence.set_work_z(command.z_mm)
            except ValueError as exc:
                raise CommandError(word, str(exc)) from None
            return Outcome(data={"work_zero_mm": round(sequence.work_zero_mm, 3)})
        if isinstance(command, ProbeSurface):
            if sequence.busy:
                raise CommandError(word, f"not during a cut ({sequence.state})")
            sequence.probe_surface(
                now,
                sequence.work_zero_mm + command.z_mm,
                command.feed_mm_min / 60.0,
                command.require_contact,
                away=command.away,
            )
            return Outcome(deferred=True)
        target = command.z_mm if command.machine else sequence.work_zero_mm + command.z_mm
        setup = sequence.config.setup_speed_mm_s
        feed = setup if command.feed_mm_min is None else min(command.feed_mm_min / 60.0, setup)
        ignored = sequence.move_z(now, target, feed)
        if ignored is not None:
            return Outcome(data={"ignored": ignored})
        return Outcome(deferred=True)

    def _probe_and_start(
        self, p6: ProbeAndStart, now: float, xy_mm: tuple[float, float] | None
    ) -> Outcome:
        if not self.prepare_probe_and_start(p6):
            return Outcome(data={"mode": p6.mode})
        self.sequence.start(now, xy_mm)
        return Outcome(deferred=True)

    def prepare_probe_and_start(self, p6: ProbeAndStart) -> bool:
        """Everything ``G100 P6`` sets before its start sequence; False for the special
        modes I2/I3, which only (re)set the values and start nothing. The preflight
        (:mod:`dthc_bridge.program.check`) records the cut here instead of starting it."""
        sequence = self.sequence
        params = replace(
            sequence.params,
            touch_feed_mm_min=p6.touch_feed_mm_min,
            pierce_height_mm=p6.pierce_height_mm,
            pierce_delay_ms=p6.pierce_delay_s * 1000.0,
            cut_height_mm=p6.cut_height_mm,
        )
        sequence.set_params(params)
        if p6.mode in (2, 3):  # special modes: only (re)set the values the PLC shows
            return False
        sequence.config = replace(sequence.config, arc_ok_timeout_s=p6.arc_ok_timeout_s)
        # RosettaCNC has no T112 M6: P6 itself says the plasma tool is active.
        sequence.plasma_mode = True
        # I0: THC armed but its comparator stays off until G100 P7 A1; I1: no THC.
        sequence.set_thc(False)
        return True
