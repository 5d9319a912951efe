"""``dthc-bridge demo``: the board bring-up on embedded defaults, against the mock board.

Starts the mock board as its own process on a pty, connects the daemon's link layer to it
through pyserial, and walks through what a shop does with a new board before any arc:
handshake, configuration, a touch-off probe compared with the plant's ground truth, a
second of telemetry, a torch relay check, and an unplug with the board's lease taking the
torch off by itself. Prints a summary (``--json``: one JSON object).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import firmware_protocol as fp

from .board import SENSOR_FLOAT, SENSOR_OHMIC, BoardClient
from .link import LinkState, LinkSupervisor, LinkTiming

__all__ = ["run_demo"]


async def _bring_up(pty: Path, proc: subprocess.Popen[str]) -> dict[str, Any]:
    timing = LinkTiming(lease_ms=250)
    supervisor = LinkSupervisor(str(pty), timing)
    client = BoardClient(supervisor)
    batches: list[fp.Samples] = []
    client.add_listener(lambda m: batches.append(m) if isinstance(m, fp.Samples) else None)
    task = asyncio.create_task(supervisor.run(), name="link-supervisor")
    out: dict[str, Any] = {}
    try:
        session = await supervisor.wait_online(5.0)
        info = session.info
        assert info is not None
        out["board"] = {
            "serial": info.serial,
            "boot_id": f"{info.boot_id:08x}",
            "firmware": f"{info.fw_major}.{info.fw_minor}.{info.fw_patch}",
            "protocol": f"{info.proto_major}.{info.proto_minor}",
            "sample_rate_hz": info.sample_rate_hz,
        }
        await client.configure(filter_kind=fp.FilterKind.MEDIAN3, arc_lost_ms=100)
        await client.ohmic_sense(True)
        await client.move_z(45.0, 50.0)
        t0 = time.monotonic()
        # Find the plate fast, back off, then touch again slowly: the slow contact is the one
        # that counts, with an overrun the float travel easily absorbs.
        sensors = SENSOR_OHMIC | SENSOR_FLOAT
        fast = await client.probe(feed_mm_s=25.0, max_travel_mm=40.0, sensors=sensors)
        await client.move_z(fast.stop_z_um / 1000 + 3.0, 50.0)
        probe = await client.probe(feed_mm_s=2.0, max_travel_mm=6.0, sensors=sensors)
        out["touch_off"] = {
            "result": fp.ProbeOutcome(probe.result).name,
            "sensor": "ohmic" if probe.sensor & SENSOR_OHMIC else "float",
            "contact_z_mm": probe.contact_z_um / 1000,
            "overrun_mm": (probe.contact_z_um - probe.stop_z_um) / 1000,
            "seconds": round(time.monotonic() - t0, 2),
        }
        await client.ohmic_sense(False)
        await client.move_z(probe.stop_z_um / 1000 + 25.0, 50.0)
        batches.clear()
        await asyncio.sleep(1.0)
        rtts = []
        for _ in range(50):
            t = time.perf_counter()
            await client.status()
            rtts.append((time.perf_counter() - t) * 1e3)
        steps = [(b.t0_us - a.t0_us) for a, b in itertools.pairwise(batches)]
        out["telemetry"] = {
            "batches_per_s": len(batches),
            "samples_per_s": sum(len(b.samples_cv) for b in batches),
            "batch_interval_us": statistics.median(steps) if steps else None,
            "status_rtt_ms_p50": round(statistics.median(rtts), 3),
            "status_rtt_ms_max": round(max(rtts), 3),
        }
        await client.torch(True)
        torch_on = bool((await client.status()).status & fp.StatusBit.TORCH_ON)
        # Pull the cable with the torch relay closed: the board must drop it by itself.
        proc.send_signal(signal.SIGUSR1)
        for _ in range(300):
            if supervisor.state is not LinkState.ONLINE:
                break
            await asyncio.sleep(0.01)
        await supervisor.wait_online(10.0)
        status = await client.status()
        out["unplug"] = {
            "torch_on_before": torch_on,
            "torch_on_after": bool(status.status & fp.StatusBit.TORCH_ON),
            "lease_fault_latched": bool(status.faults & (1 << fp.FaultCode.LEASE_EXPIRED)),
            "reconnects": supervisor.stats.reconnects,
        }
        await client.fault_reset()
        out["link"] = supervisor.stats.as_dict()
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    return out


def run_demo(*, as_json: bool = False) -> int:
    with tempfile.TemporaryDirectory(prefix="dthc-demo-") as tmp:
        pty = Path(tmp) / "dthc0"
        proc = subprocess.Popen(  # noqa: S603 - our own interpreter and module, fixed arguments
            [sys.executable, "-m", "mock_device", "--pty", str(pty), "--unplug-for", "0.5"],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            if not proc.stdout.readline().startswith("READY"):
                print("the mock board did not start", file=sys.stderr)
                return 1
            summary = asyncio.run(_bring_up(pty, proc))
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(5)
            if proc.stdout is not None:
                proc.stdout.close()
    ok = (
        summary["touch_off"]["result"] == "CONTACT"
        and summary["unplug"]["torch_on_before"]
        and not summary["unplug"]["torch_on_after"]
        and summary["unplug"]["lease_fault_latched"]
    )
    summary["passed"] = ok
    if as_json:
        print(json.dumps(summary))
    else:
        _print_summary(summary)
    return 0 if ok else 1


def _print_summary(s: dict[str, Any]) -> None:
    b, t, tel, u = s["board"], s["touch_off"], s["telemetry"], s["unplug"]
    print("dthc-bridge demo: board bring-up against the mock board (pty, pyserial)")
    print(
        f"  board      {b['serial']} fw {b['firmware']} "
        f"protocol {b['protocol']} boot {b['boot_id']}"
    )
    print(
        f"  touch-off  {t['result']} by {t['sensor']} at Z {t['contact_z_mm']:.3f} mm, "
        f"overrun {t['overrun_mm']:.3f} mm, {t['seconds']} s"
    )
    print(
        f"  telemetry  {tel['samples_per_s']} samples/s in {tel['batches_per_s']} batches, "
        f"status round trip p50 {tel['status_rtt_ms_p50']} ms, max {tel['status_rtt_ms_max']} ms"
    )
    print(
        f"  unplug     torch on before: {u['torch_on_before']}, after: {u['torch_on_after']}, "
        f"lease fault latched: {u['lease_fault_latched']}, reconnects: {u['reconnects']}"
    )
    link = s["link"]
    print(
        f"  link       {link['requests']} requests, {link['retransmits']} retransmits, "
        f"{link['timeouts']} timeouts, {link['telemetry_gaps']} telemetry gaps"
    )
    print("  result     " + ("PASS" if s["passed"] else "FAIL"))
