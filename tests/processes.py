"""Our own processes in tests (the mock board, the emulated grbl, the panel): stopped the
way a service manager stops them."""

from __future__ import annotations

import signal
import subprocess

__all__ = ["stop"]


def stop(proc: subprocess.Popen[str]) -> int:
    """SIGTERM, wait up to 5 s (then kill); the exit status. Its pipes are closed."""
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
