"""The emulated grbl / grblHAL controller, sans I/O: bytes in, bytes out, stepped by a clock.

``receive(data, now_s)`` is the serial interrupt: real-time bytes (``?`` ``!`` ``~`` 0x18 and
the 0x80+ overrides) act at once and never enter the receive buffer; other bytes go into the
``rx_buffer_bytes``-sized buffer (one slot stays empty, as in grbl's ring buffer, so a
128-byte buffer holds 127). The main loop empties it as fast as bytes arrive unless a line
blocks it (planner full, a dwell, an alarm); then bytes that find it full are lost
(``stats.rx_overflow``), as they would be on the wire. ``advance(now_s)`` is the main loop
and the stepper: the planner runs in 1 ms steps, and lines are taken out of the buffer,
parsed and answered while the planner has room. ``read()`` is what the controller sent.

Flow, as in grbl: a line leaves the receive buffer when the main loop reads it; a motion line
waits there (and everything behind it waits in the buffer) until the planner has a free
block; its ``ok`` comes once all its blocks (arc chords included) are in the planner. ``G4``,
``M0``, ``M2`` and ``M30`` wait for the planner to empty first (``G4`` then dwells), so their
``ok`` marks that point of the program.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass
from enum import Enum, StrEnum

from .blocks import Action, Dwell, Move, MoveKind, ProgramStop, read_number, scan_words
from .codes import Alarm, GcodeRefused, Status
from .config import EmulatorConfig
from .gcode import GcodeInterpreter
from .planner import MotionQueue
from .reports import HELP, UNLOCK_HINT, StatusFields, banner, build_info, status_report
from .serial_input import SerialInput
from .settings import MOTION_SETTINGS, Settings
from .stats import EmulatorStats

__all__ = ["EmulatorStats", "GrblFirmware", "MachineState"]

STEP_S = 0.001  # planner and main-loop period
MAX_CATCH_UP_S = 0.5  # after a longer stall of the host, time jumps (counted in stats.stalls)
WCO_REFRESH_REPORTS = 10  # WCO: goes out in every this many status reports
N_STARTUP_LINES = 2
BUILD_INFO_MAX_CHARS = 79  # grbl keeps the $I user text in an EEPROM line

STATUS_QUERY = 0x3F  # ?
FEED_HOLD = 0x21  # !
CYCLE_START = 0x7E  # ~
SOFT_RESET = 0x18
JOG_CANCEL = 0x85
FEED_OV = {0x90: "reset", 0x91: "+10", 0x92: "-10", 0x93: "+1", 0x94: "-1"}
RAPID_OV = {0x95: 100, 0x96: 50, 0x97: 25}
SPINDLE_OV = {0x99: "reset", 0x9A: "+10", 0x9B: "-10", 0x9C: "+1", 0x9D: "-1"}
_SPINDLE_WORD = re.compile(r"M0*[345](?![0-9])|S")


class MachineState(StrEnum):
    """The first field of a status report (without the Hold sub-state)."""

    IDLE = "Idle"
    RUN = "Run"
    HOLD = "Hold"
    JOG = "Jog"
    ALARM = "Alarm"
    CHECK = "Check"
    HOME = "Home"
    SLEEP = "Sleep"


class _Reply(Enum):
    HANDLED = "handled"  # a $ command that wrote its own answer


@dataclass(slots=True)
class _Pending:
    """The line the main loop is executing: what it still has to do before its ``ok``."""

    actions: deque[Action]
    jog: bool = False
    planned: bool = False  # the head Move is in the planner, waiting for all its blocks
    dwell_left_s: float | None = None
    paused: bool = False  # M0 has entered its hold
    homing: bool = False  # $H: clears the alarm when done


class GrblFirmware:
    """grbl 1.1 (or grblHAL) as a serial peer, on a simulated XY table."""

    def __init__(self, config: EmulatorConfig, *, now_s: float = 0.0) -> None:
        self.config = config
        self.settings = Settings.from_config(config)
        self.stats = EmulatorStats()
        self._blocks = config.planner_blocks
        self.motion = MotionQueue(
            accel_mm_s2=config.accel_mm_s2,
            rapid_mm_min=config.rapid_mm_min,
            junction_deviation_mm=config.junction_deviation_mm,
            max_rate_mm_min=config.max_rate_mm_min,
            arc_chord_mm=config.arc_chord_mm,
            start_xy=config.start_mm,
        )
        self.gcode = GcodeInterpreter(
            mist_coolant=config.defaults.mist_coolant, jog_travel_ok=self._jog_within_travel
        )
        self._t = now_s
        self._out = bytearray()
        self.serial = SerialInput(
            config.rx_buffer_bytes,
            config.line_buffer_chars,
            merge_crlf=config.defaults.merge_crlf,
        )
        self._pending: _Pending | None = None
        self._hold = False
        self._alarm = False
        self._critical = False  # a limit alarm: nothing but a reset is served
        self._sleep = False
        self._check_mode = False
        self._homing = False
        self._soft_limit_stop = False  # decelerating before ALARM:2
        self._jog_cancel = False  # decelerating before the jog is flushed
        self._spindle_ov = 100
        self._reports_since_wco = 0
        self._last_wco: tuple[float, float, float] | None = None
        self._epoch = 0  # bumped by every reset: a caller mid-loop must stop
        self.build_info_text = ""
        self.startup_lines = [""] * N_STARTUP_LINES
        self.gcode.reset(self.motion.position_mm)
        self._emit(banner(config))

    # ================================================================ wire side
    def receive(self, data: bytes, now_s: float) -> None:
        """Bytes from the host, at ``now_s`` (the clock ``advance`` uses)."""
        self.advance(now_s)
        self.stats.rx_bytes += len(data)
        serial = self.serial
        for byte in data:
            if byte in (STATUS_QUERY, FEED_HOLD, CYCLE_START, SOFT_RESET) or byte >= 0x80:
                if byte == STATUS_QUERY:
                    self._main_loop()  # lines that arrived before the query are parsed first
                self._realtime(byte)
                continue
            if serial.full:
                # The main loop drains the buffer as bytes arrive unless a line blocks it
                # (planner full, dwell, alarm): then the buffer overruns.
                self.stats.rx_high_water = len(serial)
                self._main_loop()
            if not serial.put(byte):
                self.stats.rx_overflow += 1
        self.stats.rx_high_water = max(self.stats.rx_high_water, len(serial))
        self._main_loop()

    def read(self) -> bytes:
        """Everything the controller sent since the last call."""
        out = bytes(self._out)
        self._out.clear()
        return out

    def take_plant_ops(self) -> list[dict[str, str]]:
        """Motion operations for the plant mirror since the last call, oldest first."""
        ops = self.motion.plant_ops
        self.motion.plant_ops = []
        return ops

    def _emit(self, text: str) -> None:
        self._out += text.encode("ascii") + b"\r\n"

    def _answer(self, status: Status | None) -> None:
        self.stats.lines += 1
        if status is None:
            self.stats.ok += 1
            self._emit("ok")
        else:
            self.stats.errors[int(status)] += 1
            self._emit(f"error:{int(status)}")

    # ================================================================= the clock
    def set_clock(self, now_s: float) -> None:
        """Re-anchor the clock (a host starting its loop): no time passes."""
        self._t = now_s

    def advance(self, now_s: float) -> None:
        """Run the planner and the main loop up to ``now_s``."""
        if now_s - self._t > MAX_CATCH_UP_S:
            self.stats.stalls += 1
            self._t = now_s - MAX_CATCH_UP_S
        while self._t + STEP_S <= now_s:
            self._t += STEP_S
            self._step()

    def _step(self) -> None:
        motion = self.motion
        motion.step(STEP_S)
        pending = self._pending
        if pending is not None and pending.dwell_left_s is not None and not self._hold:
            pending.dwell_left_s -= STEP_S
        if motion.speed_mm_s == 0.0:
            if self._soft_limit_stop:
                self._limit_alarm(Alarm.SOFT_LIMIT)
            elif self._jog_cancel:
                self._finish_jog_cancel()
        self.stats.planner_high_water = max(self.stats.planner_high_water, motion.segments)
        if self._pending is not None or len(self.serial):
            self._main_loop()

    # ============================================================ state, reports
    @property
    def state(self) -> MachineState:
        """The machine state, as the status report names it."""
        if self._sleep:
            return MachineState.SLEEP
        if self._homing:
            return MachineState.HOME
        if self._alarm:
            return MachineState.ALARM
        if self._check_mode:
            return MachineState.CHECK
        if self._hold:
            return MachineState.HOLD
        front = self.motion.front
        if self._jog_cancel or (front is not None and front.move.jog):
            return MachineState.JOG
        if not self.motion.empty:
            return MachineState.RUN
        return MachineState.IDLE

    def status_text(self) -> str:
        """One status report, as ``?`` gets it."""
        state = self.state
        moving = self.motion.speed_mm_s > 0.0
        label = state.value
        feed = 0.0
        if state is MachineState.HOLD:
            label = "Hold:1" if moving else "Hold:0"
            feed = 0.0 if moving else self.motion.segment_feed_mm_s * 60.0
        elif state in (MachineState.RUN, MachineState.JOG):
            feed = self.motion.segment_feed_mm_s * 60.0
        wco = self.gcode.work_offset()
        include_wco = self._last_wco != wco or self._reports_since_wco >= WCO_REFRESH_REPORTS - 1
        if include_wco:
            self._last_wco = wco
            self._reports_since_wco = 0
        else:
            self._reports_since_wco += 1
        front = self.motion.front
        line_number = 0
        if self.config.defaults.line_numbers and front is not None and not self.motion.empty:
            line_number = front.move.line_number
        buffer = None
        if self.settings.report_buffer:
            free_blocks = self._blocks - min(self._blocks, self.motion.segments)
            buffer = (free_blocks, self.serial.free_bytes)
        spindle_on = self.gcode.modal.spindle in (3, 4)
        return status_report(
            StatusFields(
                state=label,
                mpos_mm=self.motion.position_mm,
                wco_mm=wco,
                report_mpos=self.settings.report_mpos,
                inches=self.settings.report_inches,
                buffer=buffer,
                line_number=line_number,
                feed_mm_min=feed,
                spindle_rpm=self.gcode.spindle_rpm if spindle_on else 0.0,
                include_wco=include_wco,
                overrides=(
                    self.motion.feed_override_pct,
                    self.motion.rapid_override_pct,
                    self._spindle_ov,
                ),
            )
        )

    # ========================================================== real-time bytes
    def _realtime(self, byte: int) -> None:
        self.stats.realtime_bytes += 1
        if byte == SOFT_RESET:
            self._soft_reset()
        elif byte == STATUS_QUERY:
            if self._critical and not self.config.defaults.status_in_critical_alarm:
                return  # classic grbl serves nothing but a reset after a limit alarm
            self.stats.status_reports += 1
            self._emit(self.status_text())
        elif self._sleep or self._critical or self._homing:
            return
        elif byte == FEED_HOLD:
            self._feed_hold()
        elif byte == CYCLE_START:
            self._cycle_start()
        elif byte == JOG_CANCEL:
            if self.state is MachineState.JOG and not self._jog_cancel:
                self._jog_cancel = True
                self.motion.hold()
        elif byte in FEED_OV:
            self.motion.set_overrides(
                _override(self.motion.feed_override_pct, FEED_OV[byte]),
                self.motion.rapid_override_pct,
            )
        elif byte in RAPID_OV:
            self.motion.set_overrides(self.motion.feed_override_pct, RAPID_OV[byte])
        elif byte in SPINDLE_OV:
            self._spindle_ov = _override(self._spindle_ov, SPINDLE_OV[byte])
        # Other extended bytes (safety door, coolant toggles, ...) are taken off the stream
        # and ignored: this machine has none of those.

    def _feed_hold(self) -> None:
        state = self.state
        if state is MachineState.JOG:
            if not self._jog_cancel:
                self._jog_cancel = True
                self.motion.hold()
        elif state in (MachineState.IDLE, MachineState.RUN):
            self._hold = True
            self.motion.hold()

    def _cycle_start(self) -> None:
        # Only a completed hold resumes; a hold still decelerating ignores the cycle start.
        if self._hold and self.motion.speed_mm_s == 0.0 and not self._soft_limit_stop:
            self._hold = False
            self.motion.resume()

    def _soft_reset(self) -> None:
        """0x18: stop, flush, re-initialise; ALARM:3 if the table was moving."""
        state = self.state
        moving = state in (MachineState.RUN, MachineState.JOG, MachineState.HOME) or (
            state is MachineState.HOLD and self.motion.speed_mm_s > 0.0
        )
        alarm = Alarm.HOMING_FAIL_RESET if self._homing else Alarm.ABORT_CYCLE
        self.stats.resets += 1
        self._epoch += 1
        self.motion.clear()
        self.motion.set_overrides(100, 100)
        self._spindle_ov = 100
        self.serial.clear()
        self._pending = None
        self._hold = self._soft_limit_stop = self._jog_cancel = False
        self._critical = self._check_mode = self._homing = False
        if self._sleep:
            self._sleep = False
            self._alarm = True
        self.gcode.reset(self.motion.position_mm)
        self._last_wco = None
        if moving:
            self._alarm = True
            self._emit_alarm(alarm)
        self._emit(banner(self.config))
        if self._alarm:
            self._emit(UNLOCK_HINT)
        else:
            self._run_startup_lines()

    def _emit_alarm(self, alarm: Alarm) -> None:
        self.stats.alarms[int(alarm)] += 1
        self._emit(f"ALARM:{int(alarm)}")

    def _limit_alarm(self, alarm: Alarm) -> None:
        """A limit alarm: motion flushed, position kept, nothing served until a reset."""
        self.motion.clear()
        self.gcode.sync_position(self.motion.position_mm)
        self._pending = None
        self._hold = self._soft_limit_stop = self._jog_cancel = False
        self._alarm = self._critical = True
        self._emit_alarm(alarm)
        self._emit("[MSG:Reset to continue]")

    def _finish_jog_cancel(self) -> None:
        self._jog_cancel = False
        self.motion.clear()
        self.gcode.sync_position(self.motion.position_mm)
        if self._pending is not None and self._pending.jog:
            self._pending = None
            self._answer(None)

    def _jog_within_travel(self, move: Move) -> bool:
        return not self.settings.soft_limits or self._within_travel(move)

    def _within_travel(self, move: Move) -> bool:
        xmin, xmax, ymin, ymax = move.xy_extents()
        tx, ty = self.settings.travel_mm
        eps = 1e-6
        return xmin >= -eps and ymin >= -eps and xmax <= tx + eps and ymax <= ty + eps

    # ================================================================ main loop
    def _main_loop(self) -> None:
        """Take lines out of the receive buffer while nothing blocks the parser."""
        if self._pending is not None and not self._run_pending():
            return
        epoch = self._epoch
        while not (self._critical or self._sleep):
            item = self.serial.next_line()
            if item is None:
                return
            self._execute_line(*item)
            if self._epoch != epoch or self._pending is not None:
                return  # a reset flushed the buffer, or the line waits for the planner

    def _execute_line(self, line: str, overflow: bool) -> None:
        if overflow:
            self._answer(Status.OVERFLOW)
        elif not line:
            self._answer(None)
        elif line[0] == "$":
            self._system_command(line)
        elif self.state in (MachineState.ALARM, MachineState.JOG):
            self._count_words(line)
            self._answer(Status.SYSTEM_GC_LOCK)
        else:
            self._count_words(line)
            try:
                actions = self.gcode.execute(scan_words(line))
            except GcodeRefused as exc:
                self._answer(exc.status)
                return
            if self._check_mode:
                self._answer(None)
                return
            self._pending = _Pending(deque(actions))
            self._run_pending()

    def _count_words(self, line: str) -> None:
        self.stats.z_words_received += line.count("Z")
        self.stats.spindle_words_received += len(_SPINDLE_WORD.findall(line))

    def _run_pending(self) -> bool:
        """Carry the pending line on; True once it is answered."""
        pending = self._pending
        assert pending is not None
        motion = self.motion
        while pending.actions:
            if self._soft_limit_stop or self._jog_cancel:
                return False
            action = pending.actions[0]
            if isinstance(action, Move):
                if not pending.planned:
                    if motion.segments >= self._blocks:
                        return False
                    if self.settings.soft_limits and not self._within_travel(action):
                        self._soft_limit(action)
                        return False
                    if motion.plan(action):
                        self.stats.moves += 1
                    pending.planned = True
                if motion.segments > self._blocks:
                    return False  # the rest of an arc's chords still wait for room
                pending.planned = False
            elif isinstance(action, Dwell):
                if not motion.empty:
                    return False
                if pending.dwell_left_s is None:
                    pending.dwell_left_s = action.seconds
                if pending.dwell_left_s > 1e-9:
                    return False
                pending.dwell_left_s = None
            elif isinstance(action, ProgramStop):
                if not motion.empty:
                    return False
                if not action.end:
                    if not pending.paused:
                        pending.paused = True
                        self._hold = True
                        motion.hold()
                    if self._hold:
                        return False
                else:
                    motion.set_overrides(100, 100)  # grbl restores overrides at program end
                    self._spindle_ov = 100
                    self._emit("[MSG:Pgm End]")
            pending.actions.popleft()
        self._pending = None
        if pending.homing:
            self._homing = self._alarm = False
            self.gcode.sync_position(motion.position_mm)
        self._answer(None)
        return True

    def _soft_limit(self, move: Move) -> None:
        """A target beyond the travel: stop under control, then ALARM:2 (grbl 1.1)."""
        if self.motion.empty:
            self._limit_alarm(Alarm.SOFT_LIMIT)
        else:
            self._soft_limit_stop = True
            self._hold = True
            self.motion.hold()

    def _run_startup_lines(self) -> None:
        for line in self.startup_lines:
            if not line:
                continue
            try:
                actions = self.gcode.execute(scan_words(line))
            except GcodeRefused as exc:
                self._emit(f">{line}:error:{int(exc.status)}")
                continue
            for action in actions:
                if isinstance(action, Move):
                    self.motion.plan(action)
            self._emit(f">{line}:ok")

    # ========================================================== $ commands
    def _system_command(self, line: str) -> None:
        try:
            status = self._system(line)
        except GcodeRefused as exc:
            status = exc.status
        if status is not _Reply.HANDLED:
            self._answer(status)

    def _system(self, line: str) -> Status | _Reply | None:
        """Run a ``$`` line; return its answer (None: ok), or HANDLED if it answered itself."""
        state = self.state
        if line == "$":
            self._emit(HELP)
            return None
        command = line[1]
        if command == "J":
            if state not in (MachineState.IDLE, MachineState.JOG):
                return Status.IDLE_ERROR
            if len(line) < 3 or line[2] != "=":
                return Status.INVALID_STATEMENT
            self._count_words(line[3:])
            actions = self.gcode.execute(scan_words(line[3:]), jog=True)
            self._pending = _Pending(deque(actions), jog=True)
            self._run_pending()
            return _Reply.HANDLED
        if command in "$GCX":
            if len(line) != 2:
                return Status.INVALID_STATEMENT
            if command == "$":
                if state in (MachineState.RUN, MachineState.HOLD):
                    return Status.IDLE_ERROR
                for text in self.settings.listing():
                    self._emit(text)
            elif command == "G":
                self._emit(self.gcode.state_report(report_inches=self.settings.report_inches))
            elif command == "C":
                return self._toggle_check_mode()
            elif self._alarm:  # $X
                self._alarm = False
                self._emit("[MSG:Caution: Unlocked]")
            return None
        if state not in (MachineState.IDLE, MachineState.ALARM):
            return Status.IDLE_ERROR
        if command == "#":
            if len(line) != 2:
                return Status.INVALID_STATEMENT
            for text in self.gcode.parameter_report(report_inches=self.settings.report_inches):
                self._emit(text)
            return None
        if command == "H":
            return self._home()
        if command == "S":
            if line != "$SLP":
                return Status.INVALID_STATEMENT
            self._answer(None)
            self._emit("[MSG:Sleeping]")
            self.motion.clear()
            self._sleep = True
            return _Reply.HANDLED
        if command == "I":
            return self._build_info(line)
        if command == "R":
            return self._restore(line)
        if command == "N" and len(line) == 2:
            for n, text in enumerate(self.startup_lines):
                self._emit(f"$N{n}={text}")
            return None
        return self._assign(line)

    def _home(self) -> Status | _Reply:
        """``$H`` (with ``$22=1``): this table homes to machine zero at the rapid rate."""
        if not self.settings.homing:
            return Status.SETTING_DISABLED
        x, y, z = self.motion.position_mm
        home = Move(MoveKind.RAPID, (x, y, z), (0.0, 0.0, z))
        self._homing = True
        self._pending = _Pending(deque([home, Dwell(0.0)]), homing=True)
        self._run_pending()
        return _Reply.HANDLED

    def _toggle_check_mode(self) -> Status | _Reply | None:
        if self._check_mode:
            self._emit("[MSG:Disabled]")
            self._answer(None)
            self._soft_reset()
            return _Reply.HANDLED
        if self.state is not MachineState.IDLE:
            return Status.IDLE_ERROR
        self._check_mode = True
        self._emit("[MSG:Enabled]")
        return None

    def _build_info(self, line: str) -> Status | None:
        if line == "$I":
            for text in build_info(self.config, self.build_info_text):
                self._emit(text)
            return None
        if line[2] != "=":
            return Status.INVALID_STATEMENT
        if len(line) - 3 > BUILD_INFO_MAX_CHARS:
            return Status.LINE_LENGTH_EXCEEDED
        self.build_info_text = line[3:]
        return None

    def _restore(self, line: str) -> Status | _Reply | None:
        if not line.startswith("$RST=") or len(line) != 6 or line[5] not in "$#*":
            return Status.INVALID_STATEMENT
        which = line[5]
        if which in "$*":
            self.settings = Settings.from_config(self.config)
            self._apply_motion_settings()
        if which in "#*":
            self.gcode.restore_parameters()
        if which == "*":
            self.startup_lines = [""] * N_STARTUP_LINES
            self.build_info_text = ""
        self._emit("[MSG:Restoring defaults]")
        self._answer(None)
        self._soft_reset()
        return _Reply.HANDLED

    def _assign(self, line: str) -> Status | None:
        """``$N=value`` settings and ``$Nx=line`` startup lines."""
        startup = line[1] == "N"
        start = 2 if startup else 1
        number, i = read_number(line, start)
        if number is None:
            return Status.BAD_NUMBER_FORMAT
        if i >= len(line) or line[i] != "=":
            return Status.INVALID_STATEMENT
        if startup:
            if self.state is not MachineState.IDLE:
                return Status.IDLE_ERROR
            index = int(number)
            if index >= N_STARTUP_LINES:
                return Status.INVALID_STATEMENT
            text = line[i + 1 :]
            # Checked on a scratch parser: a stored line must parse, it is not run now.
            self.gcode.scratch_copy().execute(scan_words(text))
            self.startup_lines[index] = text
            return None
        value, j = read_number(line, i + 1)
        if value is None:
            return Status.BAD_NUMBER_FORMAT
        if j != len(line) or number > 255:
            return Status.INVALID_STATEMENT
        key = self.settings.assign(number, value)
        if key in MOTION_SETTINGS:
            self._apply_motion_settings()
        return None

    def _apply_motion_settings(self) -> None:
        s = self.settings
        self.motion.reconfigure(
            accel_mm_s2=s.accel_mm_s2,
            junction_deviation_mm=s.junction_deviation_mm,
            max_rate_mm_min=s.max_rate_mm_min,
        )


def _override(current: int, step: str) -> int:
    if step == "reset":
        return 100
    return max(10, min(200, current + int(step)))
