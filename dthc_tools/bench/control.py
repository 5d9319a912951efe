"""``bench control``: our THC against two baselines on the same plant, in simulated time.

Per scenario, the same seeds and the same path run three times through the real cut
sequence over a :class:`~mock_device.sim.SimulatedBoard` (:class:`ClosedLoop`):

- ``ours``: :class:`~dthc_bridge.controller.thc.ThcController` as configured by default
  (it follows a steady slow-down once its voltage rise has settled: ``slow_follow``);
- ``reference``: :class:`~.reference.ReferenceThc`, the open controllers' common law;
- ``no_thc``: THC disabled (``M666``): the torch holds the probed cut height.

Only the controller differs: sequence, THC delay, target voltage (the scenario material's
cut voltage, ``G200 V``), anti-dive percentage and THC speed limit (``M667 F3000``) are the
same. Heights are the plant's ground truth (:mod:`mock_device.plant.truth`): the RMS and
max error against the cut height while the gantry moves from 0.5 s after arc transfer,
and dives (true height below half the cut height).

Paths: the scenario's ``default_program``, split into one cut per ``G0`` (each cut probes,
pierces and ends with M5), and a slow-down appended to the last cut: a straight segment
towards the middle of the part at ``--slow-percent`` of the feed, during which the sender
reports the programmed feed (a PlasmaC ``M67 E3`` velocity reduction), so velocity
anti-dive must at least hold the torch: the reference holds it to the end of the cut, ours
holds it until the voltage rise of the slower cut has settled and then follows the plate
against the voltage measured then. Phases in ``rms_by_phase``: ``delay`` (THC delay),
``active``, ``locked`` (any lock), ``slow_follow`` (ours, following a slow-down).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

from dthc_bridge.config import default_controller_configs
from dthc_bridge.controller.commands import CutParams
from dthc_bridge.controller.sequence import State
from dthc_bridge.controller.thc import Lock, ThcConfig, ThcController
from dthc_bridge.controller.words import words
from dthc_tools.sim.closed_loop import BATCH_S, ClosedLoop
from mock_device.plant import list_scenarios, load_scenario
from mock_device.plant.truth import CutStats

from .reference import ReferenceConfig, ReferenceThc
from .report import Goal, goals_block

__all__ = [
    "CONTROLLERS",
    "DEFAULT_SCENARIOS",
    "SEPARATE_SCENARIOS",
    "BenchLoop",
    "CutPlan",
    "add_arguments",
    "plan_cuts",
    "run",
    "run_controller",
    "table",
]

DEFAULT_SCENARIOS = (
    "flat_clean",
    "warped_sheet",
    "kerf_crossing",
    "noisy_hf_start",
    "painted_plate",
    "masso_warped",
)
# Ends in an arc loss by design: run and reported, but outside the goals (the cut faults
# 2 s after transfer, for every controller, with the THC active for about 1 s).
SEPARATE_SCENARIOS = ("arc_lost_midcut",)
CONTROLLERS = ("ours", "reference", "no_thc")
RMS_RATIO_GOAL = 0.6
THC_FEED_MM_MIN = 3000.0  # M667 F3000: 50 mm/s, as the controller tests use
PIERCE_DELAY_MS = 300.0
TOUCH_FEED_MM_MIN = 300.0


@dataclass(frozen=True)
class CutPlan:
    approach: str  # the rapid to the pierce point, before M3
    lines: tuple[str, ...]  # the cut's motion, torch on
    slow: tuple[str, ...] = ()  # the slowed-down tail, sent after ``lines``
    slow_feed_mm_min: float | None = None
    programmed_feed_mm_min: float | None = None


def plan_cuts(
    program: Sequence[str], *, max_path_mm: float | None = None, slow_percent: float = 50.0
) -> tuple[CutPlan, ...]:
    """One cut per ``G0`` of an absolute (G90) program, a slow-down after the last one.

    ``max_path_mm`` shortens the program (straight moves clipped, later ones dropped).
    """
    cuts: list[tuple[str, list[str]]] = []
    x = y = 0.0
    feed: float | None = None
    travelled = 0.0
    points: list[tuple[float, float]] = []
    end = (x, y)  # where the last cut line ended
    for raw in program:
        w = dict(words(raw))  # the last word of a letter counts
        g = w.get("G")
        if "X" not in w and "Y" not in w:
            continue
        if max_path_mm is not None and travelled >= max_path_mm:
            break
        nx, ny = w.get("X", x), w.get("Y", y)
        if g == 0:
            cuts.append((f"G0 X{nx:g} Y{ny:g}", []))
        else:
            if not cuts:
                raise ValueError(f"cut motion before the first G0: {raw!r}")
            feed = w.get("F", feed)
            length = math.dist((x, y), (nx, ny))
            if max_path_mm is not None and g == 1 and travelled + length > max_path_mm:
                keep = (max_path_mm - travelled) / length
                nx, ny = x + (nx - x) * keep, y + (ny - y) * keep
                line = f"G1 X{nx:.3f} Y{ny:.3f}" + (f" F{feed:g}" if "F" in w else "")
                length = max_path_mm - travelled
            else:
                line = raw.strip()
            travelled += length
            cuts[-1][1].append(line)
            end = (nx, ny)
        points.append((nx, ny))
        x, y = nx, ny
    cuts = [(a, lines) for a, lines in cuts if lines]
    if not cuts or feed is None:
        raise ValueError("the program has no cut")
    plans = [CutPlan(approach, tuple(lines)) for approach, lines in cuts]
    # The slow-down: from the end of the last cut towards the middle of the part.
    cx = (min(p[0] for p in points) + max(p[0] for p in points)) / 2
    cy = (min(p[1] for p in points) + max(p[1] for p in points)) / 2
    x, y = end
    dist = math.dist((x, y), (cx, cy))
    if slow_percent < 100.0 and dist > 1.0:
        length = min(100.0, dist) if max_path_mm is None else min(50.0, dist)
        sx, sy = x + (cx - x) * length / dist, y + (cy - y) * length / dist
        slow_feed = feed * slow_percent / 100.0
        last = plans[-1]
        plans[-1] = CutPlan(
            last.approach,
            last.lines,
            (f"G1 X{sx:.3f} Y{sy:.3f} F{slow_feed:g}",),
            slow_feed,
            feed,
        )
    return tuple(plans)


class BenchLoop(ClosedLoop):
    """A ClosedLoop with a chosen THC and lock-time accounting."""

    def __init__(self, scenario: str, seed: int, thc: ThcController) -> None:
        super().__init__(scenario, seed=seed)
        self.sequence.thc = thc
        self.cutting_s = 0.0
        self.locked_s = 0.0
        self.lock_s: dict[str, float] = {}
        self.cut_height_mm = self.plant.scenario.material.cut_height_mm
        # Per phase: [batches, sum of squared height errors], sampled at each batch end
        # while the gantry moves in CUTTING: where the error comes from.
        self.phase_err: dict[str, list[float]] = {}

    def _record(self) -> None:
        super()._record()
        sequence = self.sequence
        if sequence.state is State.CUTTING:
            batch_s = BATCH_S
            self.cutting_s += batch_s
            locks = sequence.thc.locks(sequence.now)
            if locks:
                self.locked_s += batch_s
            for lock in locks:
                self.lock_s[str(lock)] = self.lock_s.get(str(lock), 0.0) + batch_s
            if self.plant.gantry.speed_mm_s > 0.0:
                phase = _phase(locks, sequence.thc.slow_target_v is not None)
                acc = self.phase_err.setdefault(phase, [0.0, 0.0])
                acc[0] += 1
                acc[1] += (self.plant.true_height_mm - self.cut_height_mm) ** 2


def _phase(locks: frozenset[Lock], slow_follow: bool) -> str:
    if Lock.DISABLED in locks:
        return "disabled"
    if Lock.FROZEN in locks:
        return "delay"  # THC delay (or arc-lost delay): the same for every controller
    if locks:
        return "locked"
    return "slow_follow" if slow_follow else "active"


@dataclass
class ControllerResult:
    cuts: list[CutStats] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    cutting_s: float = 0.0
    locked_s: float = 0.0
    lock_s: dict[str, float] = field(default_factory=dict)
    phase_err: dict[str, list[float]] = field(default_factory=dict)
    completed_cuts: int = 0
    planned_cuts: int = 0

    def as_dict(self) -> dict[str, object]:
        n = sum(c.measured_samples for c in self.cuts)
        sum2 = sum(
            c.measured_samples * c.height_rms_error_mm**2 for c in self.cuts if c.measured_samples
        )
        rms = math.sqrt(sum2 / n) if n else None
        worst = max((c.height_max_error_mm for c in self.cuts if c.measured_samples), default=None)
        lowest = min((c.min_height_mm for c in self.cuts), default=None)
        total2 = sum(err2 for _, err2 in self.phase_err.values())
        return {
            "rms_mm": None if rms is None else round(rms, 4),
            "max_mm": None if worst is None else round(worst, 3),
            "min_height_mm": None if lowest is None else round(lowest, 3),
            "dives": sum(c.dives for c in self.cuts),
            "touches": sum(c.touches for c in self.cuts),
            "cutting_s": round(self.cutting_s, 3),
            "locked_s": round(self.locked_s, 3),
            "locks_s": {k: round(v, 3) for k, v in sorted(self.lock_s.items())},
            "measured_s": round(n / 1000.0, 3),
            "rms_by_phase": {
                phase: {
                    "s": round(count * BATCH_S, 3),
                    "rms_mm": round(math.sqrt(err2 / count), 4),
                    "share_of_sq_error": round(err2 / total2, 3) if total2 else None,
                }
                for phase, (count, err2) in sorted(self.phase_err.items())
                if count
            },
            "cuts_completed": f"{self.completed_cuts}/{self.planned_cuts}",
            "errors": self.errors,
        }


def make_thc(kind: str, reference: ReferenceConfig, ours: ThcConfig | None = None) -> ThcController:
    """``ours`` runs the daemon's THC defaults unless told otherwise."""
    if kind == "reference":
        return ReferenceThc(reference)
    return ThcController(ours or default_controller_configs().thc)


