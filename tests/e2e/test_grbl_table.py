"""A table whose X and Y are on grbl: daemon + mock board (no XY speed input) + the
reference sender + an emulated grbl on a pty, its motion mirrored into the mock's plant.

The daemon's anti-dive gets the XY speed the sender measures from grbl's status reports
(the ``motion`` request). The program has corners and a slow-down (a PlasmaC velocity
reduction to 40 %): the THC must lock when the measured speed drops and work at speed.
"""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path
from typing import Any

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize
from dthc_tools.procs import die_with_parent
from dthc_tools.sender.grbl_backend import GrblBackend
from tests.e2e.test_end_to_end import assert_clean

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

FEED = 1500.0  # mm/min: 25 mm/s
PROGRAM = [
    "G21 G90",
    "G0 X20 Y20",
    "M3 $0 S1",
    "M65 P2",  # THC on
    f"G1 X70 Y20 F{FEED:g}",  # a corner at 70,20
    "G1 X70 Y50",
    "G1 X20 Y50",  # and at 70,50
    "M67 E3 Q40",  # the slow-down: the machine runs at 40 % of the programmed feed
    f"G1 X20 Y70 F{FEED:g}",
    "M67 E3 Q0",
    f"G1 X70 Y70 F{FEED:g}",
    "M5 $0",
    "G0 X100 Y20",
    "M3 $0 S1",
    "M65 P2",
    f"G1 X150 Y20 F{FEED:g}",
    "G1 X150 Y50",
    "M5 $0",
    "G0 X0 Y0",
    "M30",
]


def anti_dive_figures(truth: Path, telemetry: list[dict[str, Any]]) -> dict[str, Any]:
    """Each time the real XY speed (the plant's truth) fell below 90 % of the feed during a
    cut: how long it stayed down and how long after the fall the THC first held (velocity
    lock, or a slow-down followed at its own target). Board time on both sides."""
    threshold = 0.9 * FEED / 60
    drops: list[dict[str, Any]] = []
    down_since: float | None = None
    was_fast = False
    for line in truth.read_text().splitlines():
        row = json.loads(line)
        if not row["torch_on"]:
            down_since, was_fast = None, False
            continue
        fast = row["xy_speed_mm_s"] >= threshold
        if fast and down_since is not None:
            drops.append({"at_s": down_since, "lasted_s": row["t_s"] - down_since})
            down_since = None
        elif not fast and was_fast and down_since is None:
            down_since = row["t_s"]
        was_fast = was_fast or fast
    held = [p["t"] for p in telemetry
            if "velocity" in p.get("locks", []) or p.get("slow_target_v") is not None]  # fmt: skip
    for drop in drops:
        after = [t - drop["at_s"] for t in held if drop["at_s"] <= t <= drop["at_s"] + 1.0]
        drop["lock_after_s"] = round(min(after), 3) if after else None
        drop["at_s"], drop["lasted_s"] = round(drop["at_s"], 3), round(drop["lasted_s"], 3)
    return {"drops": drops}


async def test_a_grbl_table_cuts_with_the_anti_dive_on_the_measured_speed(
    tmp_path: Path,
) -> None:
    options = StackOptions(
        tmp_path, broker="mosquitto", motion="grbl", controller={"plasma_mode_at_start": True}
    )
    async with Stack(options) as stack:
        report = await stack.send(PROGRAM)
        result = await stack.finish(report)
    assert report.ok, report.error
    backend = stack.last_backend
    assert isinstance(backend, GrblBackend)
    summary = summarize(result, options.telemetry_hz)
    assert_clean(summary, cuts=2, rms_mm=0.3)
    assert report.cuts_started == 2
    figures = backend.figures
    assert figures.max_in_flight_bytes < backend.info.rx_buffer
    assert figures.status_reports > 20

    cutting = [p for p in result.telemetry if p.get("state") == "cutting"]
    speeds = [p for p in cutting if isinstance(p.get("xy_speed_mm_s"), float | int)]
    assert speeds, "the daemon never saw the sender's XY speed"
    slow = [p for p in speeds if p["xy_speed_mm_s"] < 0.9 * FEED / 60]
    fast = [p for p in speeds if p["xy_speed_mm_s"] >= 0.99 * FEED / 60]
    assert slow
    assert fast
    # Locked whenever the measured speed was down (velocity, or the slow-down followed at
    # its own target once steady), working at full speed.
    assert all(p["locks"] or p.get("slow_target_v") for p in slow)
    assert any("velocity" in p["locks"] for p in slow)
    assert any(not p["locks"] for p in fast)
    figures_out = anti_dive_figures(result.truth_path, result.telemetry)
    print(json.dumps({"grbl_e2e": figures_out, "cuts": report.cuts_started,
                      "status_reports": figures.status_reports,
                      "max_in_flight_bytes": figures.max_in_flight_bytes}))  # fmt: skip
    long_drops = [d for d in figures_out["drops"] if d["lasted_s"] >= 0.3]
    assert long_drops, figures_out
    assert all(d["lock_after_s"] is not None for d in long_drops), figures_out
    grbl_exit = (tmp_path / "grbl.log").read_text()
    assert '"z_words_received": 0' in grbl_exit
    assert '"spindle_words_received": 0' in grbl_exit
    assert '"rx_overflow": 0' in grbl_exit


async def test_send_drives_grbl_from_the_command_line_through_a_g200_s1_program(
    tmp_path: Path,
) -> None:
    """As a table owner runs it: ``dthc-bridge send --backend grbl --port PTY
    --yes-cycle-start``, a MASSO program that stops after each pierce runs to its end."""
    program = Path(__file__).parents[2] / "dthc_tools" / "demo" / "programs" / "masso_s1.ngc"
    options = StackOptions(tmp_path, broker="mosquitto", motion="grbl")
    async with Stack(options) as stack:
        send = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "dthc_bridge", "send", str(program), "--backend", "grbl",
            "--port", str(stack.grbl_pty), "--broker", f"mqtt://127.0.0.1:{stack.broker.port}",
            "--base-topic", stack.base, "--protocol", stack.broker.protocol,
            "--yes-cycle-start", "--json",
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            preexec_fn=die_with_parent(),
        )  # fmt: skip
        out, err = await asyncio.wait_for(send.communicate(), 120)
        result = await stack.finish()
    assert send.returncode == 0, out.decode() + err.decode()[-2000:]
    report = json.loads(out)
    assert report["ok"]
    assert report["cuts_started"] == 2
    assert report["cycle_starts"] == [8, 17]
    assert result.mock_exit["torch_on"] is False
    assert result.mock_exit["violations"] == {}
