"""TCP streams (``socket://host:port``): a board behind a serial-to-network bridge, or the mock.

Nagle is switched off so every small frame leaves at once. The peer closing its end (EOF)
or resetting the connection is a lost link: ``on_lost(TransportError)``, once.
"""

from __future__ import annotations

import asyncio
import socket

from .base import BytesCallback, LostCallback, TransportError
from .stream import StreamTransport
from .url import TcpUrl

__all__ = ["CLOSE_TIMEOUT_S", "CONNECT_TIMEOUT_S", "TcpTransport", "open_tcp"]

CONNECT_TIMEOUT_S = 5.0
"""Bound on resolving and connecting before :func:`open_tcp` gives up."""

CLOSE_TIMEOUT_S = 2.0
"""Bound on sending queued bytes in :meth:`TcpTransport.close` before the socket is aborted."""


class TcpTransport(StreamTransport):
    """An open TCP connection. Create with :func:`open_tcp` (or ``open_transport``)."""

    kind = "TCP connection"
    close_timeout_s = CLOSE_TIMEOUT_S
    _lib: asyncio.Transport | None

    async def _connect(self, host: str, port: int, timeout_s: float) -> None:
        try:
            async with asyncio.timeout(timeout_s):
                transport, _ = await self._loop.create_connection(self._protocol, host, port)
        except TimeoutError as exc:
            raise TransportError(self.url, f"connect timed out after {timeout_s} s") from exc
        except OSError as exc:  # refused, unreachable, name resolution (gaierror)
            raise TransportError(self.url, f"cannot connect: {exc}") from exc
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._opened(transport)

    async def _close_timed_out(self) -> None:
        assert self._lib is not None
        self._lib.abort()  # peer not reading: drop what is queued
        await asyncio.shield(self._released)

    def _lost_detail(self, exc: Exception | None) -> str:
        return f"connection lost: {exc}" if exc is not None else "closed by peer"


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
