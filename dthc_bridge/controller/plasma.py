"""PlasmaController: applies typed commands to the cut sequence (pure, no I/O).

One place decides what each command does in each state, so G-code over MQTT, structured
requests and tests all behave alike. A command either completes at once (``Outcome``), is
answered later by the sequence (``deferred``: M3 when XY may move, M5 at safe height), or
is refused with a :class:`CommandError` that changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from .commands import (
    Command,
    CommandError,
    CycleStart,
    LegacyMode,
    OhmicTest,
    OperatingMode,
    PlasmaMode,
    ProbeAndStart,
    Rearm,
    ResumePoint,
    SelectCurrent,
    SetCutParams,
    ThcEnable,
    TorchStart,
    TorchStop,
    VelocityReduction,
    VoltageAdjust,
    VoltageMode,
)
from .sequence import CutSequence, State

__all__ = ["Outcome", "PlasmaController", "ResumeTrack"]


@dataclass(frozen=True)
class ResumeTrack:
    line: int | None
    index: int  # the how-many-th P0 of the program


@dataclass(frozen=True)
class Outcome:
    deferred: bool = False  # the sequence answers later with a CommandReply
    data: dict[str, Any] = field(default_factory=dict)
    resume_point: ResumeTrack | None = None  # a G100 P0 just marked one


class PlasmaController:
    def __init__(self, sequence: CutSequence | None = None) -> None:
        self.sequence = sequence or CutSequence()
        self.resume_points: list[ResumeTrack] = []

    @property
    def last_resume_point(self) -> ResumeTrack | None:
        return self.resume_points[-1] if self.resume_points else None

    def handle(
        self, command: Command, now: float, xy_mm: tuple[float, float] | None = None
    ) -> Outcome:
        sequence = self.sequence
        if isinstance(command, TorchStart):
            sequence.start(now, xy_mm)
            return Outcome(deferred=True)
        if isinstance(command, TorchStop):
            sequence.stop(now, xy_mm)
            return Outcome(deferred=True)
        if isinstance(command, ProbeAndStart):
            return self._probe_and_start(command, now, xy_mm)
        if isinstance(command, PlasmaMode):
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
            sequence.velocity_percent = command.percent if command.percent > 0 else 100.0
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
        elif isinstance(command, OhmicTest):
            if sequence.busy:
                raise CommandError("ohmic_test", "not during a cut")
            sequence.ohmic_test(now)
        return Outcome()

    def _probe_and_start(
        self, p6: ProbeAndStart, now: float, xy_mm: tuple[float, float] | None
    ) -> Outcome:
        sequence = self.sequence
        params = replace(
            sequence.params,
            touch_feed_mm_min=p6.touch_feed_mm_min,
            pierce_height_mm=p6.pierce_height_mm,
            pierce_delay_ms=p6.pierce_delay_s * 1000.0,
            cut_height_mm=p6.cut_height_mm,
        )
        if p6.mode in (2, 3):  # special modes: only (re)set the values the PLC shows
            sequence.set_params(params)
            return Outcome(data={"mode": p6.mode})
        sequence.set_params(params)
        sequence.config = replace(sequence.config, arc_ok_timeout_s=p6.arc_ok_timeout_s)
        # RosettaCNC has no T112 M6: P6 itself says the plasma tool is active.
        sequence.plasma_mode = True
        # I0: THC armed but its comparator stays off until G100 P7 A1; I1: no THC.
        sequence.set_thc(False)
        sequence.start(now, xy_mm)
        return Outcome(deferred=True)
