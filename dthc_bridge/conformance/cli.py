"""``dthc-bridge conformance LINK``: the command line of the suite.

Z moves and the torch relay may be live on the bench, so the motion window must be
confirmed: ``--yes`` confirms it up front; otherwise, on a terminal, the operator is asked;
with neither, the command refuses to run (exit status 2) before opening the link.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Callable
from typing import TextIO

from .options import ConformanceOptions
from .report import CheckResult, SuiteReport
from .suite import CHECK_NAMES, run_suite

__all__ = ["EXIT_FAILED", "EXIT_PASSED", "EXIT_USAGE", "add_arguments", "run_from_args"]

EXIT_PASSED = 0
EXIT_FAILED = 1  # at least one check failed
EXIT_USAGE = 2  # bad options, or the motion window was not confirmed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the conformance command's arguments to ``parser`` (a subcommand's parser)."""
    d = ConformanceOptions(link="")
    parser.add_argument(
        "link", metavar="LINK", help="the board: /dev/..., socket://HOST:PORT or usb://VID:PID"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--yes", action="store_true", help="confirm the motion window without asking"
    )
    parser.add_argument(
        "--interactive", action="store_true",
        help="ask the operator to toggle each input and to press reset (needs a terminal)",
    )  # fmt: skip
    parser.add_argument(
        "--home", action="store_true",
        help="run the homing cycle (z_home_cycle): Z goes up to its home switch, beyond the "
        "motion window; for a board whose home switch (Z_LIMIT_MAX) is wired",
    )  # fmt: skip
    m = parser.add_argument_group("motion window (every Z move stays inside it)")
    m.add_argument(
        "--z-window-mm", type=float, default=d.z_window_mm,
        help="Z moves at most this far either side of the reference position (default %(default)s)",
    )  # fmt: skip
    m.add_argument(
        "--probe-travel-mm", type=float,
        help="the probe's max travel, at most the window (default: the window less 0.5 mm)",
    )  # fmt: skip
    m.add_argument(
        "--start-z-mm", type=float,
        help="first move to this absolute Z (the reference position); e.g. just above a plate "
        "of known height, as on the mock board",
    )  # fmt: skip
    m.add_argument("--feed-mm-s", type=float, default=d.feed_mm_s, help="feed of Z moves")
    m.add_argument(
        "--probe-feed-mm-s", type=float, default=d.probe_feed_mm_s, help="feed of the probe"
    )
    s = parser.add_argument_group("safety checks")
    s.add_argument("--lease-ms", type=int, default=d.lease_ms, help="lease used by the lease check")
    s.add_argument(
        "--allow-torch-relay", action="store_true",
        help="let the lease check switch the torch relay on (default: it watches ohmic "
        "sensing drop instead; never with a plasma cutter connected)",
    )  # fmt: skip
    s.add_argument(
        "--reset-signal-pid", type=int, metavar="PID",
        help="reset the board by sending SIGUSR2 to PID (the mock board process)",
    )  # fmt: skip
    s.add_argument(
        "--input-timeout-s", type=float, default=d.input_timeout_s,
        help="interactive: time per input to toggle it",
    )  # fmt: skip
    t = parser.add_argument_group("telemetry and timing")
    t.add_argument("--telemetry-s", type=float, default=d.telemetry_s, help="measuring time")
    t.add_argument("--rtt-queries", type=int, default=d.rtt_queries, help="STATUS queries timed")
    t.add_argument(
        "--rtt-limit-ms", type=float, default=d.rtt_limit_ms, help="limit of the p99 round trip"
    )
    t.add_argument(
        "--ack-timeout-ms", type=float, default=d.ack_timeout_ms, help="wait per attempt"
    )
    t.add_argument("--baudrate", type=int, default=d.baudrate, help="serial ports only")
    parser.add_argument(
        "--only",
        metavar="CHECK[,CHECK]",
        default="",
        help="run only these checks (with the handshake and set-up; the checks measured "
        "together with them run too), e.g. --only telemetry_gaps",
    )


def options_from_args(args: argparse.Namespace) -> ConformanceOptions:
    """ValueError naming the option when a value is out of range."""
    return ConformanceOptions(
        link=args.link,
        z_window_mm=args.z_window_mm,
        probe_travel_mm=args.probe_travel_mm,
        start_z_mm=args.start_z_mm,
        feed_mm_s=args.feed_mm_s,
        probe_feed_mm_s=args.probe_feed_mm_s,
        lease_ms=args.lease_ms,
        allow_torch_relay=args.allow_torch_relay,
        reset_signal_pid=args.reset_signal_pid,
        interactive=args.interactive,
        telemetry_s=args.telemetry_s,
        rtt_queries=args.rtt_queries,
        rtt_limit_ms=args.rtt_limit_ms,
        ack_timeout_ms=args.ack_timeout_ms,
        input_timeout_s=args.input_timeout_s,
        baudrate=args.baudrate,
        only=_only(args.only),
        home=args.home,
    )


def _only(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in CHECK_NAMES]
    if unknown:
        raise ValueError(
            f"--only: no check named {', '.join(unknown)} (checks: {', '.join(CHECK_NAMES)})"
        )
    return names


class ConsoleOperator:
    """Tells the person at the bench what to do, on stderr."""

    def __init__(self, out: TextIO) -> None:
        self._out = out

    def tell(self, text: str) -> None:
        self._out.write(f">>> {text}\n")
        self._out.flush()


def confirm_window(
    options: ConformanceOptions, *, yes: bool, stdin: TextIO, stderr: TextIO
) -> str | None:
    """None if the run may move Z; otherwise why it may not."""
    if yes:
        return None
    if not stdin.isatty():
        return (
            "refusing to run: Z and the torch relay may be live and the motion window was not "
            "confirmed (stdin is not a terminal). " + options.describe_motion() + " Pass --yes "
            "to confirm it."
        )
    stderr.write(options.describe_motion() + "\n")
    stderr.write("Is that space clear and may the suite move Z? [y/N] ")
    stderr.flush()
    answer = stdin.readline().strip().lower()
    if answer not in ("y", "yes"):
        return "not confirmed: nothing was moved"
    return None


def run_from_args(args: argparse.Namespace) -> int:
    """Run the suite as ``args`` say; print the report; the exit status (0, 1 or 2)."""
    try:
        options = options_from_args(args)
    except ValueError as exc:
        print(f"dthc-bridge conformance: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if options.interactive and not sys.stdin.isatty():
        print("dthc-bridge conformance: --interactive needs a terminal", file=sys.stderr)
        return EXIT_USAGE
    refusal = confirm_window(options, yes=args.yes, stdin=sys.stdin, stderr=sys.stderr)
    if refusal is not None:
        print(f"dthc-bridge conformance: {refusal}", file=sys.stderr)
        return EXIT_USAGE
    operator = ConsoleOperator(sys.stderr) if options.interactive else None
    as_json = bool(args.json)
    on_result = None if as_json else _live_printer(options.link)
    report = asyncio.run(run_suite(options, operator=operator, on_result=on_result))
    if as_json:
        report.write_json(sys.stdout)
    else:
        sys.stdout.write(report.board_line() + "\n" + report.summary_line() + "\n")
    return report.exit_status


def _live_printer(link: str) -> Callable[[CheckResult], None]:
    sys.stdout.write(SuiteReport(link).header_line() + "\n")
    sys.stdout.flush()

    def on_result(result: CheckResult) -> None:
        sys.stdout.write("\n".join(SuiteReport.check_lines(result)) + "\n")
        sys.stdout.flush()

    return on_result
