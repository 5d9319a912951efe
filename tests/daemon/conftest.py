"""The whole daemon as its own process, with a real mosquitto and the mock board on a pty."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from dthc_tools.procs import die_with_parent
from tests.mqtt.conftest import Broker, own_broker  # noqa: F401 - shared fixture

STARTUP_S = 10.0


class MockBoard:
    def __init__(self, workdir: Path, *extra: str) -> None:
        self.pty = workdir / "dthc0"
        self.truth = workdir / "truth.jsonl"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mock_device", "--pty", str(self.pty), "--seed", "2",
             "--truth", str(self.truth), *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=die_with_parent(),
        )  # fmt: skip
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        assert line.startswith("READY"), line

    def stop(self) -> dict[str, Any]:
        """Stop the mock and return its exit report (torch state, faults, violations)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        _, err = self.proc.communicate(timeout=10)
        assert self.proc.stdout is not None
        for line in reversed(err.splitlines()):
            if '"event": "exit"' in line:
                report: dict[str, Any] = json.loads(line)
                return report
        raise AssertionError(f"no exit report from the mock:\n{err}")


class Daemon:
    def __init__(self, workdir: Path, config: str, env: dict[str, str] | None = None) -> None:
        self.config = workdir / "config.toml"
        self.config.write_text(config)
        self.log = workdir / "daemon.log"
        self._log = self.log.open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "dthc_bridge", "run", "--config", str(self.config)],
            stdout=self._log, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})},
            preexec_fn=die_with_parent(),
        )  # fmt: skip

    def signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def wait(self, timeout_s: float) -> int:
        return self.proc.wait(timeout_s)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        self._log.close()

    def output(self) -> str:
        return self.log.read_text()


def daemon_config(pty: Path, broker: Broker, base: str, **mqtt: object) -> str:
    extra = "".join(f"{key} = {json.dumps(value)}\n" for key, value in mqtt.items())
    return f"""
[board]
link = "{pty}"
lease_ms = 200

[mqtt]
host = "{broker.host}"
port = {broker.port}
base_topic = "{base}"
board_id = "t1"
reconnect_initial_s = 0.1
reconnect_max_s = 0.5
state_poll_s = 0.05
{extra}
[logging]
level = "info"
json_logs = true
"""


@pytest.fixture
def mock_board(tmp_path: Path) -> Iterator[MockBoard]:
    board = MockBoard(tmp_path)
    yield board
    if board.proc.poll() is None:
        board.proc.kill()
        board.proc.communicate(timeout=5)


def wait_until(predicate: Any, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return False
