"""A SimulatedBoard ticking in real time inside the test's event loop, behind memory pairs.

Each connection the daemon opens gets a fresh memory pair, with the hostile options the
test chose for each direction; board frames are written one by one so loss hits frames.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

from dthc_bridge.transport import Transport, TransportError
from dthc_bridge.transport.base import BytesCallback, LostCallback
from mock_device.sim import SimulatedBoard
from tests.transport.memory import LinkFaults, MemoryTransport, memory_pair


class RealtimeSimBoard:
    def __init__(
        self,
        board: SimulatedBoard,
        *,
        to_host: LinkFaults | None = None,
        to_board: LinkFaults | None = None,
    ) -> None:
        self.board = board
        self.to_host = to_host
        self.to_board = to_board
        self.end: MemoryTransport | None = None
        self.connections = 0
        self.refuse_connections = False

    async def opener(self, on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
        if self.refuse_connections:
            raise TransportError("memory://board", "no such device (unplugged)")
        daemon_end, board_end = memory_pair(
            on_bytes, on_lost, self._host_bytes, self._board_lost,
            faults_a_to_b=self.to_board, faults_b_to_a=self.to_host,
        )  # fmt: skip
        self.end = board_end
        self.connections += 1
        return daemon_end

    def _host_bytes(self, data: bytes) -> None:
        self.board.host_write(data)
        self.flush()

    def _board_lost(self, exc: Exception | None) -> None:
        self.end = None

    def flush(self) -> None:
        data = self.board.read()
        end = self.end
        if end is None or not end.is_open:
            return
        for frame in data.split(b"\x00"):
            if frame:
                end.write(frame + b"\x00")

    def unplug(self) -> None:
        if self.end is not None:
            self.end.break_link()
            self.end = None

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            self.board.tick_due(loop.time())  # a reboot's new clock is anchored again
            self.flush()
            await asyncio.sleep(0.002)

    @contextlib.asynccontextmanager
    async def running(self) -> AsyncIterator[RealtimeSimBoard]:
        task = asyncio.create_task(self.run(), name="sim-board")
        try:
            yield self
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
