"""TCP transport (``socket://host:port``) against a real asyncio server on loopback."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

import pytest

from dthc_bridge.transport import TransportError, open_transport

from .helpers import Recorder, settle


@dataclass
class Board:
    """The server side: what it received, and the open connection's writer."""

    received: bytearray = field(default_factory=bytearray)
    writer: asyncio.StreamWriter | None = None
    connected: asyncio.Event = field(default_factory=asyncio.Event)
    eof: asyncio.Event = field(default_factory=asyncio.Event)
    nodelay: int = -1

    async def handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.writer = writer
        self.connected.set()
        try:
            while chunk := await reader.read(4096):
                self.received += chunk
            self.eof.set()
        finally:
            writer.close()
            await writer.wait_closed()


@pytest.fixture
async def board() -> AsyncIterator[tuple[Board, str]]:
    state = Board()
    server = await asyncio.start_server(state.handle, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    async with server:
        yield state, f"socket://127.0.0.1:{port}"
        if state.writer is not None:
            state.writer.close()
    await server.wait_closed()


async def test_bytes_flow_both_ways_over_tcp(board: tuple[Board, str]) -> None:
    """Written bytes reach the server and the server's bytes reach on_bytes, in order."""
    state, url = board
    rec = Recorder()
    transport = await open_transport(url, rec.on_bytes, rec.on_lost)
    try:
        assert transport.is_open
        await asyncio.wait_for(state.connected.wait(), 2)
        transport.write(b"\x00ping")
        transport.write(b"\x00")
        assert state.writer is not None
        state.writer.write(b"pong\x00")
        assert await rec.wait_for_bytes(5) == b"pong\x00"
    finally:
        await transport.close()
    await asyncio.wait_for(state.eof.wait(), 2)
    assert bytes(state.received) == b"\x00ping\x00"
    assert rec.lost == [None]


async def test_refused_connection_raises_transport_error() -> None:
    """Nobody listening: the open fails with TransportError naming the URL."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    url = f"socket://127.0.0.1:{port}"
    rec = Recorder()
    with pytest.raises(TransportError, match="cannot connect") as info:
        await open_transport(url, rec.on_bytes, rec.on_lost)
    assert info.value.url == url
    assert rec.lost == []


async def test_server_closing_reports_one_transport_error(board: tuple[Board, str]) -> None:
    """The peer hanging up is a lost link: on_lost(TransportError('closed by peer')) once."""
    state, url = board
    rec = Recorder()
    transport = await open_transport(url, rec.on_bytes, rec.on_lost)
    try:
        await asyncio.wait_for(state.connected.wait(), 2)
        assert state.writer is not None
        state.writer.write(b"last words")
        state.writer.close()
        error = await rec.wait_for_lost()
        assert isinstance(error, TransportError)
        assert "closed by peer" in str(error)
        assert rec.data == b"last words"
        assert not transport.is_open
        with pytest.raises(TransportError):
            transport.write(b"anyone?")
        await settle()
    finally:
        await transport.close()
    assert len(rec.lost) == 1
