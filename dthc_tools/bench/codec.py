"""``bench codec``: encode/decode messages per second, as ``python -m firmware_protocol.bench``."""

from __future__ import annotations

import argparse

from firmware_protocol import bench

from .report import Goal, goals_block

__all__ = ["DECODE_GOAL_MSGS_PER_S", "add_arguments", "run"]

DECODE_GOAL_MSGS_PER_S = 500_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--count", type=int, default=200_000, help="messages in the mix")
    parser.add_argument("--chunk", type=int, default=512, help="bytes per decoder feed")
    parser.add_argument("--repeats", type=int, default=5, help="best of this many runs")


def run(args: argparse.Namespace) -> dict[str, object]:
    figures = bench.run(args.count, args.chunk, args.repeats)
    # The header carries python and machine; keep the codec's own figures only.
    figures = {k: v for k, v in figures.items() if k not in ("python", "machine")}
    decode = figures["decode_msgs_per_s"]
    assert isinstance(decode, int)
    goals = [Goal("decode_msgs_per_s", float(decode), DECODE_GOAL_MSGS_PER_S, at_most=False)]
    return {**figures, "repeats": args.repeats, "goals": goals_block(goals)}
