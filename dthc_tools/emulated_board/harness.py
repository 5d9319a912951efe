"""The emulated board as a process for tests and benchmarks, and its event record.

    with EmulatedBoard(pty_path, HarnessOptions(record=tmp / "rec.csv")) as board:
        board.command("set estop 1")        # "ok", or ControlError with the host's reason
        board.status().z_um
        board.reboot()                      # SIGUSR2: an external reset, Z kept
    events = read_record(tmp / "rec.csv")

The process is started with ``die_with_parent`` (and checks its parent itself), so it never
outlives the test. Record lines are ``t_us,mono_s,event,fields...`` (firmware/emulator/
README.md): ``t_us`` simulated microseconds since power-on, ``mono_s`` the host's
CLOCK_MONOTONIC (``time.monotonic()``) when the line was written.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import subprocess
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Final

from dthc_tools.procs import die_with_parent

from .build import (
    EmulatedBoardError,
    arduino_bootloader,
    checkout_root,
    ensure_built,
    firmware_elf,
    host_binary,
)

__all__ = [
    "BoardStatus",
    "ControlError",
    "EmulatedBoard",
    "FrameEvent",
    "HarnessOptions",
    "RecordEvent",
    "frames",
    "read_record",
    "relay_off_after_last_host_byte_us",
    "reply_delays_us",
    "torch_on_edges",
    "unsafe_torch_us",
]

READY_TIMEOUT_S: Final = 10.0
REPLY_TIMEOUT_S: Final = 5.0
STOP_TIMEOUT_S: Final = 5.0
INJECT_CHUNK: Final = 240  # bytes per ``inject`` line (the control line holds 511 chars)
QUERY_TYPE: Final = 0x0C
STATUS_TYPE: Final = 0x88


class ControlError(EmulatedBoardError):
    """The host answered a control command with ``error: ...``, or not at all."""


@dataclass(frozen=True)
class HarnessOptions:
    mcu: str = "atmega2560"
    elf: Path | None = None  # None: the firmware's ELF for ``mcu`` (built if stale)
    record: Path | None = None
    seed: int = 1
    # Model options by their command-line names without dashes, e.g. {"plate-mm": 19.5}.
    model: Mapping[str, float] = field(default_factory=dict)
    build: bool = True  # run make first (only what is stale is rebuilt)
    stderr: Path | None = None  # the host's log (simavr's own lines, exit summary)
    # The arc front end: "adc" (the ADC channel), or "vtof" (a voltage-to-frequency card on
    # the Mega's T5: the host drives the pin, and ``elf`` None picks the vtof build).
    arc_input: str = "adc"
    # The card's nominal scaling (None: the host's defaults, 121 kHz at 0 V, 925 kHz at
    # 10 V), e.g. {"vtof-zero-hz": 100000.0}: vtof-zero-hz, vtof-full-hz, vtof-full-v.
    vtof: Mapping[str, float] = field(default_factory=dict)
    speed: float | None = None  # simulated seconds per wall second (0: flat out)
    # Arduino's bootloader at the top of flash (BOOTRST): every reset starts there, and the
    # port's opening resets the MCU (the auto-reset). The application then comes from
    # ``flash`` (Intel HEX, as avrdude leaves it), or is erased (None: a board as its
    # bootloader was burned); ``elf`` is not loaded (it still names the symbols for peek).
    bootloader: bool = False
    bootloader_kind: str | None = None  # one of build.MCU_BOOTLOADERS[mcu]; None: the first
    flash: Path | None = None


@dataclass(frozen=True)
class BoardStatus:
    """The host's ``status`` line, parsed."""

    t_us: int
    z_um: int
    torch: bool
    ohmic_enable: bool
    arc: str
    arc_v: float
    inputs: dict[str, bool]
    fields: dict[str, str]

    @classmethod
    def parse(cls, line: str) -> BoardStatus:
        words = line.split()
        if not words or words[0] != "status":
            raise ControlError(f"not a status line: {line!r}")
        f = dict(w.split("=", 1) for w in words[1:] if "=" in w)
        inputs = {}
        for item in f.get("inputs", "").split(","):
            if ":" in item:
                name, level = item.split(":", 1)
                inputs[name] = level.rstrip("!") == "1"
        return cls(
            t_us=int(f["t_us"]),
            z_um=int(f["z_um"]),
            torch=f["torch"] == "1",
            ohmic_enable=f["ohmic_enable"] == "1",
            arc=f["arc"],
            arc_v=float(f["arc_v"]),
            inputs=inputs,
            fields=f,
        )


