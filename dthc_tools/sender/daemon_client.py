"""The sender's MQTT side: requests with transaction ids, responses, and daemon events."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import uuid
from collections.abc import AsyncIterator, Callable
from typing import Any

import aiomqtt

__all__ = ["DaemonClient", "DaemonError"]


class DaemonError(Exception):
    """The daemon answered with an error, or did not answer in time."""


class DaemonClient:
    def __init__(
        self,
        host: str,
        port: int,
        *,
        base_topic: str = "dthc",
        board_id: str = "table1",
        protocol: str = "5",
        username: str | None = None,
        password: str | None = None,
        timeout_s: float = 60.0,
    ) -> None:
        self.root = f"{base_topic}/{board_id}"
        self.timeout_s = timeout_s
        version = aiomqtt.ProtocolVersion.V5 if protocol == "5" else aiomqtt.ProtocolVersion.V311
        self._client = aiomqtt.Client(
            host, port, protocol=version, username=username, password=password,
            identifier=f"dthc-sender-{uuid.uuid4().hex[:8]}", timeout=10.0,
        )  # fmt: skip
        self._ids = itertools.count(1)
        # Transactions are unique per run: the daemon answers a repeated transaction from
        # its cache instead of running it (exactly-once), so a second run must not reuse
        # the first run's "s1", "s2", ...
        self._run_id = uuid.uuid4().hex[:8]
        self._waiting: dict[str, asyncio.Future[dict[str, Any]]] = {}
        self._event_handlers: list[Callable[[dict[str, Any]], None]] = []
        self._offline_handlers: list[Callable[[], None]] = []
        self._task: asyncio.Task[None] | None = None
        # A request published while the daemon is not subscribed would be dropped by the
        # broker: wait for its availability (retained, republished on every reconnect).
        self._online = asyncio.Event()

    @contextlib.asynccontextmanager
    async def connected(self) -> AsyncIterator[DaemonClient]:
        async with self._client:
            await self._client.subscribe(f"{self.root}/response/#", qos=1)
            await self._client.subscribe(f"{self.root}/event", qos=1)
            await self._client.subscribe(f"{self.root}/availability", qos=1)
            self._task = asyncio.create_task(self._pump(), name="sender-mqtt")
            try:
                yield self
            finally:
                self._task.cancel()
                with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                    await self._task

    def on_event(self, handler: Callable[[dict[str, Any]], None]) -> None:
        self._event_handlers.append(handler)

    def on_offline(self, handler: Callable[[], None]) -> None:
        """The daemon's availability turned offline (killed, crashed or stopped)."""
        self._offline_handlers.append(handler)

    def _went_offline(self) -> None:
        """Nobody will answer what is pending: fail it now, not after the timeout."""
        for waiter in self._waiting.values():
            if not waiter.done():
                waiter.set_exception(DaemonError("the daemon went offline"))
        for handler in self._offline_handlers:
            handler()

    async def _pump(self) -> None:
        async for message in self._client.messages:
            try:
                document = json.loads(bytes(message.payload))
            except ValueError:
                continue
            if not isinstance(document, dict):
                continue
            if message.topic.matches(f"{self.root}/availability"):
                if document.get("state") == "online":
                    self._online.set()
                elif self._online.is_set():  # online -> offline: its will, or a clean stop
                    self._online.clear()
                    self._went_offline()
                continue
            if message.topic.matches(f"{self.root}/event"):
                for handler in self._event_handlers:
                    handler(document)
                continue
            waiter = self._waiting.pop(str(document.get("transaction")), None)
            if waiter is not None and not waiter.done():
                waiter.set_result(document)

    async def request(self, name: str, **args: Any) -> dict[str, Any]:
        """Publish a request, wait for its response; DaemonError on an error response."""
        try:
            await asyncio.wait_for(self._online.wait(), self.timeout_s)
        except TimeoutError:
            raise DaemonError(f"{name}: the daemon is not online") from None
        transaction = f"{self._run_id}-{next(self._ids)}"
        future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._waiting[transaction] = future
        payload = {**args, "transaction": transaction}
        await self._client.publish(f"{self.root}/request/{name}", json.dumps(payload), qos=1)
        try:
            response = await asyncio.wait_for(future, self.timeout_s)
        except TimeoutError:
            raise DaemonError(f"{name}: no response within {self.timeout_s:.0f} s") from None
        finally:
            self._waiting.pop(transaction, None)
        if response.get("status") != "ok":
            raise DaemonError(str(response.get("error") or "error"))
        data: dict[str, Any] = response.get("data") or {}
        return data

    async def gcode(
        self,
        line: str,
        *,
        line_number: int | None = None,
        xy: tuple[float, float] | None = None,
        dialect: str | None = None,
    ) -> dict[str, Any]:
        args: dict[str, Any] = {"line": line}
        if dialect is not None:
            args["dialect"] = dialect
        if line_number is not None:
            args["line_number"] = line_number
        if xy is not None:
            args["x"], args["y"] = xy
        return await self.request("gcode", **args)
