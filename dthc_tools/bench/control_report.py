"""``bench control``'s figures: per scenario, per controller, per seed; ratios and goals.

The goals are judged against LinuxCNC's real plasmac (:mod:`.plasmac`), per scenario and
per seed (the worst seed counts, not the mean), over every scenario inside the goals
(issue 35): ours with the material's voltage ≤ 0.4 x plasmac's RMS height error and
≤ 0.5 x its max error; ours with auto voltage against plasmac's auto volts ≤ 0.5 and ≤ 0.6;
no dive, no pause that plasmac does not make as well. The open controllers' law as we
re-wrote it (``reference``) stays as a second baseline with its own goal (ours ≤ 0.6 x its
RMS). Beside them: each controller's voltage at cut height against the plant's true one
(``target_error_v``: auto voltage's estimate, and ours' height-window reference), and the
height window on :data:`WINDOW_SCENARIO` (a cut voltage 15 V too low: ours must stop the
dive before the plate, through the fault path, naming the window).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .cuts import ControllerResult, CutPlan, merge
from .report import Goal, goals_block

__all__ = [
    "CONTROLLERS",
    "MAX_RATIO_VS_PLASMAC",
    "PAIRS",
    "RMS_RATIO_GOAL",
    "RMS_RATIO_VS_PLASMAC",
    "WINDOW_SCENARIO",
    "scenario_entry",
    "summarize",
    "table",
]

CONTROLLERS = ("ours", "ours_auto", "plasmac", "plasmac_auto", "reference", "no_thc")
PAIRS = (("ours", "plasmac"), ("ours_auto", "plasmac_auto"))  # (ours, its peer)
RMS_RATIO_GOAL = 0.6  # ours / reference, per scenario over the seeds
# Ours / plasmac, every scenario and seed: (RMS, max) per pair (issue 35).
RMS_RATIO_VS_PLASMAC = {"ours": 0.4, "ours_auto": 0.5}
MAX_RATIO_VS_PLASMAC = {"ours": 0.5, "ours_auto": 0.6}
# The height window's scenario: a cut voltage far too low; ours must end each cut there
# before the plate (no touch, the lowest true height at least WINDOW_MIN_HEIGHT_MM) with
# the window's error.
WINDOW_SCENARIO = "wrong_cut_voltage"
WINDOW_MIN_HEIGHT_MM = 0.25
WINDOW_ERROR = "THC height window"


@dataclass(frozen=True)
class _SeedFigures:
    seed: int
    rms_mm: float | None
    max_mm: float | None
    dives: int
    pauses: int

    @classmethod
    def of(cls, seed: int, r: ControllerResult) -> _SeedFigures:
        d = r.as_dict()
        return cls(seed, _num(d["rms_mm"]), _num(d["max_mm"]), _int(d["dives"]), len(r.pauses))

    def as_dict(self) -> dict[str, object]:
        return {
            "seed": self.seed,
            "rms_mm": self.rms_mm,
            "max_mm": self.max_mm,
            "dives": self.dives,
            "pauses": self.pauses,
        }


def _ratio(mine: float | None, peer: float | None) -> float | None:
    if mine is None or peer is None or peer <= 0.0:
        return None
    return round(mine / peer, 3)


def scenario_entry(
    scenario: str,
    seeds: Sequence[int],
    plans: Sequence[CutPlan],
    runs: Mapping[str, Sequence[ControllerResult]],
    *,
    in_goals: bool,
) -> dict[str, object]:
    """One scenario: merged figures per controller, per-seed RMS/max, ratios."""
    figures = {kind: merge(results).as_dict() for kind, results in runs.items()}
    seeds_of = {
        kind: [_SeedFigures.of(seed, r) for seed, r in zip(seeds, results, strict=True)]
        for kind, results in runs.items()
    }
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
        "per_seed": {kind: [f.as_dict() for f in fs] for kind, fs in seeds_of.items()},
        "in_goals": in_goals,
    }
    mine, ref = figures.get("ours"), figures.get("reference")
    if mine and ref:
        entry["rms_ratio"] = _ratio(_num(mine["rms_mm"]), _num(ref["rms_mm"]))
    for ours, peer in PAIRS:
        if ours not in seeds_of or peer not in seeds_of:
            continue
        pairs = list(zip(seeds_of[ours], seeds_of[peer], strict=True))
        rms = [_ratio(a.rms_mm, b.rms_mm) for a, b in pairs]
        mx = [_ratio(a.max_mm, b.max_mm) for a, b in pairs]
        entry[f"{ours}_vs_{peer}"] = {
            "rms_ratio_merged": _ratio(
                _num(figures[ours]["rms_mm"]), _num(figures[peer]["rms_mm"])
            ),
            "worst_rms_ratio": max((r for r in rms if r is not None), default=None),
            "worst_max_ratio": max((r for r in mx if r is not None), default=None),
            "rms_ratio_per_seed": rms,
            "max_ratio_per_seed": mx,
            "pauses_plasmac_did_not_make": sum(max(0, a.pauses - b.pauses) for a, b in pairs),
        }
    if scenario == WINDOW_SCENARIO:
        entry["note"] = "a cut voltage far too low: the height window's, outside the goals"
        entry["height_window"] = {
            kind: {
                "min_height_mm": fig["min_height_mm"],
                "touches": fig["touches"],
                "ended_by_window": sum(
                    1 for r in runs[kind] for e in r.errors if WINDOW_ERROR in e
                ),
                "errors": sorted({" ".join(e.split())[:60] for r in runs[kind] for e in r.errors}),
            }
            for kind, fig in figures.items()
        }
    elif not in_goals:
        entry["note"] = "ends in an arc loss by design: reported, outside the goals"
    return entry


def _num(value: object) -> float | None:
    if isinstance(value, int | float) and math.isfinite(value):
        return float(value)
    return None


def _int(value: object) -> int:
    assert isinstance(value, int)
    return value


def _total(scenarios: Sequence[Mapping[str, object]], kind: str, key: str) -> int:
    total = 0
    for s in scenarios:
        figures = s.get(kind)
        if isinstance(figures, Mapping):
            total += _int(figures[key])
    return total


def summarize(
    scenarios: Sequence[dict[str, object]], kinds: Sequence[str], plasmac: Mapping[str, object]
) -> dict[str, object]:
    """The report's totals and goals over the scenarios inside the goals."""
    counted = [s for s in scenarios if s["in_goals"]]
    ratios = [r for s in counted if (r := _num(s.get("rms_ratio"))) is not None]
    worst_ref = max(ratios) if ratios else None
    out: dict[str, object] = {
        "worst_rms_ratio": worst_ref,
        "total_dives": _total(counted, "ours", "dives") if "ours" in kinds else None,
        "dives_by_controller": {k: _total(counted, k, "dives") for k in kinds},
        "dives_including_separate": {k: _total(scenarios, k, "dives") for k in kinds},
        "false_locks_by_controller": {k: _total(counted, k, "false_locks") for k in kinds},
        "pauses_by_controller": {k: _total(counted, k, "pauses") for k in kinds},
    }
    goals: list[Goal] = []
    if worst_ref is not None:
        goals.append(Goal("rms_ratio_every_scenario", worst_ref, RMS_RATIO_GOAL, at_most=True))
    if "ours" in kinds:
        goals.append(Goal("dives", float(_total(counted, "ours", "dives")), 0, at_most=True))
    for ours, peer in PAIRS:
        key = f"{ours}_vs_{peer}"
        judged = counted
        blocks = [b for s in judged if isinstance(b := s.get(key), Mapping)]
        if not blocks:
            continue
        rms = [r for b in blocks if (r := _num(b["worst_rms_ratio"])) is not None]
        mx = [r for b in blocks if (r := _num(b["worst_max_ratio"])) is not None]
        unmatched = sum(_int(b["pauses_plasmac_did_not_make"]) for b in blocks)
        suffix = "" if ours == "ours" else "_auto"
        worst_rms = max(rms) if rms else None
        worst_max = max(mx) if mx else None
        out[f"worst_rms_ratio_vs_plasmac{suffix}"] = worst_rms
        out[f"worst_max_ratio_vs_plasmac{suffix}"] = worst_max
        out[f"pauses_plasmac_did_not_make{suffix}"] = unmatched
        goals += [
            Goal(f"rms_ratio_vs_plasmac{suffix}", worst_rms, RMS_RATIO_VS_PLASMAC[ours], True),
            Goal(f"max_ratio_vs_plasmac{suffix}", worst_max, MAX_RATIO_VS_PLASMAC[ours], True),
            Goal(f"pauses_plasmac_did_not_make{suffix}", float(unmatched), 0, at_most=True),
        ]
        if ours in kinds:
            goals.append(Goal(f"dives_{ours}", float(_total(judged, ours, "dives")), 0, True))
    out["target_error_v"] = _target_errors(scenarios, kinds)
    goals += _window_goals(scenarios, kinds, out)
    out["plasmac"] = dict(plasmac)
    out["goals"] = goals_block(goals)
    return out


