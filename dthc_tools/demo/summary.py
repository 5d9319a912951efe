"""Per-cut summary of a run: the mock's ground truth joined with the daemon's telemetry."""

from __future__ import annotations

from typing import Any

from .stack import StackResult

__all__ = ["summarize"]


def _cutting_segments(telemetry: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    segments: list[list[dict[str, Any]]] = []
    current: list[dict[str, Any]] = []
    for point in telemetry:
        if point.get("state") == "cutting":
            current.append(point)
        elif current:
            segments.append(current)
            current = []
    if current:
        segments.append(current)
    return segments


S1_STATES = frozenset({"s1_raise", "s1_wait_cycle_start", "s1_lower"})


def _one_row_per_cut(
    spans: list[dict[str, Any]], events: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """The mock's arc-on spans as cuts: a G200 S1 cut lights twice (its pierce, then the
    relight after cycle start) and is one cut. A span is joined to the one before it when
    the daemon's sequence stopped after the pierce between their starts (board time, the
    clock of both)."""
    stops = [e["t"] for e in events if e.get("topic") == "event"
             and e.get("type") == "sequence" and e.get("state") in S1_STATES
             and isinstance(e.get("t"), int | float)]  # fmt: skip
    cuts: list[dict[str, Any]] = []
    for span in spans:
        last = cuts[-1] if cuts else None
        if last is not None and any(last["start_t_s"] <= t <= span["start_t_s"] for t in stops):
            cuts[-1] = _joined(last, span)
        else:
            cuts.append(dict(span))
    return cuts


def _joined(pierce: dict[str, Any], relit: dict[str, Any]) -> dict[str, Any]:
    """An S1 cut's two spans: burn time and dives of both, height figures of the cut."""
    return {
        **relit,
        "start_t_s": pierce["start_t_s"],
        "duration_s": pierce["duration_s"] + relit["duration_s"],
        "dives": pierce["dives"] + relit["dives"],
        "min_height_mm": min(pierce["min_height_mm"], relit["min_height_mm"]),
    }


def summarize(result: StackResult, telemetry_hz: float) -> dict[str, Any]:
    spans: list[dict[str, Any]] = result.mock_exit.get("cuts", [])
    cuts_truth = _one_row_per_cut(spans, result.events)
    segments = _cutting_segments(result.telemetry)
    period = 1.0 / telemetry_hz
    cuts = []
    for index, truth in enumerate(cuts_truth):
        segment = segments[index] if index < len(segments) else []
        targets = [p["target_v"] for p in segment if p.get("target_v") is not None]
        locked = sum(1 for p in segment if p.get("locks"))
        cuts.append(
            {
                "cut": index + 1,
                "arc_on_s": round(truth["duration_s"], 3),
                "target_v": round(sum(targets) / len(targets), 2) if targets else None,
                "height_rms_mm": round(truth["height_rms_error_mm"], 4),
                "height_max_err_mm": round(truth["height_max_error_mm"], 4),
                "min_height_mm": round(truth["min_height_mm"], 3),
                "dives": truth["dives"],
                "thc_locked_s": round(locked * period, 2),
                "thc_active_s": round((len(segment) - locked) * period, 2),
            }
        )
    errors = [] if result.report.ok else [result.report.error]
    errors += [
        f"{e.get('type')}: {e.get('reason') or e.get('code')}"
        for e in result.events
        if e.get("topic") == "event"
        and e.get("type") in ("fault", "arc_lost", "pause")
        and e.get("cause") != "stop_after_pierce"  # G200 S1: the program asked for it
    ]
    violations: dict[str, int] = result.mock_exit.get("violations", {})
    measured = [c for c in cuts if c["arc_on_s"] > 0]
    return {
        "cuts": cuts,
        "pierces": len(spans),  # arc starts: an S1 cut pierces, then relights
        "completed_cuts": sum(1 for c in cuts if c["dives"] == 0) if result.report.ok else 0,
        "safety_violations": sum(violations.values()),
        "violations": violations,
        "height_rms_mm": max((c["height_rms_mm"] for c in measured), default=None),
        "height_max_err_mm": max((c["height_max_err_mm"] for c in measured), default=None),
        "errors": errors,
        "sender": result.report.as_dict(),
        "daemon_exit_code": result.daemon_exit_code,
        "daemon_exit_s": round(result.daemon_exit_s, 3),
        "torch_on_at_exit": result.mock_exit.get("torch_on"),
    }
