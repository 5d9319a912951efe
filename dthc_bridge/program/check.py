"""``dthc-bridge check-program``: a preflight a user runs before the torch fires.

The program is planned exactly as the sender plans it (:class:`.plan.ProgramPlan`) and each
daemon line is applied to a real :class:`~dthc_bridge.controller.plasma.PlasmaController`
with no board behind it: plasma mode, G200 parameters, materials and THC switches change
as they would, and what the daemon would refuse is refused here with the same words. A
cut's start (``M3``, ``G100 P6``) is recorded, not run: the report lists, per cut, the
parameters in force. Z moves, probes and origins need a board, so they are only planned.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ..config import ConfigError, ControllerSettings, load_config
from ..controller.commands import (
    CommandError,
    DefineMaterial,
    ProbeAndStart,
    ProbeSurface,
    ProgramZMove,
    SelectMaterial,
    SetCutParams,
    SetWorkZ,
    TorchStart,
    TorchStop,
)
from ..controller.dialect import Dialect
from ..controller.plasma import PlasmaController, default_material
from ..controller.words import cutting_feed_mm_min
from ..materials import Material, MaterialError, MaterialStore
from .options import add_daemon_options, add_dialect_options
from .plan import (
    DaemonStep,
    DwellStep,
    MotionStep,
    ProgramPlan,
    Refused,
    Step,
    detect_dialect,
    unknown_m_codes,
)
from .xypath import PathTracer, path_entries

__all__ = ["CheckReport", "CutReport", "add_arguments", "check_program", "run_from_args"]


@dataclass
class CutReport:
    line: int
    text: str
    sequence: str  # "automatic" (the daemon's start sequence) or "relay" (the program's)
    parameters: str  # where the heights come from: material, G200, G100 P6, default, program
    material: int | None
    material_name: str | None
    pierce_height_mm: float | None  # None: a relay cut started with no Z move known
    pierce_delay_s: float
    cut_height_mm: float | None
    target_v: float | None  # None: auto voltage, sampled at the start of the cut
    feed_mm_min: float | None
    anti_dive_percent: float
    thc: bool  # on at the start, or switched on during the cut (M667, H1, M65 P2)


@dataclass
class CheckReport:
    dialect: str
    dialect_reason: str
    plasma_mode_at_start: bool = True
    cuts: list[CutReport] = field(default_factory=list)
    refused: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    path: list[dict[str, Any]] = field(default_factory=list)  # the planned XY moves, mm

    @property
    def ok(self) -> bool:
        return not self.refused

    def refuse(self, line: int, text: str, error: str) -> None:
        self.refused.append({"line": line, "text": text, "error": error})

    def as_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "dialect": self.dialect,
            "dialect_reason": self.dialect_reason,
            "plasma_mode_at_start": self.plasma_mode_at_start,
            "cuts": [asdict(cut) for cut in self.cuts],
            "refused": self.refused,
            "warnings": self.warnings,
            "path": self.path,
        }


class _Model:
    """The daemon's controller without a board: what a program's lines change."""

    def __init__(self, plan: ProgramPlan, controller: PlasmaController) -> None:
        self.plan = plan
        self.controller = controller
        self.feed_mm_min: float | None = None
        self.open_cut: CutReport | None = None
        self.material_used = False  # an M190 or a magic comment: cuts name their material
        self.g200_seen = False  # a G200 line: its parameters, not the daemon's default
        self.last_z_mm: float | None = None  # the program's last Z move (work coordinates)
        # A relay cut's pierce delay and cut height are the program's first dwell and first
        # Z move after its M3: still to be seen.
        self._relay_dwell_due = False
        self._relay_height_due = False

    def dwell(self, seconds: float) -> None:
        """A relay cut's pierce delay is the program's first dwell after its M3."""
        cut = self.open_cut
        if cut is not None and cut.sequence == "relay" and self._relay_dwell_due:
            cut.pierce_delay_s = seconds
            self._relay_dwell_due = False

    def apply(self, step: DaemonStep, report: CheckReport) -> None:
        parsed = step.parsed
        if step.feed_note:
            feed = cutting_feed_mm_min(step.line)
            self.feed_mm_min = feed
            if self.open_cut is not None and self.open_cut.feed_mm_min is None:
                self.open_cut.feed_mm_min = feed
            return
        for command in parsed.commands:
            if isinstance(command, ProgramZMove):
                self._z_move(command.z_mm)
            if isinstance(command, ProgramZMove | ProbeSurface | SetWorkZ):
                continue  # needs the board
            if isinstance(command, TorchStart | ProbeAndStart):
                self._start(step, command, report)
            elif isinstance(command, TorchStop):
                if self.open_cut is not None and self.open_cut.feed_mm_min is None:
                    self.open_cut.feed_mm_min = self.feed_mm_min  # no new feed in the cut
                self.open_cut = None
            else:
                outcome = self.controller.handle(command, 0.0)
                self.g200_seen |= isinstance(command, SetCutParams)
                if isinstance(command, SetCutParams | SelectMaterial | DefineMaterial):
                    self.material_used = isinstance(command, SelectMaterial | DefineMaterial)
                if self.open_cut is not None and self.controller.sequence.thc_enabled:
                    self.open_cut.thc = True
                self.plan.note_pins(outcome.data)

    def _z_move(self, z_mm: float) -> None:
        cut = self.open_cut
        if cut is not None and cut.sequence == "relay" and self._relay_height_due:
            cut.cut_height_mm = z_mm
            self._relay_height_due = False
        self.last_z_mm = z_mm

    def _start(
        self, step: DaemonStep, command: TorchStart | ProbeAndStart, report: CheckReport
    ) -> None:
        sequence = self.controller.sequence
        params = sequence.params
        relay = isinstance(command, TorchStart) and (command.relay or not sequence.g200_active)
        if isinstance(command, ProbeAndStart):
            if not self.controller.prepare_probe_and_start(command):
                return
            params = sequence.params
        elif not relay and not sequence.plasma_mode:
            tool = "T0 M6" if self.plan.dialect is Dialect.PLASMAC else "T112 M6"
            raise CommandError(
                "M3",
                f"not in plasma mode: the program needs {tool} before it (plasma mode at "
                "start is off: controller.plasma_mode_at_start = false, a table with other "
                "tools; --plasma-mode-at-start checks as a plasma-only table)",
            )
        if self.open_cut is not None:
            raise CommandError("M3", f"a cut is already running (from line {self.open_cut.line})")
        table = self.controller.materials
        material = table.selected if self.material_used else None
        if relay:
            source = "program"
        elif material is not None:
            source = "material"
        elif isinstance(command, ProbeAndStart):
            source = "G100 P6"
        else:
            source = "G200" if self.g200_seen else "default"
        cut = CutReport(
            line=step.source_line,
            text=step.text,
            sequence="relay" if relay else "automatic",
            parameters=source,
            material=None if material is None else material.number,
            material_name=None if material is None else material.name,
            pierce_height_mm=params.pierce_height_mm,
            pierce_delay_s=params.pierce_delay_ms / 1000.0,
            cut_height_mm=params.cut_height_mm,
            target_v=params.cut_voltage_v,
            feed_mm_min=None,  # the cut's first feed note, else the feed in force
            anti_dive_percent=params.anti_dive_percent,
            thc=sequence.thc_enabled,
        )
        if relay:
            # The program's own heights: where Z was at M3, and what follows it.
            cut.pierce_height_mm = self.last_z_mm
            cut.pierce_delay_s, cut.cut_height_mm = 0.0, cut.pierce_height_mm
            self._relay_dwell_due = self._relay_height_due = True
            if sequence.relay_pierce_delay_s > 0:  # a tube material's: the daemon waits it
                cut.pierce_delay_s = sequence.relay_pierce_delay_s
                self._relay_dwell_due = False
        report.cuts.append(cut)
        self.open_cut = cut


_STARTS = {
    Dialect.MASSO: "M3", Dialect.PLASMAC: "M3 $0", Dialect.RELAY: "M3",
    Dialect.ROSETTA: "G100 P6 or M3",
}  # fmt: skip


def check_program(
    lines: Sequence[str],
    *,
    dialect: Dialect | None = None,
    codes: Mapping[str, str] | None = None,
    materials: Mapping[int, Material] | None = None,
    inch_materials: bool = False,
    default_feed_mm_min: float = 3000.0,
    plasma_mode_at_start: bool = True,
    fallback_dialect: Dialect | None = None,
) -> CheckReport:
    """Plan ``lines`` as the sender would and apply them to a board-less controller.

    ``fallback_dialect``: the daemon's ``controller.dialect``, assumed (as the sender does)
    when the program has nothing dialect-specific."""
    if dialect is None:
        fallback = None
        if fallback_dialect is not None:
            fallback = (fallback_dialect, "the daemon's controller.dialect")
        dialect, why = detect_dialect(lines, fallback)
    else:
        why = "given"
    report = CheckReport(str(dialect), why, plasma_mode_at_start=plasma_mode_at_start)
    plan = ProgramPlan(lines, dialect, dict(codes or {}))
    controller = PlasmaController(
        materials=materials or {},
        default=default_material(default_feed_mm_min),
        inch_materials=inch_materials,
        plasma_only=plasma_mode_at_start,
    )
    controller.sequence.plasma_mode = plasma_mode_at_start
    plan.note_pins(controller.begin_program())
    model = _Model(plan, controller)
    motions: list[Step] = []  # for the M codes a cut-less program holds
    tracer = PathTracer(plan)
    for index, step in enumerate(plan.steps()):
        tracer.step(index, step)
        if isinstance(step, MotionStep):
            motions.append(step)
        if isinstance(step, Refused):
            report.refuse(step.source_line, step.text, step.error)
            continue
        if isinstance(step, DwellStep):
            model.dwell(step.seconds)
        if not isinstance(step, DaemonStep):
            continue
        try:
            model.apply(step, report)
        except CommandError as exc:
            report.refuse(step.source_line, step.text, str(exc))
    if not report.cuts and not report.refused:
        for refused in unknown_m_codes(motions):
            report.refuse(refused.source_line, refused.text, refused.error)
    if not report.cuts and not report.refused:
        report.warnings.append(
            f"no cut found: no torch start ({_STARTS[Dialect(report.dialect)]}) in the "
            "program; if it uses its own codes, map them with --code (e.g. M10=M3)"
        )
    if model.open_cut is not None:
        report.warnings.append(f"the cut from line {model.open_cut.line} is never ended (M5)")
    if plan.z_stripped:
        report.warnings.append(
            f"{plan.z_stripped} Z moves stripped (PlasmaC; #<keep-z-motion> = 1 keeps them)"
        )
    report.warnings.extend(plan.warnings)
    report.path = path_entries(tracer.segments)
    return report


# --------------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="the G-code program")
    parser.add_argument(
        "--config", type=Path, default=None,
        help="the daemon's config.toml: check as that daemon runs (its dialect, codes, "
        "materials file, inch materials, plasma mode at start, default feed)",
    )  # fmt: skip
    add_daemon_options(parser)
    add_dialect_options(parser)
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")


def _text(report: CheckReport, path: Path) -> str:
    mode = ("on (a plasma-only table: M3 needs no tool change)" if report.plasma_mode_at_start
            else "off (T112 M6 / T0 M6 before M3: a table with other tools)")  # fmt: skip
    out = [f"{path}: dialect {report.dialect} ({report.dialect_reason}); plasma mode at "
           f"start {mode}"]  # fmt: skip
    for number, cut in enumerate(report.cuts, start=1):
        source = {
            "material": f"material {cut.material} {cut.material_name!r}",
            "program": "the program's own heights",
        }.get(cut.parameters, f"{cut.parameters} parameters")
        volts = "auto voltage" if cut.target_v is None else f"{cut.target_v:g} V"
        feed = "feed ?" if cut.feed_mm_min is None else f"feed {cut.feed_mm_min:g} mm/min"
        pierce = "?" if cut.pierce_height_mm is None else f"{cut.pierce_height_mm:g}"
        cut_height = "?" if cut.cut_height_mm is None else f"{cut.cut_height_mm:g}"
        out.append(
            f"cut {number} at line {cut.line} ({cut.sequence}): {source}; pierce "
            f"{pierce} mm for {cut.pierce_delay_s:g} s; cut height {cut_height} mm; {volts}; "
            f"{feed}; anti-dive {cut.anti_dive_percent:g} %; THC {'on' if cut.thc else 'off'}"
        )
    for refused in report.refused:
        out.append(f"refused line {refused['line']}: {refused['text']!r}: {refused['error']}")
    out.extend(f"warning: {warning}" for warning in report.warnings)
    verdict = "OK" if report.ok else f"REFUSED: {len(report.refused)} line(s)"
    out.append(f"{verdict}: {len(report.cuts)} cut(s)")
    return "\n".join(out)


def run_from_args(args: argparse.Namespace) -> int:
    """Exit 0 only when nothing is refused; 2 when the files cannot be read."""
    try:
        daemon = load_config(args.config).controller if args.config else None
        lines = args.file.read_text(encoding="utf-8", errors="replace").splitlines()
        library = args.materials or (daemon.materials_file if daemon else None)
        materials = MaterialStore(library).load() if library else {}
    except (OSError, MaterialError, ConfigError) as exc:
        print(f"dthc-bridge check-program: {exc}")
        return 2
    # The options given on the command line win over the daemon's configuration.
    report = check_program(
        lines, dialect=args.dialect, materials=materials,
        codes={**(daemon.codes if daemon else {}), **args.codes},
        inch_materials=args.inch_materials or bool(daemon and daemon.materials_in_inches),
        plasma_mode_at_start=(
            args.plasma_mode_at_start if args.plasma_mode_at_start is not None
            else daemon.plasma_mode_at_start if daemon else True
        ),
        default_feed_mm_min=daemon.default_cut_feed_mm_min if daemon else 3000.0,
        # As the daemon runs it: its controller.dialect (by default, the default daemon's)
        # for a program with nothing dialect-specific in it.
        fallback_dialect=Dialect((daemon or ControllerSettings()).dialect),
    )  # fmt: skip
    print(json.dumps(report.as_dict()) if args.json else _text(report, args.file))
    return 0 if report.ok else 1
