"""The emulator as its own process on a real pty, driven through pyserial like a USB port:
a character-counting streamer and a 10 Hz status poller, alone and with a mock board's
gantry mirroring the motion."""

from __future__ import annotations

import json
import re
import socket
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any

import pytest
import serial

from tests.grbl_emu.processes import exit_line, start_ready, stop

pytestmark = pytest.mark.slow

# 30 lines: rapids, feeds, arcs both ways, comments, a line number, modal words.
PROGRAM = [
    "G21 G90 G94 (metric, absolute)",
    "G0 X20 Y20",
    "G1 X80 Y20 F9000",
    "G2 X90 Y30 I0 J10",
    "G1 X90 Y70",
    "G3 X80 Y80 I-10 J0",
    "G1 X20 Y80",
    "G3 X10 Y70 I0 J-10",
    "G1 X10 Y30",
    "G2 X20 Y20 I10 J0 ; back to the start",
    "G0 X40 Y40",
    "G2 X40 Y40 I10 J0 F6000",
    "G0 X100 Y40",
    "N100 G1 X110 Y40 F9000",
    "X110 Y50",
    "X100 Y50",
    "X100 Y40",
    "G91",
    "G1 X5 Y5",
    "X5 Y-5",
    "X-5 Y-5",
    "X-5 Y5",
    "G90",
    "G0 X120 Y10",
    "G1 X130 Y10 F3000",
    "G2 X130 Y10 I5 J0",
    "G1 X140 Y10",
    "G1 X140 Y20",
    "G0 X150 Y25",
    "G1 X151.5 Y25.5 F1200",
]
FINAL_XY = (151.5, 25.5)
_FIELD = re.compile(r"([A-Za-z]+):([^|>]*)")


