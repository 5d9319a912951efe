"""TCP streams (``socket://host:port``): a board behind a serial-to-network bridge, or the mock.

Nagle is switched off so every small frame leaves at once. The peer closing its end (EOF)
or resetting the connection is a lost link: ``on_lost(TransportError)``, once.
"""

from __future__ import annotations

import asyncio
import socket

from .base import BytesCallback, LostCallback, Transport, TransportError
from .url import TcpUrl

__all__ = ["CLOSE_TIMEOUT_S", "CONNECT_TIMEOUT_S", "TcpTransport", "open_tcp"]

CONNECT_TIMEOUT_S = 5.0
"""Bound on resolving and connecting before :func:`open_tcp` gives up."""

CLOSE_TIMEOUT_S = 2.0
"""Bound on sending queued bytes in :meth:`TcpTransport.close` before the socket is aborted."""


class _TcpProtocol(asyncio.Protocol):
    def __init__(self, owner: TcpTransport) -> None:
        self._owner = owner

    def data_received(self, data: bytes) -> None:
        self._owner._data_received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._owner._connection_lost(exc)


class TcpTransport(Transport):
    """An open TCP connection. Create with :func:`open_tcp` (or ``open_transport``)."""

    def __init__(self, url: str, on_bytes: BytesCallback, on_lost: LostCallback) -> None:
        self.url = url
        self._on_bytes = on_bytes
        self._on_lost = on_lost
        self._loop = asyncio.get_running_loop()
        self._sock_transport: asyncio.Transport | None = None
        self._open = False
        self._closing = False
        self._reported = False
        self._released: asyncio.Future[None] = self._loop.create_future()

    async def _connect(self, host: str, port: int, timeout_s: float) -> None:
        try:
            async with asyncio.timeout(timeout_s):
                transport, _ = await self._loop.create_connection(
                    lambda: _TcpProtocol(self), host, port
                )
        except TimeoutError as exc:
            raise TransportError(self.url, f"connect timed out after {timeout_s} s") from exc
        except OSError as exc:  # refused, unreachable, name resolution (gaierror)
            raise TransportError(self.url, f"cannot connect: {exc}") from exc
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock_transport = transport
        self._open = True

    @property
    def is_open(self) -> bool:
        t = self._sock_transport
        return self._open and t is not None and not t.is_closing()

    def write(self, data: bytes) -> None:
        if not self.is_open:
            raise TransportError(self.url, "write on a closed TCP connection")
        assert self._sock_transport is not None
        self._sock_transport.write(data)

    async def close(self) -> None:
        t = self._sock_transport
        if t is None:
            return
        first = self._open
        self._open = False
        self._closing = True
        if first and not t.is_closing():
            t.close()
        try:
            async with asyncio.timeout(CLOSE_TIMEOUT_S):
                await asyncio.shield(self._released)
        except TimeoutError:
            t.abort()  # peer not reading: drop what is queued
            await asyncio.shield(self._released)
        if first:
            self._report(None)

    # --- called by _TcpProtocol -------------------------------------------------------------

    def _data_received(self, data: bytes) -> None:
        if self._open:
            self._on_bytes(data)

    def _connection_lost(self, exc: Exception | None) -> None:
        if not self._released.done():
            self._released.set_result(None)
        if self._closing:
            return  # close() reports on_lost(None)
        self._open = False
        if exc is None:
            error = TransportError(self.url, "closed by peer")
        else:
            error = TransportError(self.url, f"connection lost: {exc}")
            error.__cause__ = exc
        self._report(error)

    def _report(self, exc: Exception | None) -> None:
        if not self._reported:
            self._reported = True
            self._on_lost(exc)


async def open_tcp(
    url: str,
    link: TcpUrl,
    on_bytes: BytesCallback,
    on_lost: LostCallback,
    *,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
) -> TcpTransport:
    """Connect to ``link.host:link.port``; TransportError if refused, unreachable or timed out."""
    transport = TcpTransport(url, on_bytes, on_lost)
    await transport._connect(link.host, link.port, connect_timeout_s)
    return transport