def _target_errors(
    scenarios: Sequence[Mapping[str, object]], kinds: Sequence[str]
) -> dict[str, dict[str, object]]:
    """Per scenario and controller: its voltage at cut height against the plant's true one
    (mean signed, mean and max absolute, in volts; None where it took none)."""
    out: dict[str, dict[str, object]] = {}
    for s in scenarios:
        row: dict[str, object] = {}
        for kind in kinds:
            figures = s.get(kind)
            if isinstance(figures, Mapping) and figures.get("target_error_v") is not None:
                row[kind] = figures["target_error_v"]
        out[str(s["scenario"])] = row
    return out


def _window_goals(
    scenarios: Sequence[Mapping[str, object]], kinds: Sequence[str], out: dict[str, object]
) -> list[Goal]:
    """The height window on :data:`WINDOW_SCENARIO`: ours (fixed voltage, the one a wrong
    entry affects) ends every cut there, before the plate."""
    entry = next((s for s in scenarios if s["scenario"] == WINDOW_SCENARIO), None)
    if entry is None or "ours" not in kinds:
        return []
    window = entry.get("height_window")
    assert isinstance(window, Mapping)
    ours = window["ours"]
    out["height_window"] = dict(window)
    lowest = _num(ours["min_height_mm"])
    seeds = entry["seeds"]
    assert isinstance(seeds, list)
    return [
        Goal("height_window_touches", float(ours["touches"]), 0, at_most=True),
        Goal("height_window_min_height_mm", lowest, WINDOW_MIN_HEIGHT_MM, at_most=False),
        Goal("height_window_cuts_ended", float(ours["ended_by_window"]), len(seeds), False),
    ]


