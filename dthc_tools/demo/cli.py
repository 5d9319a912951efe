"""``dthc-bridge demo [--program NAME] [--json] [--plot PNG] [--broker KIND]``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from . import PROGRAMS, run_demo

__all__ = ["build_parser", "main"]


def build_parser(prog: str = "dthc-bridge demo") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, description="Run everything end to end on embedded defaults."
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--program", default="masso_sample", choices=sorted(PROGRAMS))
    parser.add_argument("--plot", type=Path, help="PNG to write (default out/demo.png)")
    parser.add_argument("--broker", default="auto", choices=["auto", "mosquitto", "amqtt"])
    return parser


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge demo") -> int:
    args = build_parser(prog).parse_args(sys.argv[1:] if argv is None else argv)
    return run_demo(as_json=args.json, program=args.program, plot=args.plot, broker=args.broker)
