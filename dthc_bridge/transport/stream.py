"""What the asyncio-protocol transports (serial, TCP) share: callbacks, loss, closing.

A library transport (pyserial-asyncio-fast's or asyncio's socket transport) calls our
:class:`ForwardingProtocol`; the owner turns its ``connection_lost`` into exactly one
``on_lost``: ``TransportError`` for a loss, ``None`` for a close we asked for.
"""

from __future__ import annotations

import asyncio
from typing import Protocol

from .base import BytesCallback, LostCallback, Transport, TransportError

__all__ = ["ForwardingProtocol", "LibraryTransport", "StreamTransport"]


class LibraryTransport(Protocol):
    def is_closing(self) -> bool: ...
    def write(self, data: bytes) -> None: ...
    def close(self) -> None: ...


class StreamTransport(Transport):
    """Base of transports driven by an :class:`asyncio.Protocol` callback pair."""

    kind = "link"  # for messages: "serial port", "TCP connection"
    close_timeout_s = 2.0

    def __init__(self, url: str, on_bytes: BytesCallback, on_lost: LostCallback) -> None:
        self.url = url
        self._on_bytes = on_bytes
        self._on_lost = on_lost
        self._loop = asyncio.get_running_loop()
        self._lib: LibraryTransport | None = None
        self._open = False
        self._closing = False
        self._reported = False
        self._released: asyncio.Future[None] = self._loop.create_future()

    def _protocol(self) -> ForwardingProtocol:
        return ForwardingProtocol(self)

    def _opened(self, lib: LibraryTransport) -> None:
        self._lib = lib
        self._open = True

    @property
    def is_open(self) -> bool:
        lib = self._lib
        return self._open and lib is not None and not lib.is_closing()

    def write(self, data: bytes) -> None:
        lib = self._lib
        if lib is None or not self.is_open:
            raise TransportError(self.url, f"write on a closed {self.kind}")
        # Errors surface asynchronously: the library aborts and connection_lost reports them.
        lib.write(data)

    async def close(self) -> None:
        lib = self._lib
        if lib is None:
            return
        first = self._open
        self._open = False
        self._closing = True
        if first and not lib.is_closing():
            lib.close()  # sends what is queued, then closes
        try:
            async with asyncio.timeout(self.close_timeout_s):
                await asyncio.shield(self._released)
        except TimeoutError:
            await self._close_timed_out()
        if first:
            self._report(None)

    async def _close_timed_out(self) -> None:
        """The queued bytes did not drain in time (subclasses abort or log)."""

    def _lost_detail(self, exc: Exception | None) -> str:
        return f"connection lost: {exc}" if exc is not None else "closed by the other end"

    # --- called by ForwardingProtocol ------------------------------------------------------

    def _data_received(self, data: bytes) -> None:
        if self._open:
            self._on_bytes(data)

    def _connection_lost(self, exc: Exception | None) -> None:
        if not self._released.done():
            self._released.set_result(None)
        if self._closing:
            return  # close() reports on_lost(None)
        self._open = False
        error = TransportError(self.url, self._lost_detail(exc))
        error.__cause__ = exc
        self._report(error)

    def _report(self, exc: Exception | None) -> None:
        if not self._reported:
            self._reported = True
            self._on_lost(exc)


class ForwardingProtocol(asyncio.Protocol):
    """Forwards the library's protocol calls to the owning :class:`StreamTransport`."""

    def __init__(self, owner: StreamTransport) -> None:
        self._owner = owner

    def data_received(self, data: bytes) -> None:
        self._owner._data_received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._owner._connection_lost(exc)
