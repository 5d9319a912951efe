"""``dthc-bridge conformance LINK``: does a board honour the protocol and its safety rules?

Runs a suite of checks against whatever board is on the other end of LINK (``/dev/...``,
``socket://HOST:PORT``, ``usb://VID:PID``), with no plasma cutter needed: handshake and
version, replies and duplicates, corrupt frames, telemetry rate/jitter/gaps and round
trip, Z velocity expiry, probe stop on contact, the probe away's stop on the release
(protocol 1.2), input events, the host lease (latched in
use, a lapse reported at rest), boot id across a reset. Every Z move stays inside a
window the operator confirms (``--yes``).

Each check reports ``passed`` True, False, or None when skipped (it could not run on this
bench, e.g. no way to reset the board); the exit status is 1 if any check failed, 0
otherwise, and 2 for bad options or an unconfirmed motion window.

The daemon's CLI wires the subcommand with :func:`add_arguments` and
:func:`run_from_args`; ``python -m dthc_bridge.conformance LINK ...`` runs it directly.
"""

from __future__ import annotations

from .cli import EXIT_FAILED, EXIT_PASSED, EXIT_USAGE, add_arguments, run_from_args
from .options import ConformanceOptions
from .report import CheckResult, SuiteReport
from .suite import CHECK_NAMES, run_suite

__all__ = [
    "CHECK_NAMES",
    "EXIT_FAILED",
    "EXIT_PASSED",
    "EXIT_USAGE",
    "CheckResult",
    "ConformanceOptions",
    "SuiteReport",
    "add_arguments",
    "run_from_args",
    "run_suite",
]