class EmulatedBoard:
    """The emulated-board host as a child process (a context manager)."""

    def __init__(self, pty: Path, options: HarnessOptions | None = None) -> None:
        self.pty = pty
        self.options = options or HarnessOptions()
        self.proc: subprocess.Popen[bytes] | None = None
        self._buf = b""
        self._stderr: IO[bytes] | None = None

    @property
    def pid(self) -> int:
        return self._require().pid

    @property
    def elf(self) -> Path:
        """The ELF the board runs."""
        o = self.options
        return o.elf if o.elf is not None else firmware_elf(checkout_root(), o.mcu, o.arc_input)

    def command_line(self) -> list[str]:
        o = self.options
        root = checkout_root()
        argv = [str(host_binary(root)), "--mcu", o.mcu, "--pty", str(self.pty)]
        if o.bootloader:
            argv += ["--bootloader", str(arduino_bootloader(o.mcu, o.bootloader_kind))]
            if o.flash is not None:
                argv += ["--flash", str(o.flash)]
        else:
            argv += ["--elf", str(self.elf)]
        argv += ["--seed", str(o.seed), "--arc-input", o.arc_input]
        for key, value in o.vtof.items():
            argv += [f"--{key}", repr(float(value))]
        if o.speed is not None:
            argv += ["--speed", repr(float(o.speed))]
        if o.record is not None:
            argv += ["--record", str(o.record)]
        for key, value in o.model.items():
            argv += [f"--{key}", repr(float(value))]
        return argv

    def start(self, ready_timeout_s: float = READY_TIMEOUT_S) -> None:
        """Build what is stale (if asked), start the host, wait for its READY line."""
        if self.options.build:
            ensure_built(checkout_root(), firmware=self.options.elf is None)
        if self.options.flash is not None and not self.options.bootloader:
            raise EmulatedBoardError("HarnessOptions.flash needs bootloader=True")
        if self.options.stderr is not None:
            self._stderr = self.options.stderr.open("wb")
        self.proc = subprocess.Popen(  # noqa: S603 - our own host program, built here
            self.command_line(),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            bufsize=0,
            preexec_fn=die_with_parent(),
        )
        line = self._read_line(ready_timeout_s)
        if not line.startswith("READY "):
            status = self.proc.poll()
            self.stop()
            raise EmulatedBoardError(
                f"the emulated board did not start: {line!r} (exit status {status})"
            )

    def _require(self) -> subprocess.Popen[bytes]:
        if self.proc is None:
            raise EmulatedBoardError("the emulated board is not running")
        return self.proc

    def _read_line(self, timeout_s: float) -> str:
        proc = self._require()
        assert proc.stdout is not None
        fd = proc.stdout.fileno()
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                return ""
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                return ""
            chunk = os.read(fd, 4096)
            if not chunk:
                return ""
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        return line.decode(errors="replace")

    def command(self, line: str, timeout_s: float = REPLY_TIMEOUT_S) -> str:
        """Send one control command; its reply line. ControlError on ``error: ...``."""
        proc = self._require()
        assert proc.stdin is not None
        proc.stdin.write(line.encode() + b"\n")
        proc.stdin.flush()
        reply = self._read_line(timeout_s)
        if not reply:
            raise ControlError(f"no reply to {line!r} within {timeout_s} s")
        if reply.startswith("error:"):
            raise ControlError(reply)
        return reply

    def status(self) -> BoardStatus:
        return BoardStatus.parse(self.command("status"))

    def set_input(self, name: str, level: bool | None) -> None:
        """Force an input active (True) or inactive (False); None gives it back to the model."""
        self.command(f"set {name} {'auto' if level is None else int(level)}")

    def peek(self, symbol: str) -> int:
        """A firmware variable's value now (unsigned, little-endian, at most 4 bytes), found
        by its name in the ELF's symbol table (avr-nm)."""
        nm = shutil.which("avr-nm")  # binutils-avr, installed with the firmware's build tools
        if nm is None:
            raise ControlError("avr-nm is not installed (binutils-avr)")
        listing = subprocess.run(  # noqa: S603 - binutils' nm on our own ELF
            [nm, "-S", str(self.elf)], capture_output=True, text=True, check=True
        ).stdout
        for line in listing.splitlines():
            words = line.split()
            if len(words) == 4 and words[3] == symbol:
                addr, size = int(words[0], 16) & 0xFFFF, int(words[1], 16)
                return int(self.command(f"peek {addr} {min(size, 4)}").split()[1])
        raise ControlError(f"no symbol {symbol!r} with a size in {self.elf}")

    def unplug(self) -> None:
        """The cable pulled: the pty's master closed (the client reads EIO), the --pty link
        removed; the MCU runs on and what it sends goes nowhere. :meth:`replug` ends it."""
        self.command("unplug")

    def replug(self) -> None:
        """A new pty behind the same path, as a port that enumerates again."""
        self.command("replug")

    def inject(self, data: bytes) -> None:
        """Bytes into the board's stream to the host, after what the firmware has queued
        (garbage on the line), in lines of at most ``INJECT_CHUNK`` bytes."""
        for i in range(0, len(data), INJECT_CHUNK):
            self.command("inject " + data[i : i + INJECT_CHUNK].hex())

    def drop_frames(self, rate: float, for_s: float) -> None:
        """Lose each board frame whole with probability ``rate`` for ``for_s`` seconds (the
        host's frames untouched; the record says ``frame_lost`` for each)."""
        self.command(f"drop {rate!r} {for_s!r}")

    def reboot(self) -> None:
        """SIGUSR2: reset the MCU as its reset pin would; physical Z is kept."""
        self._require().send_signal(signal.SIGUSR2)

    def stop(self) -> int | None:
        """SIGTERM, wait (then kill); the exit status (None if it never started)."""
        proc = self.proc
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(STOP_TIMEOUT_S)
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
        return proc.returncode

    def __enter__(self) -> EmulatedBoard:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


