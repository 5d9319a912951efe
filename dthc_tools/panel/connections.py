"""The panel's connections: a deadline for each request's head, a cap on how many are open,
and one rate-limited log line when the process runs out of file descriptors.

Hand-written because aiohttp's server has neither: nothing ends a connection that sends its
request line a byte at a time (its keep-alive timer, an hour by default, is all), and it
accepts connections until ``accept()`` fails with EMFILE, which asyncio then reports through
the loop's exception handler, with a traceback, for every retry. Each connection's protocol
(aiohttp's own ``RequestHandler``) is wrapped by a :class:`GuardedConnection` that:

- closes the connection when a request's head has not arrived ``header_timeout_s`` after the
  connection opened or the previous request was handled (an idle keep-alive connection is
  closed by the same deadline; a browser opens another);
- is told by the app (:func:`request_started` from the first middleware) that a head arrived;
  a live-update stream or a control's body then runs under its own limits (server.py);
- when ``max_connections`` are open, makes room by closing the connection that has waited
  longest for a head (a slow sender or an idle keep-alive), or, if every connection is busy
  with a request, answers the new one 503 and closes it.
"""

from __future__ import annotations

import asyncio
import errno
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import structlog
from aiohttp import web

__all__ = [
    "HEADER_TIMEOUT_S",
    "MAX_CONNECTIONS",
    "ConnectionLimits",
    "ConnectionPool",
    "GuardedConnection",
    "OutOfDescriptorsLog",
    "request_started",
    "start_guarded_site",
]

log = structlog.get_logger("dthc_tools.panel.connections")

HEADER_TIMEOUT_S = 10.0  # a request's head, from the connection (or the last answer) on
MAX_CONNECTIONS = 256  # open at once; well under the usual 1024 descriptors of a process
OUT_OF_FDS_LOG_PERIOD_S = 10.0  # at most one "out of file descriptors" line this often
_OUT_OF_FDS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
_BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\nContent-Length: 31\r\n"
    b"Retry-After: 5\r\nConnection: close\r\n\r\nthe panel has too many clients\n"
)


@dataclass(frozen=True)
class ConnectionLimits:
    header_timeout_s: float = HEADER_TIMEOUT_S
    max_connections: int = MAX_CONNECTIONS


class ConnectionPool:
    """Every open connection, and those waiting for a request's head (oldest first). A
    protocol factory for ``loop.create_server``: ``factory`` makes the wrapped protocol."""

    def __init__(self, factory: Callable[[], asyncio.Protocol], limits: ConnectionLimits) -> None:
        self.factory = factory
        self.limits = limits
        self.open: set[GuardedConnection] = set()
        self.waiting: dict[GuardedConnection, None] = {}  # insertion order: oldest first
        self.head_timeouts = 0  # closed: no request's head within the deadline
        self.evicted = 0  # closed to make room for a new connection
        self.refused = 0  # answered 503: every connection was busy

    def __call__(self) -> GuardedConnection:
        return GuardedConnection(self)

    def admit(self, connection: GuardedConnection) -> bool:
        if len(self.open) >= self.limits.max_connections:
            if not self.waiting:
                self.refused += 1
                return False
            oldest = next(iter(self.waiting))
            self.evicted += 1
            oldest.close()
        self.open.add(connection)
        return True

    def stats(self) -> dict[str, int]:
        return {
            "open": len(self.open), "waiting_for_head": len(self.waiting),
            "head_timeouts": self.head_timeouts, "evicted": self.evicted,
            "refused": self.refused,
        }  # fmt: skip


