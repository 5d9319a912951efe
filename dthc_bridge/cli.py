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
    demo = sub.add_parser("demo", help="run the demo against the mock board")
    demo.add_argument("--json", action="store_true", help="print one JSON object")
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
    bench = sub.add_parser("bench", help="run a benchmark suite and print JSON figures")
    bench.add_argument("suite", choices=["codec"])
    bench.add_argument("--json", action="store_true")
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

        return run_demo(as_json=args.json)
    if args.command == "bench":
        from firmware_protocol import bench  # noqa: PLC0415 - only the bench command needs it

        return bench.main(["--json"] if args.json else [])
    return 2


if __name__ == "__main__":
    sys.exit(main())
