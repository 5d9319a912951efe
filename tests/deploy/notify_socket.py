"""A stand-in for systemd's notify socket: collects what a process sends to NOTIFY_SOCKET.

Reusable by any test that starts the daemon (or anything else) under a fake service
manager::

    with FakeNotifySocket() as manager:
        proc = subprocess.Popen([...], env={**os.environ, **manager.env(watchdog_usec=200_000)})
        manager.wait_for("READY=1", timeout_s=10)
        ...
    pings = manager.times_of("WATCHDOG=1")

Each datagram is recorded with the receive time (``time.monotonic()`` in the test process)
and the sender's pid (SCM_CREDENTIALS), so a test can check timing and that only the main
process notifies (``NotifyAccess=main``). The pytest fixtures ``notify_socket`` (a socket
file) and ``abstract_notify_socket`` (an ``@name`` in the abstract namespace) are
registered for ``tests/deploy`` by its conftest; elsewhere import them from here.
"""

from __future__ import annotations

import shutil
import socket
import struct
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import pytest

__all__ = [
    "FakeNotifySocket",
    "Notification",
    "abstract_notify_socket",
    "notify_socket",
]

_UCRED = struct.Struct("iII")  # pid, uid, gid
_POLL_S = 0.05


@dataclass(frozen=True)
class Notification:
    """One datagram: when it arrived, who sent it, what it said."""

    time_s: float
    pid: int | None
    message: str

    @property
    def assignments(self) -> dict[str, str]:
        """``KEY=VALUE`` lines as a dict (``READY=1\\nSTATUS=x`` -> two keys)."""
        pairs = (line.partition("=") for line in self.message.splitlines() if line)
        return {key: value for key, _, value in pairs}


class FakeNotifySocket:
    """A bound ``AF_UNIX`` datagram socket and a thread that records what arrives."""

    def __init__(self, *, abstract: bool = False) -> None:
        self._dir: Path | None = None
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
        self._sock.settimeout(_POLL_S)
        if abstract:
            name = f"dthc-test-notify-{uuid.uuid4().hex}"
            self._sock.bind("\0" + name)
            self.address = "@" + name
        else:
            # A short directory of our own: sun_path holds at most 107 bytes.
            self._dir = Path(tempfile.mkdtemp(prefix="sdn-"))
            path = self._dir / "notify"
            self._sock.bind(str(path))
            self.address = str(path)
        self._received: list[Notification] = []
        self._changed = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive, name="fake-notify", daemon=True)
        self._thread.start()

    def env(
        self, *, watchdog_usec: int | None = None, watchdog_pid: int | None = None
    ) -> dict[str, str]:
        """Environment variables systemd would pass for this socket (and a watchdog)."""
        env = {"NOTIFY_SOCKET": self.address}
        if watchdog_usec is not None:
            env["WATCHDOG_USEC"] = str(watchdog_usec)
        if watchdog_pid is not None:
            env["WATCHDOG_PID"] = str(watchdog_pid)
        return env

    @property
    def notifications(self) -> list[Notification]:
        with self._changed:
            return list(self._received)

    def messages(self) -> list[str]:
        return [item.message for item in self.notifications]

    def times_of(self, message: str) -> list[float]:
        """Arrival times of every datagram that is exactly ``message``."""
        return [item.time_s for item in self.notifications if item.message == message]

    def wait_for(self, message: str, *, timeout_s: float, count: int = 1) -> Notification:
        """Block until ``count`` datagrams containing the line ``message`` have arrived.

        Returns the last of them; AssertionError naming what did arrive on timeout.
        """
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while True:
                matching = [n for n in self._received if message in n.message.splitlines()]
                if len(matching) >= count:
                    return matching[count - 1]
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    got = [n.message for n in self._received]
                    raise AssertionError(
                        f"{count} x {message!r} not received in {timeout_s} s: {got}"
                    )
                self._changed.wait(remaining)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._sock.close()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> FakeNotifySocket:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def _receive(self) -> None:
        ancillary = socket.CMSG_SPACE(_UCRED.size)
        while not self._stop.is_set():
            try:
                data, ancdata, _flags, _addr = self._sock.recvmsg(4096, ancillary)
            except TimeoutError:
                continue
            except OSError:
                return
            now = time.monotonic()
            pid = None
            for level, kind, payload in ancdata:
                if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS:
                    pid = _UCRED.unpack_from(payload)[0]
            with self._changed:
                self._received.append(Notification(now, pid, data.decode(errors="replace")))
                self._changed.notify_all()


@pytest.fixture
def notify_socket() -> Iterator[FakeNotifySocket]:
    """A fake notify socket bound to a file (NOTIFY_SOCKET=/tmp/sdn-.../notify)."""
    with FakeNotifySocket() as manager:
        yield manager


@pytest.fixture
def abstract_notify_socket() -> Iterator[FakeNotifySocket]:
    """A fake notify socket in the abstract namespace (NOTIFY_SOCKET=@name)."""
    with FakeNotifySocket(abstract=True) as manager:
        yield manager
