"""``dthc-bridge``: the daemon's command line."""

from __future__ import annotations

import argparse
import asyncio
import importlib
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from . import conformance
from .deploy.install import (
    add_install_arguments,
    add_uninstall_arguments,
    run_install,
    run_uninstall,
)
from .logs import configure_logging
from .program import check as check_program

__all__ = ["TOOL_COMMANDS", "main", "missing_for_extra", "run_tool"]

DISTRIBUTION = "dthc-bridge"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dthc-bridge", description="Torch height control daemon for plasma tables."
    )
    parser.add_argument("--log-level", default=None, help="debug, info, warning, error")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run the daemon (systemd service)")
    run.add_argument("--config", type=Path, help="TOML configuration file")
    check = sub.add_parser(
        "check-config", help="validate a configuration file and the files it names"
    )
    check.add_argument("file", type=Path)
    check_program.add_arguments(
        sub.add_parser(
            "check-program", help="preflight a G-code program: cuts, parameters, refused lines"
        )
    )
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
    for name, tool in TOOL_COMMANDS.items():
        tool_parser = sub.add_parser(
            name, help=f"{tool.help} (extra '{tool.extra}')", add_help=False
        )
        tool_parser.add_argument("args", nargs=argparse.REMAINDER, help="the tool's own arguments")
    return parser


def _run(config_path: Path | None, log_level: str | None) -> int:
    import structlog  # noqa: PLC0415

    from .config import ConfigError, load_config  # noqa: PLC0415 - pydantic only when needed
    from .config_paths import check_paths  # noqa: PLC0415
    from .daemon import run_daemon  # noqa: PLC0415

    try:
        config = load_config(config_path)
    except ConfigError as exc:
        print(f"dthc-bridge: {exc}", file=sys.stderr)
        return 2
    # The files it names, now: a missing CA file would otherwise be a nameless [Errno 2]
    # on every reconnect, forever.
    problems = check_paths(config)
    fatal = [str(problem) for problem in problems if problem.fatal]
    if fatal:
        where = config_path if config_path is not None else "environment"
        print(f"dthc-bridge: {where}: " + "; ".join(fatal), file=sys.stderr)
        return 2
    configure_logging(
        log_level or config.logging.level,
        json=config.logging.json_logs,
        trace_frames=config.logging.trace_frames,
    )
    for problem in problems:
        structlog.get_logger("dthc_bridge.cli").warning(
            "config_path_warning", key=problem.key, path=str(problem.path),
            problem=problem.problem,
        )  # fmt: skip
    return asyncio.run(run_daemon(config))


def _check(path: Path) -> int:
    from .config import ConfigError, load_config  # noqa: PLC0415
    from .config_paths import check_paths  # noqa: PLC0415

    try:
        config = load_config(path)
    except ConfigError as exc:
        print(f"invalid: {exc}", file=sys.stderr)
        return 1
    problems = check_paths(config)
    for problem in problems:
        if not problem.fatal:
            print(f"warning: {path}: {problem}", file=sys.stderr)
    fatal = [str(problem) for problem in problems if problem.fatal]
    if fatal:
        print(f"invalid: {path}: " + "; ".join(fatal), file=sys.stderr)
        return 1
    print(f"ok: {path} (board {config.board.link}, broker {config.mqtt.host}:{config.mqtt.port})")
    return 0


@dataclass(frozen=True)
class ToolCommand:
    """A command of a tool package: found by module name, so the runtime imports no tool."""

    module: str  # has main(argv, prog=...) -> int
    extra: str  # the extra that installs what it needs
    help: str


