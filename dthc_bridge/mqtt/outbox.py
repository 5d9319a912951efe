"""Responses and events waiting for the broker: ordered, bounded in count and in age.

A response computed while the broker is away waits here and goes out after the reconnect;
one that waited longer than ``hold_s``, or is pushed out by overflow, is dropped with a
log line (never silently).
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import structlog

__all__ = ["Outbox", "Outgoing"]

log = structlog.get_logger("dthc_bridge.mqtt")


@dataclass(frozen=True)
class Outgoing:
    topic: str
    payload: bytes
    qos: int = 1
    retain: bool = False
    correlation_data: bytes | None = None  # MQTT v5 only
    kind: str = "response"  # for logs: response, event
    label: str = ""  # for logs: request name, transaction or event type
    created_s: float = field(default_factory=time.monotonic)


class Outbox:
    def __init__(
        self, max_messages: int, hold_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.max_messages = max_messages
        self.hold_s = hold_s
        self._clock = clock
        self._items: deque[Outgoing] = deque()
        self._ready = asyncio.Event()
        self.dropped = 0

    def __len__(self) -> int:
        return len(self._items)

    def put(self, item: Outgoing) -> None:
        if len(self._items) >= self.max_messages:
            self._drop(self._items.popleft(), "outbox full")
        self._items.append(item)
        self._ready.set()

    def unget(self, item: Outgoing) -> None:
        """Put back at the head a message whose publication did not complete."""
        self._items.appendleft(item)
        self._ready.set()

    def pop(self) -> Outgoing | None:
        """The oldest message still worth sending, or None (stale ones are dropped)."""
        while self._items:
            item = self._items.popleft()
            if self._clock() - item.created_s <= self.hold_s:
                return item
            self._drop(item, "held too long")
        return None

    async def get(self) -> Outgoing:
        """The oldest message still worth sending, waiting for one."""
        while (item := self.pop()) is None:
            self._ready.clear()
            await self._ready.wait()
        return item

    def drop_all(self, reason: str) -> None:
        while self._items:
            self._drop(self._items.popleft(), reason)

    def _drop(self, item: Outgoing, reason: str) -> None:
        self.dropped += 1
        log.warning(
            "mqtt_message_dropped", kind=item.kind, label=item.label, topic=item.topic,
            reason=reason, age_s=round(self._clock() - item.created_s, 3),
        )  # fmt: skip
