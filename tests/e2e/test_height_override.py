"""PlasmaC's height override end to end: mid-cut, +0.5 mm; the torch's true height (the
mock plant's truth) rises by that much within the THC's settling time, the cut completes."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize
from tests.e2e.test_broker_restart import wait_for_state

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

PROGRAM = [
    "G21 G90", "T112 M6", "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S0",
    "G0 X20 Y20", "M3", "M667 F600", "G1 X220 Y20 F1500", "M666", "M5", "G0 X0 Y0", "M30",
]  # fmt: skip


async def test_a_height_override_raises_the_true_cut_height(tmp_path: Path) -> None:
    options = StackOptions(tmp_path, broker="mosquitto")
    async with Stack(options) as stack:
        sending = asyncio.create_task(stack.send(PROGRAM))
        seen = await wait_for_state(stack, {"cutting"}, 0, 60.0)
        await asyncio.sleep(3.0)  # THC delay, target acquired, settled at the cut height
        at_s = stack.telemetry[-1]["t"]
        t0 = time.monotonic()
        answer = await stack.request("height_override", mm=0.5)
        sent_after_s = time.monotonic() - t0
        report = await asyncio.wait_for(sending, 60.0)
        result = await stack.finish(report)
    assert seen >= 0
    assert report.ok, report.error
    assert answer["height_override_mm"] == 0.5
    summary = summarize(result, options.telemetry_hz)
    assert summary["safety_violations"] == 0
    rows = [json.loads(line) for line in result.truth_path.read_text().splitlines()]
    cutting = [r for r in rows if r["torch_on"] and r["xy_speed_mm_s"] > 20.0]
    before = [r["true_height_mm"] for r in cutting if at_s - 1.0 <= r["t_s"] < at_s]
    after = [r["true_height_mm"] for r in cutting if at_s + 1.0 <= r["t_s"] < at_s + 2.0]
    assert before
    assert after
    rise = sum(after) / len(after) - sum(before) / len(before)
    base = sum(before) / len(before)
    reached = [r["t_s"] for r in cutting if r["t_s"] > at_s and r["true_height_mm"] >= base + 0.45]
    settled = round(reached[0] - at_s, 3) if reached else None  # 90 % of the step
    figures = {"step_mm": 0.5, "rise_mm": round(rise, 3), "reached_90pct_after_s": settled,
               "request_s": round(sent_after_s, 3)}  # fmt: skip
    print(json.dumps({"height_override": figures}))
    assert rise == pytest.approx(0.5, abs=0.15)
    assert settled is not None
