"""``dthc-bridge demo [--program NAME|PATH] [--scenario NAME] [--materials FILE]
[--inch-materials] [--plasma-mode-at-start] [--dialect NAME] [--code CODE=LINE] [--json]
[--plot PNG] [--broker KIND]``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from dthc_bridge.program.options import add_daemon_options, add_dialect_options

from . import PROGRAMS, run_demo

__all__ = ["build_parser", "main"]

SCENARIOS = sorted(
    p.stem for p in (Path(__file__).parents[2] / "mock_device" / "scenarios").glob("*.toml")
)


def build_parser(prog: str = "dthc-bridge demo") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, description="Run everything end to end on embedded defaults."
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--program",
        default="masso_sample",
        help=f"a built-in program ({', '.join(sorted(PROGRAMS))}) or a G-code file",
    )
    parser.add_argument(
        "--scenario", default=None, help="the mock's plant (default: the program's, or flat_clean)"
    )
    add_daemon_options(parser)
    add_dialect_options(parser)
    parser.add_argument("--plot", type=Path, help="PNG to write (default out/demo.png)")
    parser.add_argument("--broker", default="auto", choices=["auto", "mosquitto", "amqtt"])
    return parser


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge demo") -> int:
    parser = build_parser(prog)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.program not in PROGRAMS and not Path(args.program).is_file():
        parser.error(f"--program: {args.program!r} is neither a built-in program nor a file")
    if args.materials is not None and not args.materials.is_file():
        parser.error(f"--materials: {str(args.materials)!r} is not a file")
    return run_demo(
        as_json=args.json, program=args.program, plot=args.plot, broker=args.broker,
        scenario=args.scenario, materials=args.materials, dialect=args.dialect, codes=args.codes,
        controller={"materials_in_inches": args.inch_materials,
                    **({} if args.plasma_mode_at_start is None
                       else {"plasma_mode_at_start": args.plasma_mode_at_start})},
    )  # fmt: skip
