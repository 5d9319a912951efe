"""grbl 1.1's numbered answers: ``error:N`` status codes and ``ALARM:N`` alarm codes.

The numbers are the published ones (grbl v1.1 interface documentation, error and alarm code
tables), so a sender's decoding can be tested against them; the short texts are ours.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["ALARM_TEXT", "STATUS_TEXT", "Alarm", "EmulatorError", "GcodeRefused", "Status"]


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


STATUS_TEXT: dict[Status, str] = {
    Status.EXPECTED_COMMAND_LETTER: "a word does not start with a letter",
    Status.BAD_NUMBER_FORMAT: "a number is missing or malformed",
    Status.INVALID_STATEMENT: "the $ command is not recognised",
    Status.NEGATIVE_VALUE: "a value that must be positive is negative",
    Status.SETTING_DISABLED: "homing is not enabled ($22)",
    Status.SETTING_STEP_PULSE_MIN: "step pulse shorter than 3 microseconds",
    Status.SETTING_READ_FAIL: "settings storage read failed, defaults restored",
    Status.IDLE_ERROR: "this $ command needs the machine idle",
    Status.SYSTEM_GC_LOCK: "G-code is locked out in alarm or jog state",
    Status.SOFT_LIMIT_ERROR: "soft limits need homing enabled",
    Status.OVERFLOW: "the line is longer than the line buffer",
    Status.MAX_STEP_RATE_EXCEEDED: "the setting exceeds the maximum step rate",
    Status.CHECK_DOOR: "the safety door is open",
    Status.LINE_LENGTH_EXCEEDED: "build info or startup line too long for storage",
    Status.TRAVEL_EXCEEDED: "the jog target is beyond the machine's travel",
    Status.INVALID_JOG_COMMAND: "the jog command has no '=' or a forbidden word",
    Status.SETTING_DISABLED_LASER: "laser mode needs a PWM output",
    Status.UNSUPPORTED_COMMAND: "an unsupported or invalid G-code command",
    Status.MODAL_GROUP_VIOLATION: "two commands of one modal group on the line",
    Status.UNDEFINED_FEED_RATE: "no feed rate set",
    Status.COMMAND_VALUE_NOT_INTEGER: "the command needs an integer number",
    Status.AXIS_COMMAND_CONFLICT: "two commands on the line use the axis words",
    Status.WORD_REPEATED: "a word is repeated on the line",
    Status.NO_AXIS_WORDS: "the command needs axis words",
    Status.INVALID_LINE_NUMBER: "the N line number is out of range",
    Status.VALUE_WORD_MISSING: "a required P or L word is missing",
    Status.UNSUPPORTED_COORD_SYS: "that work coordinate system is not supported",
    Status.G53_INVALID_MOTION_MODE: "G53 needs G0 or G1 active",
    Status.AXIS_WORDS_EXIST: "axis words while G80 is active",
    Status.NO_AXIS_WORDS_IN_PLANE: "the arc has no axis word in its plane",
    Status.INVALID_TARGET: "the motion target is invalid",
    Status.ARC_RADIUS_ERROR: "the arc radius cannot reach the target",
    Status.NO_OFFSETS_IN_PLANE: "the arc has no centre offset in its plane",
    Status.UNUSED_WORDS: "words on the line no command uses",
    Status.G43_DYNAMIC_AXIS_ERROR: "G43.1 applies to the Z axis only",
    Status.MAX_VALUE_EXCEEDED: "the tool number is too large",
}

ALARM_TEXT: dict[Alarm, str] = {
    Alarm.HARD_LIMIT: "hard limit switch hit: position lost",
    Alarm.SOFT_LIMIT: "soft limit: a target beyond the machine's travel",
    Alarm.ABORT_CYCLE: "reset while moving: position may be lost",
    Alarm.PROBE_FAIL_INITIAL: "probe not in its expected state before probing",
    Alarm.PROBE_FAIL_CONTACT: "probe made no contact",
    Alarm.HOMING_FAIL_RESET: "reset during homing",
    Alarm.HOMING_FAIL_DOOR: "safety door opened during homing",
    Alarm.HOMING_FAIL_PULLOFF: "homing pull-off did not clear the switch",
    Alarm.HOMING_FAIL_APPROACH: "homing switch not found",
}


class EmulatorError(Exception):
    """Root of the emulator's exceptions."""


class GcodeRefused(EmulatorError):
    """A line the firmware answers with ``error:N``; nothing of it was executed."""

    def __init__(self, status: Status, detail: str = "") -> None:
        self.status = status
        self.detail = detail
        suffix = f": {detail}" if detail else ""
        super().__init__(f"error:{int(status)} ({STATUS_TEXT[status]}){suffix}")
