"""``dthc-bridge send PROGRAM.nc``: the reference sender from the command line."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from dthc_bridge.logs import configure_logging
from dthc_bridge.program.options import add_dialect_options
from dthc_tools.broker_options import add_broker_arguments, parse_with_broker, run_with_broker

from .backend import BackendError, MotionBackend, SimGantryBackend
from .console import OperatorConsole
from .daemon_client import DaemonClient
from .grbl_backend import GrblBackend
from .remote import OperatorRemote
from .sender import Sender

__all__ = ["build_parser", "main"]


def build_parser(prog: str = "dthc-bridge send") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, description="Send a G-code program to the daemon (reference sender)."
    )
    parser.add_argument("program", type=Path)
    parser.add_argument("--base-topic", default="dthc")
    parser.add_argument("--board-id", default="table1")
    add_broker_arguments(parser)
    parser.add_argument(
        "--backend", default="sim", choices=["sim", "grbl"],
        help="sim: the mock board's gantry; grbl: a grbl/grblHAL controller for X and Y",
    )  # fmt: skip
    parser.add_argument("--gantry", default="socket://127.0.0.1:7001", help="sim backend port")
    grbl = parser.add_argument_group("grbl backend")
    grbl.add_argument("--port", help="/dev/ttyUSB0, a pty, or socket://HOST:PORT (grblHAL)")
    grbl.add_argument("--baud", type=int, default=115_200)
    grbl.add_argument(
        "--streaming", default="count", choices=["count", "sync"],
        help="count: character counting (default); sync: one line per ok",
    )  # fmt: skip
    grbl.add_argument("--status-hz", type=float, default=10.0, help="status polling, 5-20 Hz")
    parser.add_argument(
        "--start-line", type=int, default=1,
        help="restart here (a G100 P0 resume point, a cut's M3): XY goes to where the lines "
        "before it end, then the program carries on",
    )  # fmt: skip
    parser.add_argument(
        "--yes-cycle-start", action="store_true",
        help="press cycle start at each G200 S1 stop after pierce (no operator)",
    )  # fmt: skip
    parser.add_argument(
        "--wait-operator", action="store_true",
        help="after an error, wait for the operator (a panel: paused motion, resume, "
        "restart, quit) instead of ending; a terminal waits anyway",
    )  # fmt: skip
    add_dialect_options(parser)
    parser.add_argument("--json", action="store_true")
    return parser


def _host_port(url: str, scheme: str) -> tuple[str, int]:
    rest = url.removeprefix(scheme)
    host, _, port = rest.rpartition(":")
    if rest == url or not host or not port.isdigit():
        raise SystemExit(f"expected {scheme}HOST:PORT, got {url!r}")
    return host, int(port)


async def _backend(args: argparse.Namespace) -> MotionBackend:
    if args.backend == "sim":
        return SimGantryBackend(*_host_port(args.gantry, "socket://"))
    if not args.port:
        raise SystemExit("--backend grbl needs --port (/dev/ttyUSB0 or socket://HOST:PORT)")
    try:
        grbl = GrblBackend(
            args.port, baudrate=args.baud, poll_hz=args.status_hz, streaming=args.streaming
        )
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    await grbl.connect()
    return grbl


async def _send(args: argparse.Namespace) -> int:
    lines = args.program.read_text().splitlines()
    daemon = DaemonClient(args.broker_settings, base_topic=args.base_topic, board_id=args.board_id)
    backend = await _backend(args)
    sender = Sender(daemon, backend, auto_cycle_start=args.yes_cycle_start)
    interactive = _interactive() and not args.json
    if interactive:
        # The console owns the terminal and says each message once, in the operator's
        # words: the log's warnings would repeat them between its redraws.
        configure_logging("error")
    console = OperatorConsole(sender, interactive=interactive, wait_operator=args.wait_operator)
    # A panel's controls: the console's actions as MQTT requests.
    remote = OperatorRemote(sender, daemon, program=str(args.program), console=console)
    try:
        async with daemon.connected():
            progress = asyncio.create_task(remote.publish_progress())
            try:
                report = await console.run_job(
                    lines, start_line=args.start_line, dialect=args.dialect, codes=args.codes
                )
            finally:
                progress.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await progress
    finally:
        await backend.close()
    if args.json:
        print(json.dumps(report.as_dict()))
    elif report.ok:
        pressed = (f", cycle start at line {', '.join(map(str, report.cycle_starts))}"
                   if report.cycle_starts else "")  # fmt: skip
        first = args.start_line if args.start_line > 1 else 1
        span = f"lines {first}-{len(lines)}" if first > 1 else f"all {len(lines)} lines"
        print(f"done: {span} of {args.program.name}, {report.cuts_started} cuts{pressed}")
    else:
        where = f"; resume from line {report.resume_from}" if report.resume_from else ""
        print(f"stopped at line {report.error_line}: {report.error}{where}")
        if report.restart_line is not None:
            print(f"restart with --start-line {report.restart_line}")
    return 0 if report.ok else 1


def _interactive() -> bool:
    return sys.stdin.isatty() and sys.stderr.isatty()


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge send") -> int:
    args = parse_with_broker(build_parser(prog), argv)
    # OSError: the program file, a password or TLS file, the backend's port.
    return run_with_broker(prog, args, _send(args), BackendError, OSError)