def run_controller(
    scenario: str,
    seed: int,
    kind: str,
    plans: Sequence[CutPlan],
    *,
    reference: ReferenceConfig | None = None,
    ours: ThcConfig | None = None,
) -> ControllerResult:
    """Run every planned cut of ``scenario`` with one controller; ground truth per cut."""
    loop = BenchLoop(scenario, seed, make_thc(kind, reference or ReferenceConfig(), ours))
    material = load_scenario(scenario).material
    sequence = loop.sequence
    sequence.plasma_mode = True
    sequence.set_params(
        CutParams(
            touch_feed_mm_min=TOUCH_FEED_MM_MIN,
            pierce_height_mm=material.pierce_height_mm,
            pierce_delay_ms=PIERCE_DELAY_MS,
            cut_height_mm=material.cut_height_mm,
            cut_voltage_v=material.cut_voltage_v,
            ohmic=True,
        )
    )
    sequence.set_thc(kind != "no_thc", THC_FEED_MM_MIN)
    gantry = loop.plant.gantry
    gantry.feed_line("G21 G90")
    result = ControllerResult(planned_cuts=len(plans))
    for plan in plans:
        gantry.feed_line(plan.approach)
        if not loop.run_until(lambda: gantry.idle, 60.0):
            result.errors.append("approach did not finish")
            break
        # The slowed tail runs at the reduced feed while the sender keeps reporting the
        # programmed one (a PlasmaC M67 E3 velocity reduction).
        loop.reported_feed_mm_min = plan.programmed_feed_mm_min if plan.slow else None
        started = loop.m3()
        ok = started.ok and loop.move(*plan.lines, *plan.slow, max_s=600.0)
        ended = loop.m5()
        if ok and ended.ok:
            result.completed_cuts += 1
        else:
            result.errors.append(started.error or sequence.error or ended.error or "cut incomplete")
            gantry.clear()
            gantry.resume()
            loop.request("rearm")
            loop.run_until(lambda: loop.plant.zaxis.is_idle, 10.0)
    loop.close()
    result.cuts = list(loop.plant.truth.summary().cuts)
    result.cutting_s = loop.cutting_s
    result.locked_s = loop.locked_s
    result.lock_s = loop.lock_s
    result.phase_err = loop.phase_err
    return result


