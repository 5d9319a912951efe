"""``python -m dthc_tools.grbl_emu``: a grbl / grblHAL controller on a pty, for senders to test on.

    python -m dthc_tools.grbl_emu --pty /tmp/grbl0 [--flavor grbl|grblhal] [--rx-buffer N]
        [--planner-blocks N] [--plant socket://HOST:PORT] [--accel MM_S2] [--rapid MM_MIN]
        [--junction-deviation MM] [--max-rate MM_MIN] [--max-travel X,Y] [--no-soft-limits]
        [--report mpos|wpos]

Prints ``READY pty=PATH`` once the pty is there; JSON lines on stderr, the last one
``{"event": "exit", "rx_overflow": N, "lines": N, ...}``; SIGUSR1 logs the same figures
(``"event": "stats"``) without stopping.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from .config import ConfigError, EmulatorConfig, Flavor
from .firmware import GrblFirmware
from .pty_host import EmulatorHost

__all__ = ["build_parser", "main"]

_DEFAULTS = EmulatorConfig()


def _socket_url(text: str) -> tuple[str, int]:
    host, _, port = text.removeprefix("socket://").rpartition(":")
    if not text.startswith("socket://") or not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected socket://HOST:PORT, got {text!r}")
    return host, int(port)


def _pair(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in mm, got {text!r}") from None
    return x, y


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(
        prog="python -m dthc_tools.grbl_emu",
        description="A grbl 1.1 / grblHAL controller emulated on a pty, moving a simulated"
        " XY table in real time.",
    )
    p.add_argument("--pty", type=Path, required=True, help="create a raw pty, symlinked here")
    p.add_argument("--flavor", choices=[f.value for f in Flavor], default=Flavor.GRBL.value)
    p.add_argument(
        "--rx-buffer",
        type=int,
        default=0,
        help="serial receive buffer in bytes (default 128 grbl, 1024 grblhal)",
    )
    p.add_argument(
        "--planner-blocks", type=int, default=0, help="planner blocks (default 15 grbl, 35 grblhal)"
    )
    p.add_argument(
        "--plant",
        type=_socket_url,
        metavar="socket://HOST:PORT",
        help="mirror every move onto this mock board gantry port",
    )
    p.add_argument("--accel", type=float, default=_DEFAULTS.accel_mm_s2, metavar="MM_S2")
    p.add_argument("--rapid", type=float, default=_DEFAULTS.rapid_mm_min, metavar="MM_MIN")
    p.add_argument(
        "--junction-deviation", type=float, default=_DEFAULTS.junction_deviation_mm, metavar="MM"
    )
    p.add_argument(
        "--max-rate",
        type=float,
        default=0.0,
        metavar="MM_MIN",
        help="$110/$111 feed cap (default: the rapid rate)",
    )
    p.add_argument(
        "--max-travel",
        type=_pair,
        default=_DEFAULTS.max_travel_mm,
        metavar="X,Y",
        help="$130/$131: machine travel from zero, mm (default 1200,1200)",
    )
    p.add_argument("--no-soft-limits", action="store_true", help="$20=0: no travel check")
    p.add_argument(
        "--report",
        choices=["mpos", "wpos"],
        default="mpos",
        help="position in status reports ($10 bit 0)",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run until SIGTERM/SIGINT; the exit status."""
    parent_pid = os.getppid()  # first: the emulator stops once this process is gone
    args = build_parser().parse_args(argv)
    try:
        config = EmulatorConfig(
            flavor=Flavor(args.flavor),
            rx_buffer_bytes=args.rx_buffer,
            planner_blocks=args.planner_blocks,
            accel_mm_s2=args.accel,
            rapid_mm_min=args.rapid,
            junction_deviation_mm=args.junction_deviation,
            max_rate_mm_min=args.max_rate,
            max_travel_mm=args.max_travel,
            soft_limits=not args.no_soft_limits,
            report_wpos=args.report == "wpos",
        )
    except ConfigError as exc:
        print(f"grbl_emu: {exc}", file=sys.stderr)
        return 2
    firmware = GrblFirmware(config)
    host = EmulatorHost(firmware, args.pty, plant=args.plant, parent_pid=parent_pid)
    return asyncio.run(host.run())


if __name__ == "__main__":
    sys.exit(main())
