"""``dthc-bridge``: the daemon's command line."""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Sequence
from pathlib import Path

from . import conformance
from .deploy.install import (
    add_install_arguments,
    add_uninstall_arguments,
    run_install,
    run_uninstall,
)
from .logs import configure_logging

__all__ = ["main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dthc-bridge", description="Torch height control daemon for plasma tables."
    )
    parser.add_argument("--log-level", default=None, help="debug, info, warning, error")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run the daemon (systemd service)")
    run.add_argument("--config", type=Path, help="TOML configuration file")
    check = sub.add_parser("check-config", help="validate a configuration file")
    check.add_argument("file", type=Path)
    demo = sub.add_parser("demo", help="run everything end to end on embedded defaults")
    demo.add_argument("--json", action="store_true", help="print one JSON object")
    demo.add_argument(
        "--program",
        default="masso_sample",
        choices=["masso_sample", "rosetta_g100", "holes_corners"],
    )
    demo.add_argument("--plot", type=Path, help="PNG to write (default out/demo.png)")
    demo.add_argument("--broker", default="auto", choices=["auto", "mosquitto", "amqtt"])
    send = sub.add_parser("send", help="send a G-code program to the daemon (reference sender)")
    send.add_argument("program", type=Path)
    send.add_argument("--broker", default="mqtt://localhost:1883", help="mqtt://HOST:PORT")
    send.add_argument("--base-topic", default="dthc")
    send.add_argument("--board-id", default="table1")
    send.add_argument("--protocol", default="5", choices=["5", "3.1.1"])
    send.add_argument("--backend", default="sim", choices=["sim"])
    send.add_argument("--gantry", default="socket://127.0.0.1:7001", help="sim backend port")
    send.add_argument("--start-line", type=int, default=1, help="e.g. a G100 P0 resume point")
    send.add_argument("--json", action="store_true")
    conf = sub.add_parser(
        "conformance", help="check that a board honours the protocol and its safety rules"
    )
    conformance.add_arguments(conf)
    add_install_arguments(
        sub.add_parser("install-service", help="install the systemd service, udev rules, config")
    )
    add_uninstall_arguments(
        sub.add_parser("uninstall-service", help="remove the service (--purge: config and user)")
    )
    bench = sub.add_parser(
        "bench", help="benchmark suites: codec, latency, control, soak, scale (--json)"
    )
    bench.add_argument("args", nargs=argparse.REMAINDER, help="SUITE [--json] [options]")
    return parser


def _run(config_path: Path | None, log_level: str | None) -> int:
    from .config import ConfigError, load_config  # noqa: PLC0415 - pydantic only when needed
    from .daemon import run_daemon  # noqa: PLC0415

    try:
        config = load_config(config_path)
    except ConfigError as exc:
        print(f"dthc-bridge: {exc}", file=sys.stderr)
        return 2
    configure_logging(log_level or config.logging.level, json=config.logging.json_logs)
    return asyncio.run(run_daemon(config))


def _check(path: Path) -> int:
    from .config import ConfigError, load_config  # noqa: PLC0415

    try:
        config = load_config(path)
    except ConfigError as exc:
        print(f"invalid: {exc}", file=sys.stderr)
        return 1
    print(f"ok: {path} (board {config.board.link}, broker {config.mqtt.host}:{config.mqtt.port})")
    return 0


def _host_port(url: str, scheme: str) -> tuple[str, int]:
    rest = url.removeprefix(scheme)
    host, _, port = rest.rpartition(":")
    if rest == url or not host or not port.isdigit():
        raise SystemExit(f"expected {scheme}HOST:PORT, got {url!r}")
    return host, int(port)


async def _send(args: argparse.Namespace) -> int:
    import json  # noqa: PLC0415

    from .sender import DaemonClient, Sender, SimGantryBackend  # noqa: PLC0415

    host, port = _host_port(args.broker, "mqtt://")
    gantry_host, gantry_port = _host_port(args.gantry, "socket://")
    lines = args.program.read_text().splitlines()
    daemon = DaemonClient(
        host, port, base_topic=args.base_topic, board_id=args.board_id, protocol=args.protocol
    )
    backend = SimGantryBackend(gantry_host, gantry_port)
    async with daemon.connected():
        report = await Sender(daemon, backend).run(lines, start_line=args.start_line)
    await backend.close()
    if args.json:
        print(json.dumps(report.as_dict()))
    elif report.ok:
        print(f"done: {report.lines_sent} lines, {report.cuts_started} cuts")
    else:
        where = f"; resume from line {report.resume_from}" if report.resume_from else ""
        print(f"stopped at line {report.error_line}: {report.error}{where}")
    return 0 if report.ok else 1


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "run":
        return _run(args.config, args.log_level)
    configure_logging(args.log_level or "warning")
    if args.command == "check-config":
        return _check(args.file)
    if args.command == "install-service":
        return run_install(args)
    if args.command == "uninstall-service":
        return run_uninstall(args)
    if args.command == "conformance":
        return conformance.run_from_args(args)
    if args.command == "demo":
        from .demo import run_demo  # noqa: PLC0415 - the demo pulls in subprocess machinery

        return run_demo(as_json=args.json, program=args.program, plot=args.plot, broker=args.broker)
    if args.command == "send":
        return asyncio.run(_send(args))
    if args.command == "bench":
        from .bench.cli import main as bench_main  # noqa: PLC0415 - only the bench needs it

        return bench_main(args.args)
    return 2


if __name__ == "__main__":
    sys.exit(main())
