"""grbl / grblHAL's serial protocol, sans I/O: what the grbl backend sends and reads.

Written from grbl 1.1's published interface (and grblHAL's additions, as observed: see
docs in ``shared/reference/grbl-facts.md``): real-time bytes, status reports, ``$I`` build
info, ``ok`` / ``error:N`` / ``ALARM:N``, and the character-counting flow control that keeps
the firmware's serial receive buffer from overflowing. No library on PyPI implements a
grbl streamer we could depend on for a daemon-grade sender (the ones there are GUIs or
scripts that block on each line), so this is ours.
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

from dthc_bridge.controller.words import GcodeSyntaxError, Word, tokenize

__all__ = [
    "ALARMS",
    "CYCLE_START",
    "ERRORS",
    "FEED_HOLD",
    "FEED_OVERRIDE",
    "JOG_CANCEL",
    "SOFT_RESET",
    "STATUS_QUERY",
    "CharCounter",
    "FirmwareInfo",
    "LineRefused",
    "SpeedMeter",
    "StatusReport",
    "alarm_text",
    "error_text",
    "for_grbl",
    "is_banner",
    "parse_status",
]

# Real-time bytes: acted on by the firmware on arrival, never buffered, no newline.
STATUS_QUERY = b"?"
FEED_HOLD = b"!"
CYCLE_START = b"~"
SOFT_RESET = b"\x18"
JOG_CANCEL = b"\x85"
FEED_OVERRIDE = {
    "reset": b"\x90", "+10": b"\x91", "-10": b"\x92", "+1": b"\x93", "-1": b"\x94",
}  # fmt: skip

# grbl 1.1's documented codes, in our words.
ERRORS = {
    1: "a G-code word has no letter", 2: "a number is missing or malformed",
    3: "the $ command is not understood", 4: "a negative value where it must be positive",
    5: "homing is not enabled ($22)", 6: "step pulse under 3 microseconds",
    7: "EEPROM read failed, defaults restored", 8: "a $ command that needs the machine idle",
    9: "G-code is locked out in alarm or jog state", 10: "soft limits need homing enabled",
    11: "the line is longer than the firmware's line buffer", 12: "a step rate too high",
    13: "the safety door is open", 14: "a startup line or build info too long for EEPROM",
    15: "the jog target is beyond the machine's travel", 16: "an invalid jog command",
    17: "laser mode needs a PWM output", 20: "an unsupported or invalid G-code command",
    21: "two commands of one modal group on a line", 22: "no feed rate set",
    23: "the command needs an integer value", 24: "two commands on the line need axis words",
    25: "a word is repeated on the line", 26: "no axis words where the command needs them",
    27: "the line number is out of range", 28: "a P or L value is missing",
    29: "G59.1-G59.3 are not supported", 30: "G53 needs G0 or G1",
    31: "axis words the command does not use", 32: "an arc without axis words in its plane",
    33: "the motion target is invalid", 34: "the arc radius is invalid",
    35: "the arc needs offsets in its plane", 36: "values no command on the line uses",
    37: "G43.1 needs the tool length axis", 38: "the tool number is too large",
}  # fmt: skip
ALARMS = {
    1: "hard limit triggered: position lost, re-home", 2: "soft limit: the target is beyond "
    "the machine's travel", 3: "reset while in motion: position may be lost, re-home",
    4: "probe not in its expected state before probing", 5: "probe made no contact",
    6: "homing reset", 7: "safety door opened while homing", 8: "homing pull-off failed",
    9: "homing switch not found", 10: "emergency stop (grblHAL)",
}  # fmt: skip


def error_text(code: int) -> str:
    return ERRORS.get(code, "an error the firmware did not document")


def alarm_text(code: int) -> str:
    return ALARMS.get(code, "an alarm the firmware did not document")


class LineRefused(ValueError):
    """A program line that must not reach grbl (its Z, spindle or torch words)."""


# Words grbl must never see in our system: Z is the DTHC board's, the torch the daemon's.
_SPINDLE_M = {3.0, 4.0, 5.0}
# LinuxCNC modal words that PlasmaC and SheetCam posts write in their preamble and that grbl
# 1.1 refuses (error:20) though they change nothing a plasma table's XY does: G64 (path
# blending with a tolerance P, Q: grbl always blends), G97 (spindle RPM mode: no spindle),
# M52 (adaptive feed, with its P: grbl has none; a pause here is the daemon's and grbl's hold),
# G43 H (a tool length offset: Z is the DTHC board's, grbl's Z never moves).
_LINUXCNC_ONLY_G = {43.0, 64.0, 97.0}
_LINUXCNC_ONLY_M = {52.0}
_P_USERS_G = {4.0, 10.0, 38.2, 38.3, 38.4, 38.5}  # a P on their line is theirs, not G64's


def for_grbl(line: str) -> str:
    """The line as sent: comments and spaces dropped (they cost receive buffer), upper case;
    the LinuxCNC words grbl refuses that change nothing of XY (G64, G97, G43 H, M52) dropped.

    Raises :class:`LineRefused` for a Z word or a spindle/torch word (M3/M4/M5, S): the plan
    never routes them here, so one arriving is a bug worth stopping for."""
    try:
        words = tokenize(line).words
        spindle = [w for w in words if w.letter == "M" and w.value in _SPINDLE_M]
    except GcodeSyntaxError as exc:
        raise LineRefused(f"{line!r}: {exc}") from None
    kept = _without_linuxcnc_only(words)
    if len(kept) < len(words) and all(w.letter == "N" for w in kept):
        return ""  # nothing but its line number left: nothing for grbl
    for word in kept:
        if word.letter == "Z":
            raise LineRefused(f"{line!r}: Z words go to the DTHC board, never to grbl")
        if word.letter == "S" or word in spindle:
            raise LineRefused(
                f"{line!r}: {word.letter}{word.number} is the torch's (the daemon's), never grbl's"
            )
    return "".join(word.letter + word.number for word in kept)


def _without_linuxcnc_only(words: Sequence[Word]) -> Sequence[Word]:
    """``words`` less G64 (with its P and Q), G97, G43 (its H) and M52 (its P); unchanged
    without them."""
    gs = {w.value for w in words if w.letter == "G"}
    ms = {w.value for w in words if w.letter == "M"}
    if not (gs & _LINUXCNC_ONLY_G or ms & _LINUXCNC_ONLY_M):
        return words
    blend = 64.0 in gs
    p_theirs = (blend or 52.0 in ms) and not gs & _P_USERS_G
    return [
        w for w in words
        if not (w.letter == "G" and w.value in _LINUXCNC_ONLY_G)
        and not (w.letter == "M" and w.value in _LINUXCNC_ONLY_M)
        and not (blend and w.letter == "Q")
        and not (43.0 in gs and w.letter == "H")
        and not (p_theirs and w.letter == "P")
    ]  # fmt: skip


@dataclass(frozen=True, slots=True)
class StatusReport:
    """One ``<State|Field:...|...>`` report, fields by name; unknown fields are kept raw."""

    state: str  # Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep, Tool
    substate: int | None = None  # Hold:0 complete, Hold:1 decelerating; Door:n
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    wco: tuple[float, ...] | None = None
    feed: float | None = None  # FS/F: the planned feed of the executing block, not measured
    planner_free: int | None = None  # Bf: free planner blocks
    rx_free: int | None = None  # Bf: free receive buffer bytes
    overrides: tuple[int, ...] | None = None
    other: dict[str, str] = field(default_factory=dict)

    @property
    def hold_complete(self) -> bool:
        return self.state == "Hold" and self.substate == 0

    def work_position(self, wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
        """WPos as given, or MPos - WCO (the last WCO seen: grbl sends it every few reports)."""
        if self.wpos is not None:
            return self.wpos
        if self.mpos is None:
            return None
        offset = self.wco or wco
        if offset is None:
            return self.mpos
        return tuple(m - o for m, o in zip(self.mpos, offset, strict=False))


def _numbers(text: str, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"{what}: {text!r} is not a list of numbers") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what}: {text!r} has a value that is not finite")
    return values


def parse_status(line: str) -> StatusReport:
    """``<Run|MPos:1.000,2.000,0.000|Bf:15,128|FS:1500,0|Ov:100,100,100>``; ValueError if
    it is not a status report."""
    if not (line.startswith("<") and line.endswith(">")):
        raise ValueError(f"not a status report: {line!r}")
    head, *fields = line[1:-1].split("|")
    state, _, sub = head.partition(":")
    if not state:
        raise ValueError(f"status report without a state: {line!r}")
    values: dict[str, object] = {}
    other: dict[str, str] = {}
    for item in fields:
        name, _, text = item.partition(":")
        if name in ("MPos", "WPos", "WCO"):
            values[name.lower()] = _numbers(text, name)
        elif name in ("FS", "F"):
            values["feed"] = _numbers(text, name)[0]
        elif name == "Bf":
            blocks, rx = _numbers(text, name)[:2]
            values["planner_free"], values["rx_free"] = int(blocks), int(rx)
        elif name == "Ov":
            values["overrides"] = tuple(int(v) for v in _numbers(text, name))
        else:
            other[name] = text
    substate = int(sub) if sub.isdigit() else None
    return StatusReport(state, substate, other=other, **values)  # type: ignore[arg-type]


_VER = re.compile(r"^\[VER:([^:\]]*)")
_OPT = re.compile(r"^\[OPT:([^,\]]*),(\d+),(\d+)")


@dataclass(slots=True)
class FirmwareInfo:
    """What the banner and ``$I`` told us. Classic grbl: 15 planner blocks, a 128-byte
    receive buffer and 80-character lines unless ``[OPT:]`` says otherwise."""

    banner: str = ""
    version: str = ""
    planner_blocks: int = 15
    rx_buffer: int = 128
    options: str = ""
    firmware: str = "grbl"
    extra: list[str] = field(default_factory=list)

    @property
    def is_grblhal(self) -> bool:
        return self.firmware == "grblHAL" or self.banner.startswith("GrblHAL")

    @property
    def line_limit(self) -> int:
        """Characters per line the firmware takes (with its newline): 80 classic, more on
        grblHAL (256); never more than the receive buffer."""
        return min(self.rx_buffer, 256 if self.is_grblhal else 80)

    def read(self, line: str) -> None:
        """Fold one line of ``$I`` output in."""
        if match := _VER.match(line):
            self.version = match.group(1)
        elif match := _OPT.match(line):
            self.options = match.group(1)
            self.planner_blocks, self.rx_buffer = int(match.group(2)), int(match.group(3))
        elif line.startswith("[FIRMWARE:"):
            self.firmware = line.removeprefix("[FIRMWARE:").rstrip("]")
        elif line.startswith("["):
            self.extra.append(line)


def is_banner(line: str) -> bool:
    return line.startswith(("Grbl ", "GrblHAL "))


class CharCounter:
    """Character counting (grbl's own recommended streaming): a line may be sent while the
    bytes of the unacknowledged lines, newlines included, fit the receive buffer, which
    holds one byte less than its size (a ring buffer: 127 of 128). Each ``ok`` or
    ``error`` acknowledges the oldest line."""

    def __init__(self, rx_buffer: int) -> None:
        self.rx_buffer = rx_buffer
        self._in_flight: deque[int] = deque()
        self.used = 0

    def fits(self, size: int) -> bool:
        return self.used + size < self.rx_buffer

    def sent(self, size: int) -> None:
        self._in_flight.append(size)
        self.used += size

    def acknowledged(self) -> None:
        if self._in_flight:
            self.used -= self._in_flight.popleft()

    def clear(self) -> None:
        self._in_flight.clear()
        self.used = 0

    def __len__(self) -> int:
        return len(self._in_flight)


class SpeedMeter:
    """XY speed from position reports. ``FS`` runs ahead of the real motion and reads the
    programmed feed in a completed hold, so the speed is measured from positions over at
    least ``window_s`` (single 50 ms differences were about ±10 % noisy on real grblHAL)."""

    def __init__(self, window_s: float = 0.1) -> None:
        self.window_s = window_s
        self._points: deque[tuple[float, float, float]] = deque()

    def add(self, t_s: float, x: float, y: float) -> float | None:
        """Add a position; the speed over the newest window, or None until one is covered."""
        points = self._points
        points.append((t_s, x, y))
        while len(points) > 2 and t_s - points[1][0] >= self.window_s:
            points.popleft()
        t0, x0, y0 = points[0]
        if t_s - t0 < self.window_s:
            return None
        return math.hypot(x - x0, y - y0) / (t_s - t0)

    def clear(self) -> None:
        self._points.clear()