def _merge(results: Sequence[ControllerResult]) -> ControllerResult:
    merged = ControllerResult()
    for r in results:
        merged.cuts += r.cuts
        merged.errors += r.errors
        merged.cutting_s += r.cutting_s
        merged.locked_s += r.locked_s
        for lock, seconds in r.lock_s.items():
            merged.lock_s[lock] = merged.lock_s.get(lock, 0.0) + seconds
        for phase, (count, err2) in r.phase_err.items():
            acc = merged.phase_err.setdefault(phase, [0.0, 0.0])
            acc[0] += count
            acc[1] += err2
        merged.completed_cuts += r.completed_cuts
        merged.planned_cuts += r.planned_cuts
    return merged


def run_scenario(
    scenario: str,
    seeds: Sequence[int],
    *,
    max_path_mm: float | None = None,
    slow_percent: float = 50.0,
    reference: ReferenceConfig | None = None,
    ours: ThcConfig | None = None,
    controllers: Sequence[str] = CONTROLLERS,
) -> dict[str, object]:
    program = load_scenario(scenario).default_program
    plans = plan_cuts(program, max_path_mm=max_path_mm, slow_percent=slow_percent)
    figures: dict[str, dict[str, object]] = {}
    for kind in controllers:
        runs = [
            run_controller(scenario, seed, kind, plans, reference=reference, ours=ours)
            for seed in seeds
        ]
        figures[kind] = _merge(runs).as_dict()
    mine, ref = figures.get("ours"), figures.get("reference")
    ratio: float | None = None
    if mine and ref and isinstance(mine["rms_mm"], float) and isinstance(ref["rms_mm"], float):
        ratio = round(mine["rms_mm"] / ref["rms_mm"], 3) if ref["rms_mm"] > 0 else None
    in_goals = scenario not in SEPARATE_SCENARIOS
    entry: dict[str, object] = {
        "scenario": scenario,
        "seeds": list(seeds),
        "cuts": len(plans),
        "path": [[p.approach, *p.lines, *p.slow] for p in plans],
        "slow_down": (
            None
            if plans[-1].slow_feed_mm_min is None
            else {
                "feed_mm_min": plans[-1].slow_feed_mm_min,
                "reported_feed_mm_min": plans[-1].programmed_feed_mm_min,
            }
        ),
        **figures,
        "rms_ratio": ratio,
        "in_goals": in_goals,
    }
    if not in_goals:
        entry["note"] = "ends in an arc loss by design: reported, outside the goals"
    elif ratio is not None and mine is not None:
        entry["pass"] = ratio <= RMS_RATIO_GOAL and mine["dives"] == 0
    return entry


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenarios",
        default=",".join((*DEFAULT_SCENARIOS, *SEPARATE_SCENARIOS)),
        help="comma-separated scenario names (default: every cut scenario, arc_lost_midcut"
        " reported separately)",
    )
    parser.add_argument("--seeds", default="1,2,3", help="comma-separated plant seeds")
    parser.add_argument(
        "--max-path-mm", type=float, help="shorten each program to this cut length (quick runs)"
    )
    parser.add_argument(
        "--slow-percent", type=float, default=50.0,
        help="feed of the slow-down segment, percent of the programmed feed (100: none)",
    )  # fmt: skip
    parser.add_argument(
        "--ours", metavar="FIELD=VALUE,...",
        help="change our ThcConfig for this run (e.g. kp_per_s=25,deadband_v=0.15)",
    )  # fmt: skip
    parser.add_argument(
        "--reference-void-cycles", type=float, default=2.0,
        help="reference void threshold = 500 V/s x period x this (plasmac's code: 2)",
    )  # fmt: skip


