"""The grbl port as its own process, for the tests and the bench: started against a
stack's grbl and broker, ready once its pty is there."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import IO

from ..procs import die_with_parent

__all__ = ["start_port"]


def start_port(
    listen: Path,
    grbl: Path,
    broker_port: int,
    base_topic: str,
    log: IO[str],
    *,
    ready_s: float = 20.0,
) -> subprocess.Popen[bytes]:
    """``dthc-bridge grbl-port --listen LISTEN --grbl GRBL`` on a local broker; returns once
    the port's pty exists (RuntimeError naming the log if it exits or times out first)."""
    proc = subprocess.Popen(  # noqa: S603 - our own module, fixed arguments
        [sys.executable, "-m", "dthc_bridge", "grbl-port", "--listen", str(listen),
         "--grbl", str(grbl), "--broker", f"mqtt://127.0.0.1:{broker_port}",
         "--base-topic", base_topic],
        stdout=log, stderr=log, preexec_fn=die_with_parent(),
    )  # fmt: skip
    deadline = time.monotonic() + ready_s
    while not listen.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"the grbl port did not start: see {log.name}")
        time.sleep(0.05)
    return proc
