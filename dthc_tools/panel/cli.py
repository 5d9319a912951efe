"""``dthc-bridge panel``: the operator panel, a web page beside the table."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

import aiomqtt
from aiohttp import web

from dthc_bridge.mqtt.broker import describe_broker_error
from dthc_tools.broker_options import BrokerOptionError, add_broker_arguments, broker_from_args
from dthc_tools.sender.daemon_client import DaemonClient

from .history import CutHistory
from .hub import PanelHub
from .server import build_app

__all__ = ["build_parser", "main"]

TOKEN_ENV = "DTHC_PANEL_TOKEN"  # noqa: S105 - the variable's name, not a token
CONTROL_TIMEOUT_S = 15.0  # a control's answer: the daemon answers at once, or says busy


def build_parser(prog: str = "dthc-bridge panel") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="The operator panel: live arc and height, THC controls, cut history.",
    )
    parser.add_argument("--base-topic", default="dthc")
    parser.add_argument("--board-id", default="table1")
    add_broker_arguments(parser)
    parser.add_argument(
        "--listen", default="127.0.0.1:8080",
        help="HOST:PORT to serve on (default localhost only; anything else needs a token)",
    )  # fmt: skip
    parser.add_argument(
        "--token-file", type=Path,
        help=f"a file holding the token controls need (or the {TOKEN_ENV} environment "
        "variable); required when listening beyond localhost",
    )  # fmt: skip
    parser.add_argument(
        "--history", type=Path, help="keep the cut history in this file (JSON lines)"
    )
    return parser


def parse_listen(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    host = host.strip("[]")
    if not host or not port.isdigit() or not 0 <= int(port) < 65536:  # 0: any free port
        raise SystemExit(f"--listen: expected HOST:PORT, got {text!r}")
    return host, int(port)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name: it may resolve to anything


def _token(args: argparse.Namespace) -> str | None:
    if args.token_file is not None:
        token = str(args.token_file.read_text()).strip()
        if not token:
            raise SystemExit(f"--token-file {args.token_file}: the file is empty")
        return token
    return os.environ.get(TOKEN_ENV, "") or None


async def serve(args: argparse.Namespace) -> int:
    host, port = parse_listen(args.listen)
    token = _token(args)
    if token is None and not is_loopback(host):
        raise SystemExit(
            f"--listen {args.listen}: beyond localhost the controls need a token "
            f"(--token-file FILE or {TOKEN_ENV})"
        )
    client = DaemonClient(
        args.broker_settings, base_topic=args.base_topic, board_id=args.board_id,
        timeout_s=CONTROL_TIMEOUT_S, role="panel",
    )  # fmt: skip
    hub = PanelHub(client, CutHistory(args.history))
    runner = web.AppRunner(build_app(hub, token=token), access_log=None, shutdown_timeout=2.0)
    await runner.setup()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        async with client.connected():
            site = web.TCPSite(runner, host, port)
            await site.start()
            links = asyncio.create_task(hub.watch_links())
            bound = runner.addresses[0] if runner.addresses else (host, port)
            print(f"PANEL http://{_url_host(host)}:{bound[1]}/", flush=True)
            try:
                await stop.wait()
            finally:
                hub.close_pages()
                links.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await links
    finally:
        await runner.cleanup()
    return 0


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge panel") -> int:
    parser = build_parser(prog)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        args.broker_settings = broker_from_args(args)
    except BrokerOptionError as exc:
        parser.error(str(exc))
    try:
        return asyncio.run(serve(args))
    except aiomqtt.MqttError as exc:
        print(f"{prog}: {describe_broker_error(exc, args.broker_settings)}", file=sys.stderr)
        return 2
    except OSError as exc:  # the port is taken, the token or password file is missing
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