def run(
    args: argparse.Namespace, progress: Callable[[str], None] | None = None
) -> dict[str, object]:
    names = [s.strip() for s in str(args.scenarios).split(",") if s.strip()]
    known = set(list_scenarios())
    unknown = [n for n in names if n not in known]
    if unknown:
        raise SystemExit(f"unknown scenario(s): {', '.join(unknown)}; known: {sorted(known)}")
    seeds = [int(s) for s in str(args.seeds).split(",") if s.strip()]
    reference = ReferenceConfig(void_threshold_cycles=args.reference_void_cycles)
    t0 = time.perf_counter()
    scenarios = []
    for name in names:
        if progress is not None:
            progress(name)
        scenarios.append(
            run_scenario(
                name, seeds, max_path_mm=args.max_path_mm, slow_percent=args.slow_percent,
                reference=reference, ours=_ours_config(args.ours),
            )
        )  # fmt: skip
    counted = [s for s in scenarios if s["in_goals"]]
    ratios = [s["rms_ratio"] for s in counted if isinstance(s["rms_ratio"], float)]
    worst = max(ratios) if ratios else None
    dives = {kind: sum(_dives(s, kind) for s in counted) for kind in CONTROLLERS}
    all_dives = {kind: sum(_dives(s, kind) for s in scenarios) for kind in CONTROLLERS}
    goals = [
        Goal("rms_ratio_every_scenario", worst, RMS_RATIO_GOAL, at_most=True),
        Goal("dives", float(dives["ours"]), 0, at_most=True),
    ]
    return {
        "seeds": seeds,
        "reference": {
            "deadband_v": reference.deadband_v,
            "gain_mm_s_per_v": reference.gain_mm_s_per_v,
            "void_threshold_v_per_sample_at_1khz": reference.void_slope_v_s
            * reference.void_threshold_cycles
            / 1000.0,
            "void_on_samples": reference.void_on_samples,
            "void_off_samples": reference.void_off_samples,
            "anti_dive_percent": [90.0, 99.0],
        },
        "thc_speed_limit_mm_s": THC_FEED_MM_MIN / 60.0,
        "scenarios": scenarios,
        "worst_rms_ratio": worst,
        "total_dives": dives["ours"],
        "total_dives_by_controller": dives,
        "dives_including_separate": all_dives,
        "elapsed_s": round(time.perf_counter() - t0, 2),
        "goals": goals_block(goals),
    }


