"""The daemon's end of a link to a :class:`~mock_device.sim.SimulatedBoard` in-process.

What the daemon writes reaches the board at once (the board answers a command in the
same instant, as the old host-side stub did); what the board sends is handed to the
daemon from the event loop, never from inside ``write``, as a real transport does. The
board itself only moves when the simulation steps it (:meth:`deliver` after each step).
"""

from __future__ import annotations

import asyncio

import firmware_protocol as fp
from dthc_bridge.transport import BytesCallback, LostCallback, Transport, TransportError
from mock_device.sim import SimulatedBoard

__all__ = ["SimulatedLink"]


class SimulatedLink(Transport):
    def __init__(
        self,
        board: SimulatedBoard,
        on_bytes: BytesCallback,
        on_lost: LostCallback,
        url: str = "sim://board",
        *,
        record_velocities: bool = False,
    ) -> None:
        self.url = url
        self.board = board
        self._on_bytes = on_bytes
        self._on_lost = on_lost
        self._open = True
        self._delivery_scheduled = False
        self._loop = asyncio.get_running_loop()
        # Every Z velocity the daemon commanded, when asked (it decodes what the host sends).
        self._host_frames = fp.StreamDecoder() if record_velocities else None
        self.velocities_mm_s: list[float] = []

    @property
    def is_open(self) -> bool:
        return self._open

    def write(self, data: bytes) -> None:
        if not self._open:
            raise TransportError(self.url, "write on a closed simulated link")
        if self._host_frames is not None:
            for msg in self._host_frames.feed(data):
                if isinstance(msg, fp.ZVelocity):
                    self.velocities_mm_s.append(msg.velocity_um_s / 1000)
        self.board.host_write(data)
        if not self._delivery_scheduled:  # the board's answer, in this same instant
            self._delivery_scheduled = True
            self._loop.call_soon(self._scheduled_delivery)

    def _scheduled_delivery(self) -> None:
        self._delivery_scheduled = False
        self.deliver()

    def deliver(self) -> None:
        """Hand the daemon everything the board sent since the last delivery."""
        if self._open:
            data = self.board.read()
            if data:
                self._on_bytes(data)

    async def close(self) -> None:
        if self._open:
            self._open = False
            self._on_lost(None)
