"""The transport seam: bytes in and out of one board connection, nothing else.

A transport knows nothing of frames. It delivers received bytes to ``on_bytes`` from the
event loop thread, accepts writes without blocking, and reports its loss exactly once
through ``on_lost`` (with the exception, or None for a close we asked for). Library errors
(pyserial, pyusb, OSError) are wrapped in :class:`TransportError` here, at the seam.
"""

from __future__ import annotations

import abc
import os
from collections.abc import Awaitable, Callable

__all__ = [
    "BytesCallback",
    "LinkUnavailable",
    "LostCallback",
    "Transport",
    "TransportError",
    "TransportOpener",
]

BytesCallback = Callable[[bytes], None]
LostCallback = Callable[[Exception | None], None]


class TransportError(Exception):
    """Opening, writing to or reading from the board connection failed."""

    def __init__(self, url: str, detail: str) -> None:
        super().__init__(url, detail)  # args stay (url, detail): the error copies and pickles
        self.url = url
        self.detail = detail

    def __str__(self) -> str:
        return f"{self.url}: {self.detail}"


class LinkUnavailable(TransportError):
    """The link cannot be opened (no such device, permission denied, in use): the path and
    what the OS said, so the log and the published state can say it in those words."""

    def __init__(self, url: str, reason: str, errno: int | None = None) -> None:
        super().__init__(url, f"cannot open: {reason}")
        self.args = (url, reason, errno)  # copies and pickles rebuild this class
        self.reason = reason  # the OS's words: "No such file or directory"
        self.errno = errno

    @property
    def os_error(self) -> str:
        """``[Errno 2] No such file or directory`` (the reason alone without an errno)."""
        if self.errno is None:
            return self.reason
        return f"[Errno {self.errno}] {os.strerror(self.errno)}"

    def __str__(self) -> str:
        return f"cannot open {self.url}: {self.reason}"


class Transport(abc.ABC):
    """One open connection to a board. Create with :func:`dthc_bridge.transport.open_transport`."""

    url: str

    @abc.abstractmethod
    def write(self, data: bytes) -> None:
        """Queue bytes for sending. Raises TransportError once the loss is known; a write
        that fails later is reported through ``on_lost`` instead."""

    @abc.abstractmethod
    async def close(self) -> None:
        """Close; idempotent. ``on_lost(None)`` is called if it was still open."""

    @property
    @abc.abstractmethod
    def is_open(self) -> bool: ...

    async def __aenter__(self) -> Transport:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    def discard_output(self) -> None:  # noqa: B027 - optional hook, a no-op by default
        """Drop bytes queued but not yet sent (before a retransmission), where possible."""


TransportOpener = Callable[[BytesCallback, LostCallback], Awaitable[Transport]]
"""Opens one connection given the receiver's callbacks: :func:`open_transport` bound to a
URL in production; tests and the simulation hand the link layer their own."""
