"""The reference firmware's very ELF on an emulated ATmega (simavr), as a board on a pty.

The emulator itself is a GPL-3.0-or-later C program in ``firmware/emulator/`` (it links
simavr); this package (MIT) only builds it with ``make`` and runs it as a separate process:

    build    where the source checkout is; which tools are missing; ``make`` what is stale
    harness  :class:`EmulatedBoard`: start it (dies with its parent), wait for READY, send
             control commands, reboot it; :func:`read_record` and the measurements a test
             takes from its event record
    cli      ``dthc-emulated-board --pty PATH ...``: build, then exec the host program
"""

from __future__ import annotations

from .build import (
    ARC_INPUTS,
    INSTALL_HINT,
    MCUS,
    BuildError,
    EmulatedBoardError,
    ToolsMissing,
    arduino_bootloader,
    checkout_root,
    ensure_built,
    firmware_elf,
    firmware_hex,
    host_binary,
    missing_tools,
    selftest_elf,
)
from .harness import (
    BoardStatus,
    ControlError,
    EmulatedBoard,
    FrameEvent,
    HarnessOptions,
    RecordEvent,
    frames,
    read_record,
    relay_off_after_last_host_byte_us,
    reply_delays_us,
)

__all__ = [
    "ARC_INPUTS",
    "INSTALL_HINT",
    "MCUS",
    "BoardStatus",
    "BuildError",
    "ControlError",
    "EmulatedBoard",
    "EmulatedBoardError",
    "FrameEvent",
    "HarnessOptions",
    "RecordEvent",
    "ToolsMissing",
    "arduino_bootloader",
    "checkout_root",
    "ensure_built",
    "firmware_elf",
    "firmware_hex",
    "frames",
    "host_binary",
    "missing_tools",
    "read_record",
    "relay_off_after_last_host_byte_us",
    "reply_delays_us",
    "selftest_elf",
]