def table(report: Mapping[str, object]) -> str:
    """RMS / max error (mm) per scenario and controller, then the ratios to plasmac."""
    scenarios = report["scenarios"]
    assert isinstance(scenarios, list)
    kinds = [k for k in CONTROLLERS if any(k in s for s in scenarios)]
    head = f"{'scenario':<22}" + "".join(f"{k + ' rms/max':>22}" for k in kinds)
    head += f"{'vs plasmac':>12}{'auto vs auto':>14}"
    lines = [head, "-" * len(head)]
    for s in scenarios:
        cells = []
        for k in kinds:
            f = s.get(k)
            cells.append(
                f"{f['rms_mm']}/{f['max_mm']}" + (f" d{f['dives']}" if f["dives"] else "")
                if isinstance(f, Mapping)
                else "-"
            )
        vs = s.get("ours_vs_plasmac")
        auto = s.get("ours_auto_vs_plasmac_auto")
        mark = "" if s["in_goals"] else " *"
        lines.append(
            f"{s['scenario'] + mark:<22}"
            + "".join(f"{c:>22}" for c in cells)
            + f"{_worst(vs):>12}{_worst(auto):>14}"
        )
    if any(not s["in_goals"] for s in scenarios):
        lines.append("* outside the goals (arc lost by design; a wrong cut voltage)")
    lines.append(
        "ratios: worst over seeds of ours/plasmac RMS and max error; "
        f"worst rms vs plasmac {report.get('worst_rms_ratio_vs_plasmac')}, "
        f"max {report.get('worst_max_ratio_vs_plasmac')}; auto vs auto "
        f"{report.get('worst_rms_ratio_vs_plasmac_auto')}/"
        f"{report.get('worst_max_ratio_vs_plasmac_auto')}; vs reference "
        f"{report.get('worst_rms_ratio')}; elapsed {report.get('elapsed_s')} s"
    )
    errors = report.get("target_error_v")
    if isinstance(errors, Mapping) and errors:
        lines.append("")
        lines.append("voltage at cut height, estimate - truth (V): mean / mean |e| / max |e|")
        for name, row in errors.items():
            assert isinstance(row, Mapping)
            cells = [
                f"{k} {e['mean_v']:+.2f}/{e['mean_abs_v']:.2f}/{e['max_abs_v']:.2f}"
                for k, e in row.items()
                if isinstance(e, Mapping)
            ]
            lines.append(f"  {name:<20} " + "  ".join(cells))
    window = report.get("height_window")
    if isinstance(window, Mapping):
        lines.append("")
        lines.append(f"height window ({WINDOW_SCENARIO}): lowest true height mm, touches, ended")
        for kind, w in window.items():
            assert isinstance(w, Mapping)
            lines.append(
                f"  {kind:<14} {w['min_height_mm']} mm, {w['touches']} touches,"
                f" {w['ended_by_window']} ended by the window; {'; '.join(w['errors'])}"
            )
    return "\n".join(lines)


def _worst(block: object) -> str:
    if not isinstance(block, Mapping):
        return "-"
    return f"{block['worst_rms_ratio']}/{block['worst_max_ratio']}"
