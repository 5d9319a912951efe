"""``dthc-bridge panel``: the operator panel, a web page beside the table."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from aiohttp import web

from dthc_tools.broker_options import add_broker_arguments, parse_with_broker, run_with_broker
from dthc_tools.sender.daemon_client import DaemonClient

from .connections import start_guarded_site
from .history import CutHistory
from .http_guard import (
    HostAllowList,
    TokenRefused,
    check_token,
    host_name,
    is_loopback,
    read_token_file,
)
from .hub import PanelHub
from .server import PanelLimits, build_app

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
    add_broker_arguments(parser, role="panel")
    parser.add_argument(
        "--listen", default="127.0.0.1:8080",
        help="HOST:PORT to serve on (default localhost only; anything else needs a token)",
    )  # fmt: skip
    parser.add_argument(
        "--token-file", type=Path,
        help=f"a file (mode 600) holding the panel's token (or the {TOKEN_ENV} environment "
        "variable), at least 128 random bits; required beyond localhost, where every "
        "endpoint needs it",
    )  # fmt: skip
    parser.add_argument(
        "--allow-host", action="append", default=[], type=_allowed_name, metavar="NAME",
        help="a Host name the panel is reached by, besides localhost and the --listen host "
        "(repeatable; e.g. the shop PC's name, or a reverse proxy's); any other Host is "
        "answered 421, and a name beyond localhost needs a token",
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


def _allowed_name(text: str) -> str:
    """An --allow-host: a name or address, without scheme or port."""
    name = host_name(text)
    bare = text.strip().lower().strip("[]").rstrip(".")
    if not name or "/" in text or name != bare:
        raise argparse.ArgumentTypeError(f"expected a host name without port, got {text!r}")
    return name


def _token(args: argparse.Namespace) -> str | None:
    """The token (TokenRefused: too short, or a file others may read; OSError: no file)."""
    if args.token_file is not None:
        return read_token_file(args.token_file)
    token = os.environ.get(TOKEN_ENV, "").strip()
    return check_token(token, TOKEN_ENV) if token else None


def _access(args: argparse.Namespace, host: str) -> tuple[HostAllowList, str | None]:
    """The Host names served and the token; TokenRefused when the panel must not start."""
    allowed = HostAllowList.build(host, args.allow_host)
    token = _token(args)
    if token is None and not (is_loopback(host) and allowed.loopback_only):
        beyond = [n for n in sorted(allowed.names) if not is_loopback(n)] or [host]
        raise TokenRefused(
            f"--listen {args.listen}: beyond localhost ({', '.join(beyond)}) every endpoint "
            f"needs a token (--token-file FILE or {TOKEN_ENV})"
        )
    return allowed, token


async def serve(args: argparse.Namespace) -> int:
    host, port = parse_listen(args.listen)
    try:
        allowed, token = _access(args, host)
    except TokenRefused as exc:  # one line, before anything starts
        print(f"dthc-bridge panel: {exc}", file=sys.stderr)
        return 2
    client = DaemonClient(
        args.broker_settings, base_topic=args.base_topic, board_id=args.board_id,
        timeout_s=CONTROL_TIMEOUT_S, role="panel",
    )  # fmt: skip
    hub = PanelHub(client, CutHistory(args.history))
    limits = PanelLimits()
    app = build_app(hub, token=token, allowed=allowed, limits=limits)
    runner = web.AppRunner(app, access_log=None, shutdown_timeout=2.0)
    server: asyncio.Server | None = None
    await runner.setup()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        async with client.connected():
            server, _pool = await start_guarded_site(runner, host, port, limits.connections)
            links = asyncio.create_task(hub.watch_links())
            bound = server.sockets[0].getsockname() if server.sockets else (host, port)
            print(f"PANEL http://{_url_host(host)}:{bound[1]}/", flush=True)
            try:
                await stop.wait()
            finally:
                hub.close_pages()
                links.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await links
    finally:
        if server is not None:
            server.close()  # no new connections; the runner ends those still open
        await runner.cleanup()
        if server is not None:
            await server.wait_closed()
    return 0


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def main(argv: Sequence[str] | None = None, *, prog: str = "dthc-bridge panel") -> int:
    args = parse_with_broker(build_parser(prog), argv)
    # OSError: the port is taken, the token or password file is missing.
    return run_with_broker(prog, args, serve(args), OSError)
