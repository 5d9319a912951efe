"""``dthc-bridge send PROGRAM.nc``: the reference sender from the command line."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import aiomqtt

from dthc_bridge.program.options import add_dialect_options

from .backend import SimGantryBackend
from .daemon_client import DaemonClient
from .sender import Sender

__all__ = ["build_parser", "main"]


def build_parser(prog: str = "dthc-bridge send") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, description="Send a G-code program to the daemon (reference sender)."
    )
    parser.add_argument("program", type=Path)
    parser.add_argument("--broker", default="mqtt://localhost:1883", help="mqtt://HOST:PORT")
    parser.add_argument("--base-topic", default="dthc")
    parser.add_argument("--board-id", default="table1")
    parser.add_argument("--protocol", default="5", choices=["5", "3.1.1"])
    parser.add_argument("--backend", default="sim", choices=["sim"])
    parser.add_argument("--gantry", default="socket://127.0.0.1:7001", help="sim backend port")
    parser.add_argument("--start-line", type=int, default=1, help="e.g. a G100 P0 resume point")
    add_dialect_options(parser)
    parser.add_argument("--json", action="store_true")
    return parser


def _host_port(url: str, scheme: str) -> tuple[str, int]:
    rest = url.removeprefix(scheme)
    host, _, port = rest.rpartition(":")
    if rest == url or not host or not port.isdigit():
        raise SystemExit(f"expected {scheme}HOST:PORT, got {url!r}")
    return host, int(port)


async def _send(args: argparse.Namespace) -> int:
    host, port = _host_port(args.broker, "mqtt://")
    gantry_host, gantry_port = _host_port(args.gantry, "socket://")
    lines = args.program.read_text().splitlines()
    daemon = DaemonClient(
        host, port, base_topic=args.base_topic, board_id=args.board_id, protocol=args.protocol
    )
    backend = SimGantryBackend(gantry_host, gantry_port)
    async with daemon.connected():
        report = await Sender(daemon, backend).run(
            lines, start_line=args.start_line, dialect=args.dialect, codes=args.codes
        )
    await backend.close()
    if args.json:
        print(json.dumps(report.as_dict()))
    elif report.ok:
        print(f"done: {report.lines_sent} lines, {report.cuts_started} cuts")
    else:
        where = f"; resume from line {report.resume_from}" if report.resume_from else ""
        print(f"stopped at line {report.error_line}: {report.error}{where}")
    return 0 if report.ok else 1


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge send") -> int:
    args = build_parser(prog).parse_args(sys.argv[1:] if argv is None else argv)
    try:
        return asyncio.run(_send(args))
    except aiomqtt.MqttError as exc:
        print(f"{prog}: cannot reach the broker at {args.broker}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the program file, or the motion backend's port
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
