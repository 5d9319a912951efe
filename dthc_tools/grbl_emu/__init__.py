"""A grbl 1.1 / grblHAL controller emulated as its own process on a pty.

A realistic serial peer for a sender's grbl backend: character-counting flow control against
a receive buffer that really loses bytes when overrun, a planner of limited blocks that backs
lines up into that buffer, real-time bytes, status reports, alarms and overrides, with the
table moved in real time by the mock board's gantry planner (and optionally mirrored onto a
running mock board, so its arc physics sees the table move).

    codes        grbl's error and alarm numbers
    config       flavour, buffer sizes, motion limits
    blocks       moves, dwells and stops a block asks for; grbl's word reader
    gcode        the G-code parser (modal state, offsets, arcs, errors)
    settings     the $ settings table
    planner      the gantry planner counted in blocks, with live overrides
    reports      banner, $I, status report text
    serial_input the receive buffer and line assembly
    stats        what the controller saw (the exit line)
    firmware     the controller, sans I/O: bytes in, bytes out, stepped by a clock
    plant_mirror moves mirrored onto the mock board's gantry port
    pty_host     the real-time process on a pty (``python -m dthc_tools.grbl_emu``)
"""

from __future__ import annotations

from .codes import Alarm, EmulatorError, GcodeRefused, Status
from .config import ConfigError, EmulatorConfig, Flavor
from .firmware import GrblFirmware, MachineState
from .stats import EmulatorStats

__all__ = [
    "Alarm",
    "ConfigError",
    "EmulatorConfig",
    "EmulatorError",
    "EmulatorStats",
    "Flavor",
    "GcodeRefused",
    "GrblFirmware",
    "MachineState",
    "Status",
]
