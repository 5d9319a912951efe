"""``python -m dthc_bridge.conformance LINK ...``: the suite without the daemon's CLI."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ..logs import configure_logging
from .cli import add_arguments, run_from_args

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="dthc-bridge conformance",
        description="Check that a DTHC board honours the wire protocol and its safety rules.",
    )
    parser.add_argument("--log-level", default="warning", help="debug, info, warning, error")
    add_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    return run_from_args(args)


if __name__ == "__main__":
    sys.exit(main())
