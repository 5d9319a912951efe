"""The session's first words wait for the board's: an Arduino opened through its USB-serial
chip resets and runs its bootloader first, and a byte sent then reaches the bootloader (the
Mega's stk500v2 then waits 5 s more). Against the real bootloaders:
tests/emulated_board/test_bootloader.py."""

from __future__ import annotations

import asyncio

import firmware_protocol as fp
from dthc_bridge.link import LinkTiming
from dthc_bridge.link.session import BoardSession
from dthc_bridge.link.stats import LinkStats
from dthc_bridge.transport import Transport
from dthc_bridge.transport.base import BytesCallback, LostCallback


class Recorder(Transport):
    """A transport that keeps what the session writes; the test plays the board."""

    def __init__(self) -> None:
        self.url = "test://board"
        self.written: list[bytes] = []
        self._open = True

    def write(self, data: bytes) -> None:
        self.written.append(data)

    async def close(self) -> None:
        self._open = False

    @property
    def is_open(self) -> bool:
        return self._open


async def open_session(boot_window_s: float) -> tuple[BoardSession, Recorder, BytesCallback]:
    transport = Recorder()
    received: list[BytesCallback] = []

    async def opener(on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
        received.append(on_bytes)
        return transport

    session = BoardSession("test://board", LinkTiming(boot_window_s=boot_window_s), LinkStats())
    await session.open(opener)
    return session, transport, received[0]


async def test_nothing_is_sent_until_the_board_speaks() -> None:
    """Opening sends no byte; the wait ends at the board's first valid frame (not at its
    garbage: a bootloader's bytes are not a frame), well before the boot window."""
    session, transport, to_host = await open_session(boot_window_s=5.0)
    waiting = asyncio.create_task(session.wait_for_board())
    await asyncio.sleep(0.1)
    to_host(b"\x14\x10garbage\x00")  # what a bootloader may say
    await asyncio.sleep(0.1)
    assert transport.written == []
    assert not waiting.done()
    to_host(fp.encode(fp.Ack(0, 0x1234)))
    assert await asyncio.wait_for(waiting, 0.5) is True
    await session.close()


async def test_a_silent_board_is_spoken_to_after_the_boot_window() -> None:
    """A board that says nothing of itself is not waited for forever: after boot_window_s
    the wait ends (False) and the handshake may start."""
    session, transport, _ = await open_session(boot_window_s=0.2)
    loop = asyncio.get_running_loop()
    started_s = loop.time()
    assert await session.wait_for_board() is False
    assert 0.15 <= loop.time() - started_s < 1.0
    assert transport.written == []
    await session.close()
