"""The emulated grbl (and the mock board) as processes in tests: started until READY,
stopped with SIGTERM, their exit figures read from the log."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

from dthc_tools.procs import die_with_parent
from tests.processes import stop

__all__ = ["exit_line", "start_ready", "stop"]


def start_ready(cmd: list[str], log: Path) -> tuple[subprocess.Popen[str], str]:
    """Start a process that prints READY on stdout; the process and that line."""
    with log.open("w") as stderr:
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=stderr,
            text=True,
            preexec_fn=die_with_parent(),
        )
    assert proc.stdout is not None
    ready = proc.stdout.readline()
    assert ready.startswith("READY"), ready + log.read_text()
    return proc, ready.strip()


def exit_line(log: Path) -> dict[str, Any]:
    """The emulator's (or the mock's) exit figures, from its log."""
    events = [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]
    exits = [e for e in events if e["event"] == "exit"]
    assert exits, log.read_text()
    exit_line: dict[str, Any] = exits[-1]
    return exit_line
