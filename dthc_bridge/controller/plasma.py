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
from ..units import MM_PER_INCH
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
from .sequence import CutSequence

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
        self.sequence.begin_program()
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

    def _in_inches(self, material: Material) -> bool:
        """Library and program materials are in the machine's units; material 0 is the
        daemon's own default, always mm."""
        return self.inch_materials and material.number != 0

    def _material_params(self, material: Material, word: str) -> CutParams:
        """The cut parameters ``material`` would put in force; refused during a cut or
        when the material is outside the controller's ranges. Changes nothing."""
        sequence = self.sequence
        sequence.require_idle(word)
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
            sequence.program_positions(material.pierce_delay_s, word)
        else:
            sequence.set_params(params or self._material_params(material, word))
        sequence.set_thc(material.thc)
        sequence.set_material_timing(
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
        """Dispatch ``command`` to the sequence method that owns it and its guard (a refusal
        raises CommandError and changes nothing)."""
        sequence = self.sequence
        if isinstance(command, TorchStart):
            sequence.start(now, xy_mm, relay=command.relay)
            return Outcome(deferred=True)
        if isinstance(command, TorchStop):
            sequence.stop(now, xy_mm)
            return Outcome(deferred=True)
        if isinstance(command, ProgramZMove):
            ignored = sequence.program_z_move(now, command)
            if ignored is not None:
                return Outcome(data={"ignored": ignored})
            return Outcome(deferred=True)
        if isinstance(command, ProbeSurface):
            sequence.probe_surface(now, command)
            return Outcome(deferred=True)
        if isinstance(command, SetWorkZ):
            return Outcome(data={"work_zero_mm": round(sequence.set_work_z(command), 3)})
        if isinstance(command, ProbeAndStart):
            if not self.prepare_probe_and_start(command):
                return Outcome(data={"mode": command.mode})
            sequence.start(now, xy_mm)
            return Outcome(deferred=True)
        if isinstance(command, PlasmaMode):
            if self.plasma_only and not command.enabled:
                return Outcome(data={"tool": command.tool, "note": TOOL_NOTE})
            sequence.set_plasma_mode(command.enabled, f"T{command.tool} M6")
        elif isinstance(command, SetCutParams):
            sequence.set_params(command.params)  # a later G200 overwrites; takes effect next cut
        elif isinstance(command, LegacyMode):
            sequence.legacy_mode()
        elif isinstance(command, ThcEnable):
            sequence.set_thc(command.enabled, command.z_feed_mm_min)
        elif isinstance(command, TorchEnable):
            sequence.enable_torch(command.enabled)
        elif isinstance(command, SelectMaterial):
            return Outcome(data=self._select_material(command))
        elif isinstance(command, DefineMaterial):
            return self._define_material(command.comment)
        elif isinstance(command, VoltageAdjust):
            sequence.adjust_voltage(command.delta_v)
            return Outcome(
                data={"target_v": sequence.target_v, "offset_v": sequence.voltage_offset_v}
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
            sequence.set_cut_voltage(None if command.auto else command.volts)
        elif isinstance(command, OperatingMode):
            sequence.set_operating_mode(command.mode)
        elif isinstance(command, VelocityReduction):
            pass  # the sender slows its motion; the THC sees the slower speed as anti-dive
        elif isinstance(command, CycleStart):
            sequence.cycle_start(now)
        elif isinstance(command, Rearm):
            sequence.rearm(now)
        elif isinstance(command, HeightOverride):
            height = sequence.step_height_override(command.step_mm, command.reset)
            return Outcome(data={"height_override_mm": height, "target_v": sequence.target_v})
        elif isinstance(command, Abort):
            return Outcome(data={"aborted": sequence.abort("stopped by the operator")})
        elif isinstance(command, ThcHold):
            ended = sequence.hold_thc(now, command.on)
            return Outcome(data={"thc_held": command.on, "cut_ended": ended})
        elif isinstance(command, OhmicTest):
            sequence.ohmic_test(now)
        elif isinstance(command, ProbeTest):
            sequence.probe_test(now)
            return Outcome(deferred=True)
        elif isinstance(command, JogZ):
            sequence.jog_z(now, command.mm, command.feed_mm_min)
            return Outcome(deferred=True)
        return Outcome()

    def _select_material(self, command: SelectMaterial) -> dict[str, Any]:
        word = command.word or f"M190 P{command.number}"
        try:
            material = self.materials.get(
                self.materials.initial if command.number == -1 else command.number, where=word
            )
        except MaterialError as exc:
            raise CommandError(word, exc.reason) from None
        data = self._use_material(material, word)
        self.materials.select(command.number)
        return data

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

    def prepare_probe_and_start(self, p6: ProbeAndStart) -> bool:
        """Everything ``G100 P6`` sets before its start sequence; False for the special
        modes I2/I3, which only (re)set the values and start nothing. The preflight
        (:mod:`dthc_bridge.program.check`) records the cut here instead of starting it."""
        return self.sequence.set_probe_and_start(p6)
