"""A PNG of a run: arc and target voltage, true torch height, and the THC's state."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["plot_run"]

ARC_TRANSFERRED = 2  # mock_device.plant.arc.ArcState.TRANSFERRED, as the truth file stores it


def _truth_rows(path: Path, every: int = 5) -> list[dict[str, Any]]:
    rows = []
    with path.open() as lines:
        for index, line in enumerate(lines):
            if index % every == 0:
                rows.append(json.loads(line))
    return rows


def plot_run(
    telemetry: list[dict[str, Any]], truth_path: Path, cut_height_mm: float, out: Path
) -> Path:
    import matplotlib  # noqa: PLC0415 - plotting is optional at import time

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    truth = _truth_rows(truth_path) if truth_path.exists() else []
    arc_on = [r for r in truth if r.get("arc_state") == ARC_TRANSFERRED]
    # Board time and daemon time differ by a constant: line up the first arc transfer with
    # the first moment the daemon saw arc OK (the pierce delay starts then).
    lit = [p for p in telemetry if p.get("state") == "pierce_delay" and "t" in p]
    offset = (arc_on[0]["t_s"] - lit[0]["t"]) if arc_on and lit else 0.0
    fig, (ax_v, ax_h, ax_s) = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    t_tel = [p["t"] + offset for p in telemetry if "t" in p]
    ax_v.plot(t_tel, [p.get("voltage_v") for p in telemetry if "t" in p], lw=0.8,
              label="arc voltage (filtered)")  # fmt: skip
    ax_v.plot(t_tel, [p.get("target_v") for p in telemetry if "t" in p], lw=1.2,
              label="target voltage")  # fmt: skip
    ax_v.set_ylabel("V")
    ax_v.legend(loc="upper right")
    ax_v.set_ylim(90, 160)
    heights = [r["true_height_mm"] if r.get("torch_on") else None for r in truth]
    ax_h.plot([r["t_s"] for r in truth], heights, lw=0.8, color="tab:green",
              label="true height (torch on)")  # fmt: skip
    ax_h.axhline(cut_height_mm, color="grey", ls="--", lw=0.8, label="cut height")
    ax_h.set_ylabel("mm")
    ax_h.set_ylim(0, max(6.0, cut_height_mm * 2.5))
    ax_h.legend(loc="upper right")
    active = [1 if p.get("state") == "cutting" and not p.get("locks") else 0 for p in telemetry]
    locked = [1 if p.get("state") == "cutting" and p.get("locks") else 0 for p in telemetry]
    ax_s.fill_between(t_tel, active[: len(t_tel)], step="post", alpha=0.5, label="THC active")
    ax_s.fill_between(t_tel, locked[: len(t_tel)], step="post", alpha=0.5, label="THC locked")
    ax_s.set_yticks([])
    ax_s.set_xlabel("s")
    ax_s.legend(loc="upper right")
    fig.suptitle("dthc-bridge demo: MASSO sample program on a warped sheet (mock board)")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
