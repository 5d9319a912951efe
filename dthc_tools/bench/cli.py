"""``dthc-bridge bench SUITE [--json] [options]``: one suite, one report.

Each suite is a :class:`Suite` in :data:`SUITES`: its options, a ``run`` that returns the
suite's figures (with a ``goals`` block), and optionally a ``table`` for people. The report
adds what every suite carries: ``suite``, ``command``, ``python``, ``machine``, and
``pass`` (every goal met). ``--json`` prints it as one JSON object on one line.
``--check`` makes the exit status 1 when a goal is missed. New suites (``soak``,
``scale``) are one more entry in :data:`SUITES`.

Logging is the caller's: ``dthc-bridge`` and ``python -m dthc_tools.bench`` route
structlog to stderr (warnings and up), so stdout holds the report alone.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from dthc_bridge.logs import configure_logging, logging_configured

from . import codec, control, faults, fuzz, grbl_port, latency, panel_slow, scale, soak
from .report import print_report, report_header

__all__ = ["SUITES", "Suite", "build_parser", "main", "run_suite"]


@dataclass(frozen=True)
class Suite:
    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], dict[str, object]]
    table: Callable[[dict[str, object]], str] | None = None


def _control_run(args: argparse.Namespace) -> dict[str, object]:
    def progress(name: str) -> None:
        if not args.json:
            print(f"... {name}", file=sys.stderr, flush=True)

    return control.run(args, progress)


SUITES: dict[str, Suite] = {
    s.name: s
    for s in (
        Suite(
            "codec",
            "encode/decode messages per second (firmware_protocol.bench)",
            codec.add_arguments,
            codec.run,
        ),
        Suite(
            "latency",
            "daemon processing per batch, end to end over a pty, CPU and RSS",
            latency.add_arguments,
            latency.run,
        ),
        Suite(
            "control",
            "our THC vs the reference law and no THC, per scenario, simulated time",
            control.add_arguments,
            _control_run,
            control.table,
        ),
        Suite(
            "soak",
            "minutes of cutting under bit errors, drops, an unplug, a reboot, a broker restart",
            soak.add_arguments,
            soak.run,
        ),
        Suite(
            "faults",
            "every fault at every phase of a cut (the mock, or --board atmega2560: the firmware "
            "on the emulated Mega): torch-on, lost requests, recovery",
            faults.add_arguments,
            faults.run,
        ),
        Suite(
            "fuzz",
            "mutated frames into the daemon's pty and MQTT payloads through mosquitto, mid-cut",
            fuzz.add_arguments,
            fuzz.run,
        ),
        Suite(
            "scale",
            "K daemons and K mock boards on one broker: CPU per table, broker message rate",
            scale.add_arguments,
            scale.run,
        ),
        Suite(
            "port",
            "the grbl port: what it adds to a line's answer against a bare grbl, in one run",
            grbl_port.add_arguments,
            grbl_port.run,
        ),
        Suite(
            "panel",
            "the operator panel while N slow clients hold connections: RSS, response time",
            panel_slow.add_arguments,
            panel_slow.run,
        ),
    )
}


def build_parser(prog: str = "dthc-bridge bench") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description="Benchmark suites.")
    sub = parser.add_subparsers(dest="suite", required=True, metavar="SUITE")
    for suite in SUITES.values():
        p = sub.add_parser(suite.name, help=suite.help, description=suite.help)
        p.add_argument("--json", action="store_true", help="print one JSON object")
        p.add_argument("--check", action="store_true", help="exit 1 when a goal is missed")
        suite.add_arguments(p)
    return parser


def run_suite(
    name: str, args: argparse.Namespace, argv: Sequence[str], prog: str = "dthc-bridge bench"
) -> dict[str, object]:
    """Run one suite; the report with the common header and the overall ``pass``."""
    figures = SUITES[name].run(args)
    goals = figures.get("goals", {})
    assert isinstance(goals, Mapping)
    passed = all(bool(g["pass"]) for g in goals.values())
    return {**report_header(name, argv, prog), **figures, "pass": passed}


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge bench") -> int:
    if not logging_configured():  # called as a library: stdout is the report's alone
        configure_logging("warning")
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(prog).parse_args(argv)
    report = run_suite(args.suite, args, argv, prog)
    suite = SUITES[args.suite]
    if args.json or suite.table is None:
        print_report(report, args.json)
    else:
        print(suite.table(report))
        goals = report["goals"]
        assert isinstance(goals, Mapping)
        for name, goal in goals.items():
            verdict = "pass" if goal["pass"] else "MISS"
            print(f"goal {name}: {goal['value']} ({goal['target']}) {verdict}")
    return 1 if args.check and not report["pass"] else 0
