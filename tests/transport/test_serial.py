"""Serial transport over a real pseudo-terminal: exchange, unplug, exclusive open, bad path.

Closing the pty's master side is what a USB unplug looks like to pyserial (EIO on read and
write), so these tests cover the unplug path without hardware.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from dthc_bridge.transport import LinkUnavailable, TransportError, open_transport

from .helpers import WAIT_S, Recorder, settle


@dataclass
class Pty:
    master: int
    slave: int
    path: str
    master_open: bool = True

    def close_master(self) -> None:
        if self.master_open:
            self.master_open = False
            os.close(self.master)


@pytest.fixture
def pty() -> Iterator[Pty]:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    os.set_blocking(master, False)
    pair = Pty(master, slave, os.ttyname(slave))
    yield pair
    pair.close_master()
    os.close(slave)


async def read_master(pty: Pty, count: int, timeout_s: float = WAIT_S) -> bytes:
    """Read exactly ``count`` bytes from the board side of the pty."""
    loop = asyncio.get_running_loop()
    buf = bytearray()
    done: asyncio.Future[None] = loop.create_future()

    def ready() -> None:
        with contextlib.suppress(BlockingIOError):
            buf.extend(os.read(pty.master, count - len(buf)))
        if len(buf) >= count and not done.done():
            done.set_result(None)

    loop.add_reader(pty.master, ready)
    try:
        async with asyncio.timeout(timeout_s):
            await done
    finally:
        loop.remove_reader(pty.master)
    return bytes(buf)


async def test_bytes_flow_both_ways_through_a_pty_symlink(pty: Pty, tmp_path: Path) -> None:
    """Opened by a symlink (like a udev name), the port passes bytes both ways unchanged."""
    link = tmp_path / "board"
    link.symlink_to(pty.path)
    rec = Recorder()
    transport = await open_transport(str(link), rec.on_bytes, rec.on_lost)
    try:
        assert transport.is_open
        assert transport.url == str(link)
        transport.write(b"\x00hello\xff")
        assert await read_master(pty, 7) == b"\x00hello\xff"
        everything = bytes(range(256))
        os.write(pty.master, everything)
        assert await rec.wait_for_bytes(256) == everything
        assert rec.lost == []
    finally:
        await transport.close()
    assert rec.lost == [None]
    assert not transport.is_open


async def test_close_reports_on_lost_none_once_and_is_idempotent(pty: Pty) -> None:
    """A close we asked for reports None exactly once, however often close is called."""
    rec = Recorder()
    transport = await open_transport(pty.path, rec.on_bytes, rec.on_lost)
    await asyncio.gather(transport.close(), transport.close())
    await transport.close()
    await settle()
    assert rec.lost == [None]
    with pytest.raises(TransportError, match="closed"):
        transport.write(b"x")


async def test_unplug_mid_stream_reports_one_transport_error(pty: Pty) -> None:
    """Master closed while bytes flow (a USB unplug): on_lost once, with a TransportError."""
    rec = Recorder()
    transport = await open_transport(pty.path, rec.on_bytes, rec.on_lost)
    try:
        os.write(pty.master, b"before")
        await rec.wait_for_bytes(6)
        os.write(pty.master, b"in flight" * 10)
        pty.close_master()
        error = await rec.wait_for_lost()
        assert isinstance(error, TransportError)
        assert error.url == pty.path
        assert not transport.is_open
        with pytest.raises(TransportError):
            transport.write(b"after the unplug")
        await settle(0.05)
        assert len(rec.lost) == 1
    finally:
        await transport.close()
    assert len(rec.lost) == 1  # the close after the loss reports nothing more


async def test_write_into_an_unplugged_port_reports_one_transport_error(pty: Pty) -> None:
    """A write that hits EIO before the reader noticed the unplug still ends in one on_lost."""
    rec = Recorder()
    transport = await open_transport(pty.path, rec.on_bytes, rec.on_lost)
    try:
        pty.close_master()
        transport.write(b"into the void")  # fails asynchronously, inside pyserial-asyncio-fast
        error = await rec.wait_for_lost()
        assert isinstance(error, TransportError)
        with pytest.raises(TransportError):
            transport.write(b"again")
        await settle(0.05)
        assert len(rec.lost) == 1
    finally:
        await transport.close()
    assert len(rec.lost) == 1


async def test_a_missing_device_raises_transport_error_on_open(tmp_path: Path) -> None:
    """A path that does not exist (board unplugged at start) fails the open with the path
    and the OS's words, nothing leaks."""
    rec = Recorder()
    missing = str(tmp_path / "ttyACM9")
    with pytest.raises(LinkUnavailable) as info:
        await open_transport(missing, rec.on_bytes, rec.on_lost)
    assert info.value.url == missing
    assert str(info.value) == f"cannot open {missing}: No such file or directory"
    assert info.value.os_error == "[Errno 2] No such file or directory"
    assert rec.lost == []


async def test_a_second_open_of_the_same_port_fails(pty: Pty) -> None:
    """The port is opened exclusively: a second opener is refused and the first keeps working."""
    first, second = Recorder(), Recorder()
    transport = await open_transport(pty.path, first.on_bytes, first.on_lost)
    try:
        with pytest.raises(LinkUnavailable, match="in use by another program") as refused:
            await open_transport(pty.path, second.on_bytes, second.on_lost)
        assert refused.value.errno is not None  # EAGAIN or EWOULDBLOCK from flock
        transport.write(b"still mine")
        assert await read_master(pty, 10) == b"still mine"
    finally:
        await transport.close()
    assert second.lost == []
    # Once closed, the port can be opened again.
    again = await open_transport(pty.path, second.on_bytes, second.on_lost)
    await again.close()
    assert second.lost == [None]


async def test_discard_output_keeps_the_port_usable(pty: Pty) -> None:
    """Dropping queued output (before a retransmission) works on a pty and loses no later bytes."""
    rec = Recorder()
    transport = await open_transport(pty.path, rec.on_bytes, rec.on_lost)
    try:
        transport.discard_output()
        transport.write(b"fresh")
        assert await read_master(pty, 5) == b"fresh"
    finally:
        await transport.close()
    transport.discard_output()  # after close: a no-op, not an error