# --- the record ----------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordEvent:
    t_us: int
    mono_s: float
    event: str
    fields: tuple[str, ...]


@dataclass(frozen=True)
class FrameEvent:
    """A frame delimiter: delivered to the UART (host_frame) or written by the board
    (board_frame); ``type_`` and ``seq`` from the frame's first decoded bytes."""

    t_us: int  # the delimiter
    mono_s: float
    type_: int | None
    seq: int | None
    encoded_len: int
    start_us: int | None  # the frame's first byte (None in records without it)


def read_record(path: Path) -> list[RecordEvent]:
    """Every complete line of a record (a partial last line, still being written, is left
    out; comment lines too)."""
    text = path.read_text(errors="replace")
    lines = text.split("\n")
    events = []
    for line in lines[:-1] if not text.endswith("\n") else lines:
        if not line or line.startswith("#"):
            continue
        parts = line.split(",")
        if len(parts) < 3:
            continue
        try:
            events.append(RecordEvent(int(parts[0]), float(parts[1]), parts[2], tuple(parts[3:])))
        except ValueError:
            continue
    return events


def frames(events: Iterable[RecordEvent], kind: str) -> list[FrameEvent]:
    """``kind``: "host_frame" or "board_frame"."""
    out = []
    for e in events:
        if e.event != kind or len(e.fields) < 3:
            continue
        type_ = int(e.fields[0], 16) if e.fields[0] != "?" else None
        seq = int(e.fields[1]) if e.fields[1] != "?" else None
        start = int(e.fields[3]) if len(e.fields) > 3 else None
        out.append(FrameEvent(e.t_us, e.mono_s, type_, seq, int(e.fields[2]), start))
    return out


def relay_off_after_last_host_byte_us(events: list[RecordEvent]) -> int | None:
    """Simulated µs from the last host frame delivered before the torch relay's last
    falling edge to that edge (the lease measured at the pin); None without both."""
    offs = [e for e in events if e.event == "torch" and e.fields[:1] == ("0",)]
    if not offs:
        return None
    off = offs[-1]
    before = [f for f in frames(events, "host_frame") if f.t_us <= off.t_us]
    if not before:
        return None
    return off.t_us - before[-1].t_us


def reply_delays_us(
    events: list[RecordEvent],
    request_type: int = QUERY_TYPE,
    reply_type: int = STATUS_TYPE,
    *,
    to_first_byte: bool = False,
) -> list[int]:
    """For each request frame delivered, simulated µs until the board wrote the delimiter
    (``to_first_byte``: the first byte) of the first later reply frame with the same seq
    (QUERY -> STATUS by default)."""
    replies = [f for f in frames(events, "board_frame") if f.type_ == reply_type]
    delays = []
    for req in frames(events, "host_frame"):
        if req.type_ != request_type or req.seq is None:
            continue
        match = next((r for r in replies if r.t_us >= req.t_us and r.seq == req.seq), None)
        if match is not None:
            end = match.start_us if to_first_byte and match.start_us is not None else match.t_us
            delays.append(end - req.t_us)
    return delays


def unsafe_torch_us(events: Iterable[RecordEvent], grace_us: int) -> tuple[int, int]:
    """Torch-relay time past the lease, from the record alone (simulated µs): the relay pin
    HIGH more than ``grace_us`` after the last host frame delivered to the UART before that
    moment. (total µs, episodes): an episode is one stretch of the relay on past its grace.
    The relay still on at the record's end counts up to its last line."""
    total = episodes = 0
    torch_on = False
    last_frame: int | None = None
    prev_t: int | None = None
    late = False
    for e in events:
        if torch_on and prev_t is not None:
            limit = (last_frame + grace_us) if last_frame is not None else prev_t
            late_us = max(0, e.t_us - max(prev_t, limit))
            if late_us and not late:
                episodes += 1
            late = late or late_us > 0
            total += late_us
        prev_t = e.t_us
        if e.event == "torch":
            torch_on = e.fields[:1] == ("1",)
            if not torch_on:
                late = False
        elif e.event == "host_frame":
            last_frame = e.t_us
            late = False
    return total, episodes


def torch_on_edges(events: Iterable[RecordEvent]) -> int:
    """The relay pin's rising edges: each torch-on the board carried out."""
    return sum(1 for e in events if e.event == "torch" and e.fields[:1] == ("1",))