class GrblClient:
    """The smallest character-counting streamer: one port, one reader, no threads."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port
        self.buf = b""
        self.pending: deque[int] = deque()  # bytes of each unanswered line
        self.answers: list[str] = []
        self.reports: list[dict[str, str]] = []
        self.messages: list[str] = []

    def pump(self) -> None:
        """Read what arrived (waiting up to the port timeout) and sort it."""
        self.buf += self.port.read(self.port.in_waiting or 1)
        *lines, self.buf = self.buf.split(b"\r\n")
        for raw in lines:
            line = raw.decode("ascii")
            if line.startswith("<"):
                state = line[1:].split("|", 1)[0]
                self.reports.append({"state": state, **dict(_FIELD.findall(line))})
            elif line == "ok" or line.startswith("error:"):
                self.answers.append(line)
                self.pending.popleft()
            elif line:
                self.messages.append(line)

    def command(self, line: str, within_s: float = 2.0) -> list[str]:
        """Send one line, wait for its answer; the messages before it and the answer."""
        start_msgs, start_answers = len(self.messages), len(self.answers)
        self.pending.append(len(line) + 1)
        self.port.write(line.encode() + b"\n")
        deadline = time.monotonic() + within_s
        while len(self.answers) == start_answers:
            assert time.monotonic() < deadline, f"no answer to {line!r}"
            self.pump()
        return self.messages[start_msgs:] + self.answers[start_answers:]

    def wait_message(self, text: str, within_s: float = 2.0) -> None:
        """Read until a push message ``text`` arrives."""
        deadline = time.monotonic() + within_s
        while text not in self.messages:
            assert time.monotonic() < deadline, f"no {text!r}: {self.messages}"
            self.pump()

    def stream(self, lines: list[str], rx_bytes: int, poll_s: float = 0.1) -> None:
        """Character counting against ``rx_bytes``, a ``?`` every ``poll_s``; returns when
        every line is answered."""
        queue = deque(lines)
        next_poll = time.monotonic()
        deadline = next_poll + 60.0
        while queue or self.pending:
            assert time.monotonic() < deadline
            while queue and sum(self.pending) + len(queue[0]) + 1 < rx_bytes:
                line = queue.popleft()
                self.pending.append(len(line) + 1)
                self.port.write(line.encode() + b"\n")
            if time.monotonic() >= next_poll:
                self.port.write(b"?")
                next_poll += poll_s
            self.pump()

    def poll_until_idle(self, blocks: int, rx_bytes: int, poll_s: float = 0.1) -> dict[str, str]:
        """Poll at ``1/poll_s`` Hz until Idle with an empty planner; that report."""
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            self.port.write(b"?")
            seen = len(self.reports)
            until = time.monotonic() + poll_s
            while time.monotonic() < until:
                self.pump()
            for report in self.reports[seen:]:
                if report["state"] == "Idle" and report["Bf"] == f"{blocks},{rx_bytes}":
                    return report
        raise AssertionError(f"never idle: {self.reports[-3:]}")


def _run_program(tmp_path: Path, *extra: str) -> tuple[GrblClient, dict[str, str], Path]:
    pty = tmp_path / "grbl0"
    log = tmp_path / "emu.log"
    proc, ready = start_ready(
        [sys.executable, "-m", "dthc_tools.grbl_emu", "--pty", str(pty), *extra], log
    )
    assert ready == f"READY pty={pty}"
    try:
        with serial.Serial(str(pty), timeout=0.01, exclusive=True) as port:
            client = GrblClient(port)
            # pyserial flushes what came before the port was open (the start-up banner), as
            # a sender must expect: reset and wait for the banner.
            port.write(b"\x18")
            client.wait_message("Grbl 1.1f ['$' for help]")
            info = client.command("$I")
            opt = next(m for m in info if m.startswith("[OPT:"))
            _, blocks, rx = opt.removesuffix("]").split(",")
            assert (blocks, rx) == ("15", "128")
            assert info[-1] == "ok"
            client.stream(PROGRAM, int(rx))
            final = client.poll_until_idle(int(blocks), int(rx))
    finally:
        assert stop(proc) == 0
    return client, final, log


def test_streaming_a_program_by_character_counting_over_a_real_pty(tmp_path: Path) -> None:
    """Banner, $I, 30 lines streamed against 128 bytes with 10 Hz polling: Run, then Idle
    at the program's end point; every line ok, no byte lost, no Z or spindle word sent."""
    client, final, log = _run_program(tmp_path)
    assert client.answers == ["ok"] * (1 + len(PROGRAM))
    states = [r["state"] for r in client.reports]
    assert "Run" in states
    assert states[-1] == "Idle"
    assert final["MPos"] == f"{FINAL_XY[0]:.3f},{FINAL_XY[1]:.3f},0.000"
    assert any(r["Bf"].startswith("0,") for r in client.reports)  # the planner filled up
    stats = exit_line(log)
    assert stats["rx_overflow"] == 0
    assert stats["lines"] == 1 + len(PROGRAM)
    assert stats["errors"] == {}
    assert stats["z_words_received"] == 0
    assert stats["spindle_words_received"] == 0
    assert stats["status_reports"] >= 20


def _gantry_request(port: int, op: str) -> dict[str, Any]:
    with socket.create_connection(("127.0.0.1", port), timeout=10.0) as sock:
        sock.sendall(json.dumps({"op": op}).encode() + b"\n")
        reply = sock.makefile("rb").readline()
    result: dict[str, Any] = json.loads(reply)
    return result


def test_the_mock_boards_gantry_follows_the_emulator(tmp_path: Path) -> None:
    """With ``--plant``, the mock board's gantry runs the same moves: it ends where the
    emulator ends, having been told every line (and nothing refused)."""
    mock, ready = start_ready(
        [sys.executable, "-m", "mock_device", "--pty", str(tmp_path / "dthc0"),
         "--gantry-listen", "socket://127.0.0.1:0"],
        tmp_path / "mock.log",
    )  # fmt: skip
    try:
        gantry_port = int(next(w for w in ready.split() if w.startswith("gantry=")).split("=")[1])
        _, final, log = _run_program(tmp_path, "--plant", f"socket://127.0.0.1:{gantry_port}")
        plant = _gantry_request(gantry_port, "wait_idle")
    finally:
        stop(mock)
    x, y, _ = (float(v) for v in final["MPos"].split(","))
    assert (x, y) == FINAL_XY
    assert plant["x"] == pytest.approx(x, abs=1e-3)
    assert plant["y"] == pytest.approx(y, abs=1e-3)
    stats = exit_line(log)
    assert stats["plant"]["sent"] >= stats["moves"]  # every line, and the reset's clear
    assert (stats["plant"]["refused"], stats["plant"]["dropped"]) == (0, 0)