TOOL_COMMANDS = {
    "demo": ToolCommand(
        "dthc_tools.demo.cli", "demo", "run everything end to end on embedded defaults"
    ),
    "send": ToolCommand(
        "dthc_tools.sender.cli", "sender", "send a G-code program to the daemon (reference sender)"
    ),
    "panel": ToolCommand(
        "dthc_tools.panel.cli", "panel", "the operator panel: a web page beside the table"
    ),
    "grbl-port": ToolCommand(
        "dthc_tools.grbl_port.cli",
        "sender",
        "a grbl for any grbl sender, in front of the table's grbl (in progress, issue 32)",
    ),
    "bench": ToolCommand(
        "dthc_tools.bench.cli", "bench", "benchmark suites: codec, latency, control, soak, scale"
    ),
}
_REQUIREMENT = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)(?:\[([^\]]*)\])?")
_EXTRA_MARKER = re.compile(r"""extra\s*==\s*["']([^"']+)["']""")


def missing_for_extra(extra: str, distribution: str = DISTRIBUTION) -> list[str]:
    """The distributions ``extra`` needs that are not installed, read from the package's
    own metadata (pyproject.toml is the one list), following extras of extras.

    Parsed by hand, narrowly (a name, optional [extras], an ``extra == "..."`` marker):
    ``packaging`` would do it fully but is not a runtime dependency of the daemon."""
    try:
        requirements = metadata.requires(distribution) or []
    except metadata.PackageNotFoundError:
        return []  # run from a source tree without metadata: the import will tell
    missing: list[str] = []
    for requirement in requirements:
        marker = _EXTRA_MARKER.search(requirement)
        head = _REQUIREMENT.match(requirement)
        if marker is None or marker.group(1) != extra or head is None:
            continue
        name, nested = head.group(1), head.group(2)
        if name.replace("_", "-").lower() == distribution:
            for inner in (nested or "").split(","):
                if inner.strip():
                    missing += missing_for_extra(inner.strip(), distribution)
            continue
        try:
            metadata.version(name)
        except metadata.PackageNotFoundError:
            missing.append(name)
    return missing


def run_tool(name: str, argv: Sequence[str]) -> int:
    """Run a tool command, or say which extra installs it (exit 2)."""
    tool = TOOL_COMMANDS[name]
    missing = missing_for_extra(tool.extra)
    if not missing:
        try:
            module = importlib.import_module(tool.module)
        except ModuleNotFoundError as exc:
            if exc.name is None or exc.name.split(".")[0] == "dthc_tools":
                raise
            missing = [exc.name]
    if missing:
        print(
            f"dthc-bridge {name}: needs the '{tool.extra}' extra (missing: {', '.join(missing)});"
            f" install it with: pip install 'dthc-bridge[{tool.extra}]'",
            file=sys.stderr,
        )
        return 2
    tool_main: Callable[..., int] = module.main
    return tool_main(list(argv), prog=f"dthc-bridge {name}")


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # A tool's arguments are the tool's: hand everything after its name over untouched.
    head, _, rest = _split_at_tool(argv)
    if rest is not None:
        args = parser.parse_args(head)
        configure_logging(args.log_level or "warning")
        return run_tool(args.command, rest)
    args = parser.parse_args(argv)
    if args.command == "run":
        return _run(args.config, args.log_level)
    configure_logging(args.log_level or "warning")
    if args.command == "check-config":
        return _check(args.file)
    if args.command == "check-program":
        return check_program.run_from_args(args)
    if args.command == "install-service":
        return run_install(args)
    if args.command == "uninstall-service":
        return run_uninstall(args)
    if args.command == "conformance":
        return conformance.run_from_args(args)
    return 2


def _split_at_tool(argv: list[str]) -> tuple[list[str], str, list[str] | None]:
    """``[--log-level L] TOOL ARGS...`` -> (global part with TOOL, TOOL, ARGS)."""
    index = 0
    while index < len(argv) and argv[index].startswith("-"):
        index += 1 if "=" in argv[index] or argv[index] in ("-h", "--help") else 2
    if index < len(argv) and argv[index] in TOOL_COMMANDS:
        return argv[: index + 1], argv[index], argv[index + 1 :]
    return argv, "", None


if __name__ == "__main__":
    sys.exit(main())
