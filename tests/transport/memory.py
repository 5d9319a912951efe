"""In-process transport pairs for tests, clean or hostile (bellows' fake transports).

:func:`memory_pair` connects two :class:`MemoryTransport` ends back to back. Each end's
writes pass through that end's :class:`LinkFaults` before reaching the peer: whole writes
dropped at random and bits flipped at random (by the mock's
:class:`~mock_device.faults.LinkFaultInjector`, the one fault injector), bytes delivered one
at a time, delivery delayed. Randomness is seeded, so a failing run repeats. Every delivery
goes through the event loop (``call_soon`` / ``call_later``), never from inside ``write``,
and keeps the write order.

There is no ``memory://`` link kind in the product: a test hands the link layer an opener
(``TransportOpener``) that returns the daemon's half of a pair.
"""

from __future__ import annotations

import asyncio
import random
from collections import deque
from dataclasses import dataclass

from dthc_bridge.transport.base import BytesCallback, LostCallback, Transport, TransportError
from mock_device.faults import FaultPlan, LinkFaultInjector, check_rate

__all__ = [
    "LinkFaults",
    "MemoryTransport",
    "memory_pair",
]


@dataclass(frozen=True, slots=True)
class LinkFaults:
    """What happens to one direction's bytes on their way to the peer.

    ``loss_rate``: probability that a whole write is dropped. ``bit_flip_rate``: probability,
    per byte, that one of its bits is flipped. ``one_byte_at_a_time``: each byte is its own
    delivery. ``delay_s``: every delivery waits this long (``loop.call_later``). ``seed``
    seeds this direction's random generator.
    """

    one_byte_at_a_time: bool = False
    loss_rate: float = 0.0
    bit_flip_rate: float = 0.0
    delay_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_rate("loss_rate", self.loss_rate)
        check_rate("bit_flip_rate", self.bit_flip_rate)
        if self.delay_s < 0:
            raise ValueError(f"delay_s must not be negative, got {self.delay_s}")

    def injector(self) -> LinkFaultInjector:
        """A fresh injector for this direction's losses and bit flips, seeded with ``seed``."""
        plan = FaultPlan(bit_flip_rate=self.bit_flip_rate, drop_frame_rate=self.loss_rate)
        return LinkFaultInjector(plan, random.Random(self.seed))


class MemoryTransport(Transport):
    """One end of an in-process link. Create pairs with :func:`memory_pair`."""

    def __init__(
        self,
        url: str,
        on_bytes: BytesCallback,
        on_lost: LostCallback,
        *,
        faults: LinkFaults | None = None,
    ) -> None:
        self.url = url
        self._faults = faults if faults is not None else LinkFaults()  # for the link's life
        self._injector = self._faults.injector()
        self._on_bytes = on_bytes
        self._on_lost = on_lost
        self._loop = asyncio.get_running_loop()
        self._peer: MemoryTransport | None = None
        self._outgoing: deque[tuple[int, bytes | None]] = deque()  # None: "I closed"
        self._next_id = 0
        self._open = True
        self._reported = False

    @property
    def writes_dropped(self) -> int:
        return self._injector.dropped_frames

    @property
    def bytes_corrupted(self) -> int:
        return self._injector.flipped_bits  # one bit per hit byte

    @property
    def is_open(self) -> bool:
        return self._open

    def write(self, data: bytes) -> None:
        if not self._open:
            raise TransportError(self.url, "write on a closed memory link")
        payload = self._injector.outgoing(bytes(data))  # b"" when the write is lost
        if self._faults.one_byte_at_a_time:
            for i in range(len(payload)):
                self._send(payload[i : i + 1])
        elif payload:
            self._send(payload)

    def discard_output(self) -> None:
        if self._open:
            self._outgoing.clear()

    async def close(self) -> None:
        if not self._open:
            return
        self._open = False
        self._send(None)  # the peer sees the close after the bytes already in flight
        self._report(None)

    def break_link(self) -> None:
        """Cut the wire: both ends drop what is in flight and see ``on_lost(TransportError)``."""
        for end in (self, self._peer):
            if end is not None and end._open:
                end._open = False
                end._outgoing.clear()
                error = TransportError(end.url, "link broken")
                self._loop.call_soon(end._report, error)

    # --- delivery ---------------------------------------------------------------------------

    def _send(self, item: bytes | None) -> None:
        self._next_id += 1
        self._outgoing.append((self._next_id, item))
        if self._faults.delay_s > 0:
            self._loop.call_later(self._faults.delay_s, self._deliver_up_to, self._next_id)
        else:
            self._loop.call_soon(self._deliver_up_to, self._next_id)

    def _deliver_up_to(self, item_id: int) -> None:
        # Delivering by id from the head of the queue keeps the write order even when two
        # timers come due in another order, and skips items a discard or break removed.
        while self._outgoing and self._outgoing[0][0] <= item_id:
            _, item = self._outgoing.popleft()
            if self._peer is None:
                continue
            if item is None:
                self._peer._peer_closed()
            else:
                self._peer._receive(item)

    def _receive(self, data: bytes) -> None:
        if self._open:
            self._on_bytes(data)

    def _peer_closed(self) -> None:
        if self._open:
            self._open = False
            self._outgoing.clear()
            self._report(TransportError(self.url, "closed by peer"))

    def _report(self, exc: Exception | None) -> None:
        if not self._reported:
            self._reported = True
            self._on_lost(exc)


def memory_pair(
    on_bytes_a: BytesCallback,
    on_lost_a: LostCallback,
    on_bytes_b: BytesCallback,
    on_lost_b: LostCallback,
    *,
    url_a: str = "memory://a",
    url_b: str = "memory://b",
    faults_a_to_b: LinkFaults | None = None,
    faults_b_to_a: LinkFaults | None = None,
) -> tuple[MemoryTransport, MemoryTransport]:
    """Two connected ends: what ``a`` writes ``b`` receives and vice versa. Needs a running loop."""
    a = MemoryTransport(url_a, on_bytes_a, on_lost_a, faults=faults_a_to_b)
    b = MemoryTransport(url_b, on_bytes_b, on_lost_b, faults=faults_b_to_a)
    a._peer = b
    b._peer = a
    return a, b