def _dives(scenario: dict[str, object], kind: str) -> int:
    figures = scenario[kind]
    assert isinstance(figures, dict)
    return int(figures["dives"])


def _ours_config(spec: str | None) -> ThcConfig | None:
    """``kp_per_s=25,deadband_v=0.15`` -> a ThcConfig with those fields changed."""
    if not spec:
        return None
    known = {f.name for f in fields(ThcConfig)}
    types = {f.name: f.type for f in fields(ThcConfig)}
    values: dict[str, Any] = {}
    for item in spec.split(","):
        key, _, value = item.partition("=")
        key = key.strip()
        if key not in known:
            raise SystemExit(f"--ours: unknown ThcConfig field {key!r}; known: {sorted(known)}")
        kind = types[key]  # a string: thc.py has postponed annotations
        if kind == "bool":
            values[key] = value.strip().lower() in ("1", "true", "yes", "on")
        elif kind == "int":
            values[key] = int(value)
        else:
            values[key] = float(value)
    return replace(ThcConfig(), **values)


def table(report: dict[str, object]) -> str:
    """The per-scenario comparison as a fixed-width table."""
    head = (
        f"{'scenario':<16}{'ours rms/max':>16}{'ref rms/max':>16}{'no-THC rms/max':>18}"
        f"{'ratio':>8}{'dives o/r/n':>13}{'locked o/r s':>14}"
    )
    lines = [head, "-" * len(head)]
    scenarios = report["scenarios"]
    assert isinstance(scenarios, list)
    for s in scenarios:

        def pair(kind: str, s: dict[str, object] = s) -> str:
            f = s[kind]
            assert isinstance(f, dict)
            return f"{f['rms_mm']}/{f['max_mm']}"

        def get(kind: str, key: str, s: dict[str, object] = s) -> object:
            f = s[kind]
            assert isinstance(f, dict)
            return f[key]

        mark = "" if s["in_goals"] else " *"
        lines.append(
            f"{s['scenario'] + mark:<16}{pair('ours'):>16}{pair('reference'):>16}"
            f"{pair('no_thc'):>18}{s['rms_ratio']!s:>8}"
            f"{get('ours', 'dives')!s:>5}/{get('reference', 'dives')!s}"
            f"/{get('no_thc', 'dives')!s:<5}"
            f"{get('ours', 'locked_s')!s:>7}/{get('reference', 'locked_s')!s}"
        )
    if any(not s["in_goals"] for s in scenarios):
        lines.append("* outside the goals (arc lost by design)")
    lines.append(
        f"worst rms ratio: {report['worst_rms_ratio']}  dives (ours): {report['total_dives']}"
    )
    return "\n".join(lines)
