"""What a transport's owner sees: received bytes and loss reports, with waits that time out."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

WAIT_S = 2.0


class Recorder:
    """Collects ``on_bytes`` chunks and ``on_lost`` calls from one transport."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.lost: list[Exception | None] = []
        self._changed = asyncio.Event()

    @property
    def data(self) -> bytes:
        return b"".join(self.chunks)

    def on_bytes(self, data: bytes) -> None:
        assert isinstance(data, bytes)
        self.chunks.append(data)
        self._changed.set()

    def on_lost(self, exc: Exception | None) -> None:
        self.lost.append(exc)
        self._changed.set()

    async def wait_until(self, condition: Callable[[], bool], timeout_s: float = WAIT_S) -> None:
        async with asyncio.timeout(timeout_s):
            while not condition():
                self._changed.clear()
                await self._changed.wait()

    async def wait_for_bytes(self, count: int, timeout_s: float = WAIT_S) -> bytes:
        await self.wait_until(lambda: len(self.data) >= count, timeout_s)
        return self.data

    async def wait_for_lost(self, timeout_s: float = WAIT_S) -> Exception | None:
        await self.wait_until(lambda: bool(self.lost), timeout_s)
        return self.lost[0]


async def poll_until(condition: Callable[[], bool], timeout_s: float = WAIT_S) -> None:
    """Wait for something another thread changes (no event to wait on): poll every 5 ms."""
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110 - the change happens in another thread
            await asyncio.sleep(0.005)


async def settle(seconds: float = 0.02) -> None:
    """Let callbacks already scheduled (and a little more) run."""
    await asyncio.sleep(seconds)
