"""``bench scale``: K tables (K daemons, K mock boards) on one broker, all cutting at once.

Figures: CPU per table (each daemon process's user+system time over the run, as a share of
one core), the broker's message rate (every message an observer subscribed to the whole
tree saw, per second), and whether every table completed its program.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import tempfile
import time
import uuid
from pathlib import Path

import aiomqtt

from dthc_bridge.mqtt.broker import BrokerSettings

from ..demo import Stack, StackOptions, program_lines
from .report import Goal, goals_block, proc_cpu_s

__all__ = ["add_arguments", "run"]

CPU_GOAL_PERCENT = 15.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tables", type=int, default=3, help="K: daemons and mock boards")
    parser.add_argument("--program", default="holes_corners")


def _daemon_cpu_s(pid: int) -> float:
    cpu = proc_cpu_s(pid)
    if cpu is None:
        raise RuntimeError(f"daemon process {pid} is gone")
    return cpu


async def _count_messages(broker: BrokerSettings, counter: list[int]) -> None:
    async with aiomqtt.Client(
        **broker.client_options(), identifier=f"scale-{uuid.uuid4().hex[:6]}"
    ) as client:
        await client.subscribe("#", qos=0)
        async for _ in client.messages:
            counter[0] += 1


async def _scale(args: argparse.Namespace, workdir: Path) -> dict[str, object]:
    lines = program_lines(args.program)
    async with contextlib.AsyncExitStack() as stacks:
        first = await stacks.enter_async_context(
            Stack(StackOptions(workdir / "t0", board_id="t0", telemetry_hz=10.0))
        )
        tables = [first]
        for k in range(1, args.tables):
            stack = Stack(StackOptions(workdir / f"t{k}", board_id=f"t{k}", telemetry_hz=10.0))
            stack.broker = first.broker  # one broker for every table
            stack.broker_shared = True
            tables.append(await stacks.enter_async_context(stack))
        counter = [0]
        observer = asyncio.create_task(_count_messages(first.broker_settings("dashboard"), counter))
        await asyncio.sleep(0.5)
        cpu0 = [_daemon_cpu_s(t.daemon.pid) for t in tables if t.daemon is not None]
        t0, messages0 = time.monotonic(), counter[0]
        reports = await asyncio.gather(*(t.send(lines) for t in tables))
        elapsed = time.monotonic() - t0
        cpu1 = [_daemon_cpu_s(t.daemon.pid) for t in tables if t.daemon is not None]
        messages = counter[0] - messages0
        observer.cancel()
        with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
            await observer
        results = [await t.finish(r) for t, r in zip(tables, reports, strict=True)]
    cpu_percent = [round(100.0 * (b - a) / elapsed, 2) for a, b in zip(cpu0, cpu1, strict=True)]
    violations = sum(sum(r.mock_exit.get("violations", {}).values()) for r in results)
    worst = max(cpu_percent)
    goals = [Goal("cpu_percent_per_table_max", worst, CPU_GOAL_PERCENT, at_most=True, unit=" %")]
    return {
        "tables": args.tables,
        "program": args.program,
        "elapsed_s": round(elapsed, 2),
        "cpu_percent_per_table": cpu_percent,
        "cpu_percent_per_table_mean": round(sum(cpu_percent) / len(cpu_percent), 2),
        "broker_messages": messages,
        "broker_messages_per_s": round(messages / elapsed, 1),
        "programs_completed": sum(1 for r in reports if r.ok),
        "pierces": sum(len(r.mock_exit.get("cuts", [])) for r in results),
        "safety_violations": violations,
        "goals": goals_block(goals),
    }


def run(args: argparse.Namespace) -> dict[str, object]:
    with tempfile.TemporaryDirectory(prefix="dthc-scale-") as tmp:
        workdir = Path(tmp)
        for k in range(args.tables):
            (workdir / f"t{k}").mkdir()
        return asyncio.run(_scale(args, workdir))
