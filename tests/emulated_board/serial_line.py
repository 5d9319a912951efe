"""A raw pty client for the self-test program's line protocol (firmware/emulator/selftest)."""

from __future__ import annotations

import os
import select
import time
import tty
from pathlib import Path

__all__ = ["LineClient"]


class LineClient:
    """Opens the board's pty raw; sends a line, reads the reply line."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.buf = b""

    def close(self) -> None:
        os.close(self.fd)

    def read_line(self, timeout_s: float = 2.0) -> bytes:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self.buf:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self.fd], [], [], max(left, 0.0))
            if not ready:
                raise TimeoutError(f"no line within {timeout_s} s (have {self.buf!r})")
            self.buf += os.read(self.fd, 4096)
        line, _, self.buf = self.buf.partition(b"\n")
        return line

    def drain(self, quiet_s: float = 0.05) -> bytes:
        """Whatever arrives until the line is quiet for ``quiet_s``."""
        got = self.buf
        self.buf = b""
        while True:
            ready, _, _ = select.select([self.fd], [], [], quiet_s)
            if not ready:
                return got
            got += os.read(self.fd, 4096)

    def ask(self, line: str, timeout_s: float = 2.0) -> str:
        os.write(self.fd, line.encode() + b"\n")
        return self.read_line(timeout_s).decode(errors="replace")

    def write(self, data: bytes) -> None:
        os.write(self.fd, data)
