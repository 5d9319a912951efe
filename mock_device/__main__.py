"""``dthc-mock``: the mock DTHC board as its own process, on a pty or a TCP port."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from firmware_protocol import Capability

from .board_logic import BoardIdentity
from .faults import FaultPlan
from .links import BoardLink, PtyLink, TcpLink
from .plant import list_scenarios
from .process import MockBoardProcess, ProcessOptions
from .sim import SimulatedBoard
from .variants import VARIANTS

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="dthc-mock",
        description="Mock DTHC/ohmic board with a simulated torch, plate and gantry.",
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", type=Path, help="create a raw pty and symlink it here")
    where.add_argument("--listen", help="socket://HOST:PORT to serve one TCP client")
    p.add_argument("--scenario", default="flat_clean", help=f"one of {list_scenarios()}")
    p.add_argument("--seed", type=int, default=1, help="random seed (plant, noise, boot id)")
    p.add_argument("--serial", default="MOCK-0001", help="board serial in HELLO_INFO")
    p.add_argument("--no-xy-speed", action="store_true", help="board without XY speed input")
    p.add_argument(
        "--boot-z-mm",
        type=float,
        help="the Z the board takes at power-on, as a real board's firmware constant (60 on "
        "the reference firmware), wherever the plant's Z stands: Z is right only once homed "
        "(default: the board knows where Z stands)",
    )
    p.add_argument(
        "--firmware-variant", choices=sorted(VARIANTS), default="good",
        help="a firmware with one deliberate fault (for conformance tests)",
    )  # fmt: skip
    p.add_argument("--duration", type=float, help="exit after this many board seconds")
    p.add_argument("--truth", type=Path, help="write ground truth here on exit (.csv/.jsonl)")
    p.add_argument("--program", type=Path, help="G-code whose motion lines the gantry runs")
    p.add_argument(
        "--gantry-listen", help="socket://HOST:PORT: JSON-lines control port for a sender's"
        " motion backend (port 0 picks a free one; READY prints it)",
    )  # fmt: skip
    p.add_argument("--default-program", action="store_true", help="run the scenario's path")
    p.add_argument(
        "--latency-log", type=Path, help="write JSON lines here on exit: when each Z_VELOCITY"
        " arrived and each SAMPLES frame was sent, in real-clock board time",
    )  # fmt: skip
    f = p.add_argument_group("fault injection (SIGUSR1 unplugs, SIGUSR2 reboots)")
    f.add_argument("--bit-flip-rate", type=float, default=0.0, help="per byte")
    f.add_argument("--drop-frame-rate", type=float, default=0.0, help="per board frame")
    f.add_argument("--delay-ms", type=float, default=0.0, help="added to every board frame")
    f.add_argument("--garbage-rate", type=float, default=0.0, help="bursts per board frame")
    f.add_argument("--unplug-at", type=float, help="board seconds")
    f.add_argument("--unplug-for", type=float, default=1.0, help="seconds")
    f.add_argument("--reboot-at", type=float, help="board seconds")
    f.add_argument("--stall-acks-at", type=float, help="board seconds")
    f.add_argument("--stall-for", type=float, default=0.5, help="seconds")
    return p


def _parse_listen(url: str) -> tuple[str, int]:
    if not url.startswith("socket://"):
        raise SystemExit(f"--listen: expected socket://HOST:PORT, got {url!r}")
    host, _, port = url.removeprefix("socket://").rpartition(":")
    if not host or not port.isdigit():
        raise SystemExit(f"--listen: expected socket://HOST:PORT, got {url!r}")
    return host, int(port)


def main(argv: Sequence[str] | None = None) -> int:
    parent_pid = os.getppid()  # first: the mock exits when this process is gone
    args = build_parser().parse_args(argv)
    plan = FaultPlan(
        bit_flip_rate=args.bit_flip_rate,
        drop_frame_rate=args.drop_frame_rate,
        delay_ms=args.delay_ms,
        garbage_rate=args.garbage_rate,
        unplug_at_s=args.unplug_at,
        unplug_for_s=args.unplug_for,
        reboot_at_s=args.reboot_at,
        stall_acks_at_s=args.stall_acks_at,
        stall_for_s=args.stall_for,
    )
    identity = BoardIdentity(serial=args.serial, boot_z_mm=args.boot_z_mm)
    if args.no_xy_speed:
        identity = dataclasses.replace(
            identity, capabilities=identity.capabilities & ~Capability.XY_SPEED
        )
    board = SimulatedBoard(
        args.scenario, args.seed, identity=identity, faults=plan,
        firmware_class=VARIANTS[args.firmware_variant],
    )  # fmt: skip
    program: tuple[str, ...] = ()
    if args.program:
        program = tuple(args.program.read_text().splitlines())
    elif args.default_program:
        program = tuple(board.scenario.default_program)
    link: BoardLink
    if args.pty:
        link = PtyLink(args.pty, lambda _: None)
    else:
        host, port = _parse_listen(args.listen)
        link = TcpLink(host, port, lambda _: None)
    gantry = _parse_listen(args.gantry_listen) if args.gantry_listen else None
    options = ProcessOptions(
        duration_s=args.duration,
        truth_path=args.truth,
        program=program,
        gantry=gantry,
        latency_log=args.latency_log,
        parent_pid=parent_pid,
    )
    return asyncio.run(MockBoardProcess(board, link, plan, options).run())


if __name__ == "__main__":
    sys.exit(main())
