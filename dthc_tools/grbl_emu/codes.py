"""grbl 1.1's numbered answers: ``error:N`` status codes and ``ALARM:N`` alarm codes.

The numbers are the published ones (grbl v1.1 interface documentation, error and alarm code
tables), so a sender's decoding can be tested against them; their texts are the sender's
(:mod:`dthc_tools.sender.grbl_protocol`), one table for both.
"""

from __future__ import annotations

from enum import IntEnum

from dthc_tools.sender.grbl_protocol import error_text

__all__ = ["Alarm", "EmulatorError", "GcodeRefused", "Status"]


class Status(IntEnum):
    """What ``error:N`` means (grbl 1.1 numbering)."""

    EXPECTED_COMMAND_LETTER = 1
    BAD_NUMBER_FORMAT = 2
    INVALID_STATEMENT = 3
    NEGATIVE_VALUE = 4
    SETTING_DISABLED = 5
    SETTING_STEP_PULSE_MIN = 6
    SETTING_READ_FAIL = 7
    IDLE_ERROR = 8
    SYSTEM_GC_LOCK = 9
    SOFT_LIMIT_ERROR = 10
    OVERFLOW = 11
    MAX_STEP_RATE_EXCEEDED = 12
    CHECK_DOOR = 13
    LINE_LENGTH_EXCEEDED = 14
    TRAVEL_EXCEEDED = 15
    INVALID_JOG_COMMAND = 16
    SETTING_DISABLED_LASER = 17
    UNSUPPORTED_COMMAND = 20
    MODAL_GROUP_VIOLATION = 21
    UNDEFINED_FEED_RATE = 22
    COMMAND_VALUE_NOT_INTEGER = 23
    AXIS_COMMAND_CONFLICT = 24
    WORD_REPEATED = 25
    NO_AXIS_WORDS = 26
    INVALID_LINE_NUMBER = 27
    VALUE_WORD_MISSING = 28
    UNSUPPORTED_COORD_SYS = 29
    G53_INVALID_MOTION_MODE = 30
    AXIS_WORDS_EXIST = 31
    NO_AXIS_WORDS_IN_PLANE = 32
    INVALID_TARGET = 33
    ARC_RADIUS_ERROR = 34
    NO_OFFSETS_IN_PLANE = 35
    UNUSED_WORDS = 36
    G43_DYNAMIC_AXIS_ERROR = 37
    MAX_VALUE_EXCEEDED = 38


class Alarm(IntEnum):
    """What ``ALARM:N`` means (grbl 1.1 numbering)."""

    HARD_LIMIT = 1
    SOFT_LIMIT = 2
    ABORT_CYCLE = 3
    PROBE_FAIL_INITIAL = 4
    PROBE_FAIL_CONTACT = 5
    HOMING_FAIL_RESET = 6
    HOMING_FAIL_DOOR = 7
    HOMING_FAIL_PULLOFF = 8
    HOMING_FAIL_APPROACH = 9


class EmulatorError(Exception):
    """Root of the emulator's exceptions."""


class GcodeRefused(EmulatorError):
    """A line the firmware answers with ``error:N``; nothing of it was executed."""

    def __init__(self, status: Status, detail: str = "") -> None:
        self.status = status
        self.detail = detail
        suffix = f": {detail}" if detail else ""
        super().__init__(f"error:{int(status)} ({error_text(int(status))}){suffix}")
