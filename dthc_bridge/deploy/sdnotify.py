"""sd_notify(3) without libsystemd: readiness, status and the watchdog for ``Type=notify``.

systemd passes ``NOTIFY_SOCKET`` (an ``AF_UNIX`` datagram socket; a leading ``@`` means the
abstract namespace) and, with ``WatchdogSec=``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID``.
Outside systemd none of them is set and every call here is a no-op. Sending never raises:
a failed notification is logged and counted, it does not take the daemon down.

The watchdog is fed from the event loop itself (:meth:`SdNotifier.watchdog_loop`), so the
pings stop when the loop is blocked and systemd restarts a daemon that has hung. It is not
gated on the board: an unplugged board is reported over MQTT; a restart would not fix it.
"""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Mapping
from types import TracebackType

import structlog

__all__ = ["SdNotifier"]

log = structlog.get_logger("dthc_bridge.sdnotify")


class SdNotifier:
    """One service's notification channel to systemd (or nowhere, outside systemd).

    ``address`` is ``NOTIFY_SOCKET`` as systemd spells it (a path, or ``@name`` for the
    abstract namespace); ``None`` disables notification. ``watchdog_usec`` is the watchdog
    timeout that applies to this process, or ``None``.
    """

    def __init__(self, address: str | None, *, watchdog_usec: int | None = None) -> None:
        self._address = _socket_address(address) if address else None
        self._watchdog_usec = watchdog_usec
        self._sock: socket.socket | None = None
        self.sent = 0
        self.failed = 0
        self._failing = False  # log a run of failures once, and the recovery
        if address and self._address is None:
            log.warning("sd_notify_unsupported_socket", notify_socket=address)

    @classmethod
    def from_env(
        cls, environ: Mapping[str, str] | None = None, *, pid: int | None = None
    ) -> SdNotifier:
        """Read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID`` (sd_watchdog_enabled).

        The watchdog applies only when ``WATCHDOG_USEC`` is a positive integer and
        ``WATCHDOG_PID``, if set, names this process (``pid``, default ``os.getpid()``).
        """
        env = os.environ if environ is None else environ
        own_pid = os.getpid() if pid is None else pid
        return cls(env.get("NOTIFY_SOCKET") or None, watchdog_usec=_watchdog_usec(env, own_pid))

    @property
    def enabled(self) -> bool:
        """True when there is a notify socket to talk to."""
        return self._address is not None

    def notify(self, message: str) -> bool:
        """Send one datagram of ``KEY=VALUE`` lines; True if it was handed to the socket."""
        if self._address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                # Never block the event loop on a busy manager: a full queue is a failure.
                self._sock.setblocking(False)
            self._sock.sendto(message.encode(), self._address)
        except OSError as exc:
            self.failed += 1
            if not self._failing:
                self._failing = True
                log.warning("sd_notify_failed", message=message, error=str(exc))
            return False
        self.sent += 1
        if self._failing:
            self._failing = False
            log.info("sd_notify_recovered", failed=self.failed)
        return True

    def ready(self, status: str | None = None) -> bool:
        """``READY=1`` (with an optional ``STATUS=``): start-up is complete."""
        return self.notify("READY=1" if status is None else f"READY=1\nSTATUS={_one_line(status)}")

    def stopping(self) -> bool:
        """``STOPPING=1``: shutdown has begun."""
        return self.notify("STOPPING=1")

    def status(self, text: str) -> bool:
        """``STATUS=``: a one-line state shown by ``systemctl status``."""
        return self.notify(f"STATUS={_one_line(text)}")

    def watchdog(self) -> bool:
        """One ``WATCHDOG=1`` keep-alive."""
        return self.notify("WATCHDOG=1")

    def watchdog_period_s(self) -> float | None:
        """Seconds between keep-alives: half the watchdog timeout; None without a watchdog."""
        if self._watchdog_usec is None:
            return None
        return self._watchdog_usec / 2 / 1_000_000

    async def watchdog_loop(self) -> None:
        """Send ``WATCHDOG=1`` every :meth:`watchdog_period_s` until cancelled.

        Runs on the event loop on purpose: while the loop is blocked no ping goes out.
        Returns at once when there is no watchdog (or no socket).
        """
        period_s = self.watchdog_period_s()
        if period_s is None or not self.enabled:
            return
        log.debug("sd_watchdog_started", period_s=period_s)
        while True:
            self.watchdog()
            await asyncio.sleep(period_s)

    def close(self) -> None:
        """Close the socket (idempotent); later notifications open a new one."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> SdNotifier:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _socket_address(notify_socket: str) -> str | None:
    """The ``sendto`` address for a ``NOTIFY_SOCKET`` value; None if not an AF_UNIX one."""
    if notify_socket.startswith("@"):
        return "\0" + notify_socket[1:]
    if notify_socket.startswith("/"):
        return notify_socket
    return None  # e.g. vsock:CID:PORT (VMs); not something a shop PC hands us


def _watchdog_usec(env: Mapping[str, str], own_pid: int) -> int | None:
    try:
        usec = int(env.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    if usec <= 0:
        return None
    watchdog_pid = env.get("WATCHDOG_PID")
    if watchdog_pid is not None:
        try:
            if int(watchdog_pid) != own_pid:
                return None
        except ValueError:
            return None
    return usec


def _one_line(text: str) -> str:
    return " ".join(text.splitlines())