class GuardedConnection(asyncio.Protocol):
    """One connection: aiohttp's protocol inside, a deadline for each request's head."""

    def __init__(self, pool: ConnectionPool) -> None:
        self._pool = pool
        self._inner: asyncio.Protocol | None = None
        self._transport: asyncio.Transport | None = None
        self._deadline: asyncio.TimerHandle | None = None

    # --- asyncio's side: passed on to aiohttp's protocol ----------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport
        if not self._pool.admit(self):
            transport.write(_BUSY)
            transport.close()
            return
        self._inner = self._pool.factory()
        self._inner.connection_made(transport)
        self.wait_for_head()

    def connection_lost(self, exc: Exception | None) -> None:
        self._stop_waiting()
        self._pool.open.discard(self)
        self._transport = None
        if self._inner is not None:
            self._inner.connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._inner is not None:
            self._inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self._inner.eof_received() if self._inner is not None else None

    def pause_writing(self) -> None:
        if self._inner is not None:
            self._inner.pause_writing()

    def resume_writing(self) -> None:
        if self._inner is not None:
            self._inner.resume_writing()

    # --- the deadline -----------------------------------------------------------------------

    def wait_for_head(self) -> None:
        """From now, a request's head must arrive within the deadline."""
        if self._transport is None or self._transport.is_closing():
            return
        self._stop_waiting()
        self._pool.waiting[self] = None
        loop = asyncio.get_running_loop()
        self._deadline = loop.call_later(self._pool.limits.header_timeout_s, self._head_late)

    def head_arrived(self) -> None:
        self._stop_waiting()

    def close(self) -> None:
        self._stop_waiting()
        if self._transport is not None:
            self._transport.close()

    def _stop_waiting(self) -> None:
        self._pool.waiting.pop(self, None)
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _head_late(self) -> None:
        self._deadline = None
        self._pool.head_timeouts += 1
        self.close()


def request_started(request: web.BaseRequest) -> GuardedConnection | None:
    """The app's first middleware: a request's head arrived on this connection. The guarded
    connection (None under a plain aiohttp site, as in tests) is told again when the
    request was handled (:meth:`GuardedConnection.wait_for_head`)."""
    transport = request.transport
    protocol = transport.get_protocol() if transport is not None else None
    if isinstance(protocol, GuardedConnection):
        protocol.head_arrived()
        return protocol
    return None


class OutOfDescriptorsLog:
    """The loop's exception handler: asyncio's accept loop reports EMFILE (and its kin) with
    a traceback at every retry; this turns them into one warning per period with a count,
    and passes anything else to the handler it replaced."""

    def __init__(self, previous: Any = None, period_s: float = OUT_OF_FDS_LOG_PERIOD_S) -> None:
        self._previous = previous
        self._period_s = period_s
        self._last = -float("inf")
        self.unlogged = 0
        self.total = 0

    def __call__(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        exc = context.get("exception")
        if isinstance(exc, OSError) and exc.errno in _OUT_OF_FDS:
            self.total += 1
            self.unlogged += 1
            now = time.monotonic()
            if now - self._last >= self._period_s:
                log.warning(
                    "panel_out_of_file_descriptors", error=errno.errorcode.get(exc.errno or 0),
                    refused_accepts=self.unlogged, total=self.total,
                    limit=resource.getrlimit(resource.RLIMIT_NOFILE)[0],
                )  # fmt: skip
                self._last = now
                self.unlogged = 0
            return
        if self._previous is not None:
            self._previous(loop, context)
        else:
            loop.default_exception_handler(context)


async def start_guarded_site(
    runner: web.AppRunner, host: str, port: int, limits: ConnectionLimits
) -> tuple[asyncio.Server, ConnectionPool]:
    """Serve ``runner``'s app on HOST:PORT, each connection guarded; the loop's exception
    handler logs running out of descriptors once per period. The caller closes the server
    before ``runner.cleanup()``, which ends the connections still open."""
    loop = asyncio.get_running_loop()
    if not isinstance(loop.get_exception_handler(), OutOfDescriptorsLog):
        loop.set_exception_handler(OutOfDescriptorsLog(loop.get_exception_handler()))
    server = runner.server
    assert server is not None, "runner.setup() first"
    pool = ConnectionPool(server, limits)
    return await loop.create_server(pool, host, port), pool
