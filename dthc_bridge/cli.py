"""``dthc-bridge``: the daemon's command line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from .logs import configure_logging

__all__ = ["main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dthc-bridge", description=__doc__)
    parser.add_argument("--log-level", default="warning", help="debug, info, warning, error")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the demo against the mock board")
    demo.add_argument("--json", action="store_true", help="print one JSON object")
    bench = sub.add_parser("bench", help="run a benchmark suite and print JSON figures")
    bench.add_argument("suite", choices=["codec"])
    bench.add_argument("--json", action="store_true")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level)
    if args.command == "demo":
        from .demo import run_demo  # noqa: PLC0415 - the demo pulls in subprocess machinery

        return run_demo(as_json=args.json)
    if args.command == "bench":
        from firmware_protocol import bench  # noqa: PLC0415 - only the bench command needs it

        return bench.main(["--json"] if args.json else [])
    return 2


if __name__ == "__main__":
    sys.exit(main())
