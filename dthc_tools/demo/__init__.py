"""``dthc-bridge demo``: the whole system on embedded defaults, end to end.

A broker (mosquitto if installed, else an embedded amqtt broker), the mock board on a pty
with a warped sheet under the torch, the daemon as its own process, and the reference
sender running the MASSO sample program from the post-processor requirements. Prints a
per-cut summary against the mock's ground truth and writes a PNG of the run.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from dthc_bridge.controller.dialect import Dialect

from .plot import plot_run
from .stack import Stack, StackOptions, StackResult
from .summary import summarize

__all__ = ["PROGRAMS", "Stack", "StackOptions", "StackResult", "program_lines", "run_demo"]

PROGRAMS = {
    "masso_sample": ("masso_warped", 3.5),
    "rosetta_g100": ("warped_sheet", 1.5),
    "holes_corners": ("flat_clean", 1.5),
    "masso_s1": ("flat_clean", 1.5),
}
TELEMETRY_HZ = 50.0


def program_lines(name: str) -> list[str]:
    """A built-in program by name, else the lines of the file ``name``."""
    if name not in PROGRAMS:
        return Path(name).read_text(encoding="utf-8", errors="replace").splitlines()
    text = resources.files("dthc_tools.demo").joinpath("programs", f"{name}.ngc").read_text()
    return text.splitlines()


@dataclass(frozen=True)
class DemoRun:
    program: str
    scenario: str
    materials: Path | None = None
    dialect: Dialect | None = None
    codes: Mapping[str, str] = field(default_factory=dict)
    controller: Mapping[str, object] = field(default_factory=dict)  # [controller] keys


async def _run(run: DemoRun, workdir: Path, broker: str) -> StackResult:
    materials = None
    if run.materials is not None:  # the daemon writes its library: work on a copy
        materials = workdir / "materials.cfg"
        shutil.copyfile(run.materials, materials)
    options = StackOptions(
        workdir, scenario=run.scenario, broker=broker, telemetry_hz=TELEMETRY_HZ,
        materials_file=materials, controller=dict(run.controller),
    )  # fmt: skip
    async with Stack(options) as stack:
        report = await stack.send(program_lines(run.program), dialect=run.dialect, codes=run.codes)
        return await stack.finish(report)


def run_demo(
    *, as_json: bool = False, program: str = "masso_sample", plot: Path | None = None,
    broker: str = "auto", scenario: str | None = None, materials: Path | None = None,
    dialect: Dialect | None = None, codes: Mapping[str, str] | None = None,
    controller: Mapping[str, object] | None = None,
) -> int:  # fmt: skip
    """The whole stack over ``program``: a built-in name or a G-code file; ``controller``:
    daemon ``[controller]`` settings (``plasma_mode_at_start``, ``materials_in_inches``)."""
    default_scenario, cut_height_mm = PROGRAMS.get(program, ("flat_clean", 1.5))
    run = DemoRun(
        program, scenario or default_scenario, materials, dialect, dict(codes or {}),
        dict(controller or {}),
    )  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="dthc-demo-") as tmp:
        result = asyncio.run(_run(run, Path(tmp), broker))
        summary = summarize(result, TELEMETRY_HZ)
        plot = plot or Path("out") / "demo.png"
        plot.parent.mkdir(parents=True, exist_ok=True)
        plot_run(result.telemetry, result.truth_path, cut_height_mm, plot)
    summary["program"] = program
    summary["scenario"] = run.scenario
    summary["dialect"] = result.report.dialect
    summary["warnings"] = result.report.warnings
    summary["cycle_starts"] = result.report.cycle_starts  # program lines: the S1 stops
    summary["plot"] = str(plot)
    ok = (
        summary["safety_violations"] == 0
        and not summary["errors"]
        and summary["completed_cuts"] == len(summary["cuts"]) > 0
        and summary["torch_on_at_exit"] is False
    )
    summary["passed"] = ok
    if as_json:
        print(json.dumps(summary))
    else:
        _print(summary)
    return 0 if ok else 1


def _print(s: dict[str, Any]) -> None:
    print(f"dthc-bridge demo: {s['program']} on {s['scenario']} (mock board, broker, daemon)")
    print(f"{'cut':>4} {'arc on s':>9} {'target V':>9} {'RMS mm':>8} {'max mm':>8} "
          f"{'dives':>6} {'locked s':>9} {'active s':>9}")  # fmt: skip
    for c in s["cuts"]:
        target = "-" if c["target_v"] is None else f"{c['target_v']:.1f}"
        print(f"{c['cut']:>4} {c['arc_on_s']:>9.2f} {target:>9} {c['height_rms_mm']:>8.3f} "
              f"{c['height_max_err_mm']:>8.3f} {c['dives']:>6} {c['thc_locked_s']:>9.2f} "
              f"{c['thc_active_s']:>9.2f}")  # fmt: skip
    if s["cycle_starts"]:
        print(f"cycle start pressed at line(s) {', '.join(map(str, s['cycle_starts']))} "
              "(G200 S1: stop after pierce)")  # fmt: skip
    errors = s["errors"] or "none"
    print(f"pierces {s['pierces']}, completed cuts {s['completed_cuts']}, "
          f"safety violations {s['safety_violations']}, errors {errors}")  # fmt: skip
    print(f"daemon stopped in {s['daemon_exit_s']} s (exit {s['daemon_exit_code']}), "
          f"torch on at exit: {s['torch_on_at_exit']}")  # fmt: skip
    print(f"plot: {s['plot']}")
    print("result: " + ("PASS" if s["passed"] else "FAIL"))
