"""``dthc-emulated-board --pty PATH``: the reference firmware on an emulated ATmega.

Builds what is missing or stale (``make -C firmware`` for the ELF, ``make -C
firmware/emulator`` for the host program), then execs the host program in this very
process, so the PID the user sees is the emulator's: SIGUSR2 to it resets the MCU, SIGTERM
stops it. Missing build tools: says which command installs them and exits 2.

Prints ``READY <pty path>`` once the board runs; reads control commands on stdin
(firmware/emulator/README.md).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from .build import (
    ARC_INPUTS,
    BOOTLOADER_HEX,
    INSTALL_HINT,
    MCUS,
    EmulatedBoardError,
    ToolsMissing,
    arduino_bootloader,
    checkout_root,
    ensure_built,
    firmware_elf,
    host_binary,
    selftest_elf,
)

__all__ = ["build_parser", "main"]

EXIT_SETUP = 2

# Model options passed through to the host program: (name, help).
MODEL_OPTIONS: tuple[tuple[str, str], ...] = (
    ("plate-mm", "the plate's surface Z (default 20)"),
    ("warp-mm", "warp amplitude A: the surface varies as A*sin(2*pi*t/P) while cutting"),
    ("warp-period-s", "warp period P in seconds of transferred arc"),
    ("arc-slope-v-mm", "arc volts per mm of height (default 7.5)"),
    ("cut-v", "arc volts at cut height (default 116)"),
    ("cut-height-mm", "cut height for --cut-v (default 1.5)"),
    ("noise-v", "Gaussian sigma per ADC conversion, volts (default 0.4)"),
    ("arc-ok-delay-ms", "torch on -> transfer and arc OK (default 100)"),
    ("float-travel-mm", "float switch closes this far below the touch point (default 1.5)"),
    ("ocv-v", "open-circuit (pilot, lost arc) volts (default 250)"),
    ("transfer-max-mm", "the pilot transfers at most this high (default 8)"),
    ("lose-above-mm", "a transferred arc is lost above this height (default 10)"),
    ("pilot-timeout-ms", "a pilot that never transfers ends after this (default 3000)"),
    ("home-switch-mm", "the home switch (Z_LIMIT_MAX) closes at and above this Z (default 102)"),
)
# The voltage-to-frequency card's nominal scaling (--arc-input vtof): (name, help).
VTOF_OPTIONS: tuple[tuple[str, str], ...] = (
    ("vtof-zero-hz", "the card's frequency at 0 V input (default 121000)"),
    ("vtof-full-hz", "the card's frequency at full-scale input (default 925000)"),
    ("vtof-full-v", "the card's full-scale input in volts (default 10)"),
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="dthc-emulated-board",
        description="The reference firmware's ELF on an emulated ATmega (simavr), UART0 on a "
        "pty, with a plate, an arc and a Z axis. SIGUSR2 resets the MCU.",
    )
    p.add_argument("--pty", type=Path, required=True, help="symlink the pty's slave here")
    p.add_argument("--mcu", choices=MCUS, default=MCUS[0])
    p.add_argument("--elf", type=Path, help="run this ELF instead of the built firmware")
    p.add_argument(
        "--selftest", action="store_true", help="run the harness's own test program instead"
    )
    p.add_argument(
        "--bootloader",
        nargs="?",
        const="",
        choices=("", *BOOTLOADER_HEX),
        metavar="KIND",
        help="Arduino's own bootloader at the top of flash (Debian's arduino-core-avr), as a "
        "board off the shelf: every reset starts it, opening the port resets the MCU; the "
        "application from --flash, or erased (flash it with avrdude through the pty). KIND: "
        "stk500v2 (the Mega's), optiboot (the Uno's and new Nano's, the Nano's default) or "
        "atmegaboot (the old Nano's)",
    )
    p.add_argument(
        "--flash", type=Path, metavar="HEX", help="with --bootloader: the application's HEX"
    )
    p.add_argument("--record", type=Path, help="write the event record here")
    p.add_argument("--seed", type=int, default=1, help="noise seed")
    p.add_argument("--no-build", action="store_true", help="do not run make first")
    p.add_argument(
        "--arc-input",
        choices=ARC_INPUTS,
        default=ARC_INPUTS[0],
        help="the arc front end: the ADC, or a V-to-F card on the Mega's T5 (the vtof build)",
    )
    m = p.add_argument_group("plate and arc model")
    for name, text in MODEL_OPTIONS:
        m.add_argument(f"--{name}", type=float, help=text)
    v = p.add_argument_group("voltage-to-frequency card (--arc-input vtof)")
    for name, text in VTOF_OPTIONS:
        v.add_argument(f"--{name}", type=float, help=text)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.flash is not None and args.bootloader is None:
        parser.error("--flash needs --bootloader")
    if args.bootloader is not None and (args.elf is not None or args.selftest):
        parser.error("--bootloader runs what is flashed (--flash HEX, or nothing): not --elf")
    try:
        root = checkout_root()
        if args.selftest:
            elf = selftest_elf(root, args.mcu)
        elif args.elf is not None:
            elf = args.elf
        else:
            elf = firmware_elf(root, args.mcu, args.arc_input)
        if not args.no_build:
            ensure_built(root, firmware=args.elf is None and not args.selftest)
        bootloader = (
            None
            if args.bootloader is None
            else arduino_bootloader(args.mcu, args.bootloader or None)
        )
    except ToolsMissing as exc:
        print(
            f"dthc-emulated-board: build tools missing: {', '.join(exc.missing)}\n"
            f"install them with: {INSTALL_HINT}",
            file=sys.stderr,
        )
        return EXIT_SETUP
    except EmulatedBoardError as exc:
        print(f"dthc-emulated-board: {exc}", file=sys.stderr)
        return EXIT_SETUP
    host = host_binary(root)
    command = [str(host), "--mcu", args.mcu, "--pty", str(args.pty)]
    if bootloader is not None:
        command += ["--bootloader", str(bootloader)]
        if args.flash is not None:
            command += ["--flash", str(args.flash)]
    else:
        command += ["--elf", str(elf)]
    command += ["--seed", str(args.seed), "--arc-input", args.arc_input]
    if args.record is not None:
        command += ["--record", str(args.record)]
    for name, _ in (*MODEL_OPTIONS, *VTOF_OPTIONS):
        value = getattr(args, name.replace("-", "_"))
        if value is not None:
            command += [f"--{name}", repr(value)]
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(host, command)  # noqa: S606 - replaces this process: the user's PID is the host's
    return EXIT_SETUP  # not reached: execv returns only by raising OSError


if __name__ == "__main__":
    sys.exit(main())
