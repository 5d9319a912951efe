"""Where the mock board's bytes go: a raw pseudo-terminal behind a stable symlink, or TCP.

A pty stands in for a USB CDC-ACM port: closing its master side makes pyserial on the
other end raise exactly what a USB unplug raises (EIO on read and write).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty
from collections.abc import Callable
from pathlib import Path

__all__ = ["BoardLink", "PtyLink", "TcpLink"]


class BoardLink:
    """One end of the host link, owned by the mock board process."""

    def __init__(self, on_bytes: Callable[[bytes], None]) -> None:
        self.on_bytes = on_bytes
        self.dropped_writes = 0

    async def open(self) -> None:
        raise NotImplementedError

    def write(self, data: bytes) -> None:
        raise NotImplementedError

    async def close(self) -> None:
        raise NotImplementedError

    @property
    def is_open(self) -> bool:
        raise NotImplementedError


class PtyLink(BoardLink):
    def __init__(self, path: Path, on_bytes: Callable[[bytes], None]) -> None:
        super().__init__(on_bytes)
        self.path = path
        self._master: int | None = None
        self._slave: int | None = None

    @property
    def is_open(self) -> bool:
        return self._master is not None

    async def open(self) -> None:
        master, slave = os.openpty()
        # Raw mode on both sides: no echo, no line discipline, 8-bit clean, like a USB port.
        tty.setraw(slave)
        tty.setraw(master)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        # Keeping the slave open ourselves means a host that closes and reopens the port does
        # not make the master read EIO; only an "unplug" (closing the master) does.
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(os.ttyname(slave))
        tmp.replace(self.path)  # atomic: the path never points at a dead pty
        asyncio.get_running_loop().add_reader(master, self._readable)

    @property
    def device(self) -> str | None:
        """The pty's device (/dev/pts/N) while open."""
        return os.ttyname(self._slave) if self._slave is not None else None

    def _readable(self) -> None:
        assert self._master is not None
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError:
            return
        if data:
            self.on_bytes(data)

    def write(self, data: bytes) -> None:
        if self._master is None or not data:
            return
        try:
            os.write(self._master, data)
        except (BlockingIOError, OSError):
            # Nobody reads the port: a real board's USB buffer overflows the same way.
            self.dropped_writes += 1

    async def close(self) -> None:
        if self._master is not None:
            asyncio.get_running_loop().remove_reader(self._master)
            os.close(self._master)
            self._master = None
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None
        with contextlib.suppress(FileNotFoundError):
            if self.path.is_symlink():
                self.path.unlink()


class TcpLink(BoardLink):
    """``socket://HOST:PORT``: one host connection at a time, as ser2net would serve it."""

    def __init__(self, host: str, port: int, on_bytes: Callable[[bytes], None]) -> None:
        super().__init__(on_bytes)
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._writer: asyncio.StreamWriter | None = None

    @property
    def is_open(self) -> bool:
        return self._server is not None

    @property
    def bound_port(self) -> int:
        assert self._server is not None
        port: int = self._server.sockets[0].getsockname()[1]
        return port

    async def open(self) -> None:
        self._server = await asyncio.start_server(self._client, self.host, self.port)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._writer is not None:
            self._writer.close()
        self._writer = writer
        try:
            while data := await reader.read(4096):
                self.on_bytes(data)
        except ConnectionError:
            pass
        finally:
            if self._writer is writer:
                self._writer = None
            writer.close()

    def write(self, data: bytes) -> None:
        if self._writer is None or self._writer.is_closing():
            self.dropped_writes += 1
            return
        self._writer.write(data)

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None
