"""``bench soak``: minutes of cutting under link and broker faults, counting what was lost.

The whole stack runs (broker, mock board process, daemon process, sender), cutting the
holes-and-corners program over and over, while the mock corrupts and drops frames all the
time and, at set moments, is unplugged, then rebooted, and the broker is restarted. After
an error the sender re-arms and starts the program again.

Figures: requests sent, answered and lost (published while the sender stayed connected,
and never answered), requests interrupted by the sender's own broker disconnection,
unsafe torch-on time (the mock's count of torch-on time past the lease plus one sample
period), and link recoveries with their times.
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path
from typing import Any

import aiomqtt

from ..demo import Stack, StackOptions, program_lines
from ..sender import DaemonClient, DaemonError
from .report import Goal, goals_block

__all__ = ["add_arguments", "run"]

# A request unanswered this long counts as lost (the daemon's own deadline is 30 s).
REQUEST_TIMEOUT_S = 40.0


class CountingClient(DaemonClient):
    """The sender's MQTT client, counting every request's fate."""

    sent = 0
    answered = 0
    errors = 0
    lost = 0
    interrupted = 0

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        try:
            result = await super().request(name, **args)
        except DaemonError as exc:
            if "no response" in str(exc):
                CountingClient.lost += 1
            else:
                CountingClient.answered += 1
                CountingClient.errors += 1
            raise
        except aiomqtt.MqttError:
            CountingClient.interrupted += 1
            raise
        finally:
            CountingClient.sent += 1
        CountingClient.answered += 1
        return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=float, default=3.0, help="how long to cut")
    parser.add_argument("--bit-flip-rate", type=float, default=2e-5, help="per byte, board side")
    parser.add_argument("--drop-frame-rate", type=float, default=0.005, help="per board frame")
    parser.add_argument("--seed", type=int, default=7)


async def _soak(args: argparse.Namespace, workdir: Path) -> dict[str, object]:
    duration = args.minutes * 60.0
    unplug_at, reboot_at, broker_at = duration * 0.25, duration * 0.5, duration * 0.75
    mock_args = (
        "--bit-flip-rate", str(args.bit_flip_rate), "--drop-frame-rate", str(args.drop_frame_rate),
        "--unplug-at", f"{unplug_at:.1f}", "--unplug-for", "1.0", "--reboot-at", f"{reboot_at:.1f}",
    )  # fmt: skip
    for name in ("sent", "answered", "errors", "lost", "interrupted"):
        setattr(CountingClient, name, 0)
    options = StackOptions(workdir, scenario="flat_clean", seed=args.seed, mock_args=mock_args)
    lines = program_lines("holes_corners")
    runs = completed = rearms = 0
    stopped: list[str] = []
    async with Stack(options) as stack:
        t0 = time.monotonic()

        async def restart_broker() -> None:
            await asyncio.sleep(broker_at)
            await stack.broker.stop()
            await asyncio.sleep(1.0)
            await stack.broker.start()

        restarter = asyncio.create_task(restart_broker(), name="broker-restart")
        while time.monotonic() - t0 < duration:
            runs += 1
            try:
                client = stack.daemon_client(CountingClient, timeout_s=REQUEST_TIMEOUT_S)
                report = await stack.send(lines, daemon=client)
            except (aiomqtt.MqttError, DaemonError, OSError) as exc:
                stopped.append(f"sender: {exc}")
                await asyncio.sleep(0.5)
                continue
            if report.ok:
                completed += 1
                continue
            stopped.append(report.error)
            try:
                await stack.reset_motion()
                await stack.request("rearm")
                rearms += 1
            except (aiomqtt.MqttError, DaemonError, OSError) as exc:
                stopped.append(f"rearm: {exc}")
                await asyncio.sleep(0.5)
        restarter.cancel()
        result = await stack.finish()
    boards = [e for e in result.events if e.get("topic") == "board"]
    recoveries: list[float] = []
    down_at: float | None = None
    for event in boards:
        if event.get("state") != "online" and down_at is None:
            down_at = float(event["received_s"])
        elif event.get("state") == "online" and down_at is not None:
            recoveries.append(round(float(event["received_s"]) - down_at, 3))
            down_at = None
    unsafe_ms = float(result.mock_exit.get("unsafe_torch_ms", float("nan")))
    goals = [
        Goal("commands_lost", float(CountingClient.lost), 0, at_most=True),
        Goal("unsafe_torch_ms", unsafe_ms, 0, at_most=True, unit=" ms"),
    ]
    return {
        "minutes": args.minutes,
        "faults": {
            "bit_flip_rate": args.bit_flip_rate,
            "drop_frame_rate": args.drop_frame_rate,
            "unplug_at_s": unplug_at,
            "reboot_at_s": reboot_at,
            "broker_restart_at_s": broker_at,
        },
        "commands_sent": CountingClient.sent,
        "commands_answered": CountingClient.answered,
        "commands_answered_with_error": CountingClient.errors,
        "commands_lost": CountingClient.lost,
        "commands_interrupted": CountingClient.interrupted,
        "unsafe_torch_ms": unsafe_ms,
        "program_runs": runs,
        "program_runs_completed": completed,
        "rearms": rearms,
        "recoveries": len(recoveries),
        "recovery_s": recoveries,
        "pierces": len(result.mock_exit.get("cuts", [])),
        "violations": result.mock_exit.get("violations", {}),
        "stops": stopped[:20],
        "goals": goals_block(goals),
    }


def run(args: argparse.Namespace) -> dict[str, object]:
    with tempfile.TemporaryDirectory(prefix="dthc-soak-") as tmp:
        return asyncio.run(_soak(args, Path(tmp)))
