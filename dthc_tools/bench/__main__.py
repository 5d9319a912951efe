"""``python -m dthc_tools.bench SUITE [--json] [options]``."""

from __future__ import annotations

import sys

from dthc_bridge.logs import configure_logging

from .cli import main

if __name__ == "__main__":
    configure_logging("warning")  # the link layer logs to stderr; stdout is the report's
    sys.exit(main(prog="python -m dthc_tools.bench"))
