"""The reference G-code sender: ``dthc-bridge send PROGRAM.nc``."""

from __future__ import annotations

from .backend import BackendError, MotionBackend, SimGantryBackend
from .daemon_client import DaemonClient, DaemonError
from .sender import Sender, SendReport

__all__ = [
    "BackendError",
    "DaemonClient",
    "DaemonError",
    "MotionBackend",
    "SendReport",
    "Sender",
    "SimGantryBackend",
]
