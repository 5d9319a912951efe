"""Test-side MQTT: a probe client that records everything, and a gateway running in a task."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import socket
import uuid
from collections.abc import AsyncIterator, Callable
from typing import Any

import aiomqtt

from dthc_bridge.mqtt import MqttGateway, MqttSettings

from .conftest import Broker
from .fakes import FakeController

__all__ = [
    "Probe",
    "fast_settings",
    "open_probe",
    "running_gateway",
    "unique_base",
]

_counter = itertools.count()


def unique_base() -> str:
    """A base topic of its own, so tests sharing the session broker never see each other."""
    return f"t{next(_counter)}-{uuid.uuid4().hex[:8]}"


def fast_settings(broker: Broker, **overrides: Any) -> MqttSettings:
    """Short backoffs and periods, own base topic and client id."""
    values: dict[str, Any] = {
        "host": broker.host,
        "port": broker.port,
        "base_topic": unique_base(),
        "client_id": f"gw-{uuid.uuid4().hex[:10]}",
        "reconnect_initial_s": 0.05,
        "reconnect_max_s": 0.2,
        "keepalive_s": 5,
        "operation_timeout_s": 3.0,
        "diagnostics_period_s": 0.5,
        "state_poll_s": 0.05,
        "request_deadline_s": 5.0,
    }
    values.update(overrides)
    return MqttSettings.model_validate(values)


class Probe:
    """An aiomqtt client on the test's side; every message it receives is kept in order."""

    def __init__(self, client: aiomqtt.Client) -> None:
        self.client = client
        self.messages: list[aiomqtt.Message] = []
        self._arrived = asyncio.Event()

    async def pump(self) -> None:
        async for message in self.client.messages:
            self.messages.append(message)
            self._arrived.set()

    async def wait_for(
        self, predicate: Callable[[aiomqtt.Message], bool], timeout_s: float = 5.0, start: int = 0
    ) -> aiomqtt.Message:
        """The first message from index ``start`` on that satisfies ``predicate``."""
        index = start
        async with asyncio.timeout(timeout_s):
            while True:
                while index < len(self.messages):
                    if predicate(self.messages[index]):
                        return self.messages[index]
                    index += 1
                self._arrived.clear()
                await self._arrived.wait()

    async def wait_json(
        self,
        topic: str,
        where: Callable[[dict[str, Any]], bool] = lambda doc: True,
        timeout_s: float = 5.0,
        start: int = 0,
    ) -> dict[str, Any]:
        message = await self.wait_for(
            lambda m: m.topic.value == topic and where(_json_or_empty(m)), timeout_s, start
        )
        return _json_or_empty(message)

    async def wait_count(self, topic: str, count: int, timeout_s: float = 5.0) -> None:
        """Until ``count`` messages arrived on ``topic``."""
        seen = 0

        def counted(message: aiomqtt.Message) -> bool:
            nonlocal seen
            seen += message.topic.value == topic
            return seen >= count

        await self.wait_for(counted, timeout_s)

    def on(self, topic: str) -> list[aiomqtt.Message]:
        return [m for m in self.messages if m.topic.value == topic]

    def json_on(self, topic: str) -> list[dict[str, Any]]:
        return [_json_or_empty(m) for m in self.on(topic)]

    async def publish_json(self, topic: str, document: object, **kwargs: Any) -> None:
        await self.client.publish(topic, json.dumps(document), qos=1, **kwargs)


def _json_or_empty(message: aiomqtt.Message) -> dict[str, Any]:
    try:
        document = json.loads(bytes(message.payload))
    except ValueError:
        return {}
    return document if isinstance(document, dict) else {"value": document}


@contextlib.asynccontextmanager
async def open_probe(
    broker: Broker,
    *topics: str,
    protocol: aiomqtt.ProtocolVersion = aiomqtt.ProtocolVersion.V311,
    **client_kwargs: Any,
) -> AsyncIterator[Probe]:
    """A connected probe subscribed (QoS 1) to ``topics``, pumping until the block ends."""
    client = aiomqtt.Client(
        broker.host, broker.port, protocol=protocol, timeout=3.0,
        identifier=client_kwargs.pop("identifier", f"probe-{uuid.uuid4().hex[:10]}"),
        socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)],
        **client_kwargs,
    )  # fmt: skip
    async with client:
        for topic in topics:
            await client.subscribe(topic, qos=1)
        probe = Probe(client)
        task = asyncio.create_task(probe.pump(), name="probe")
        try:
            yield probe
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task


@contextlib.asynccontextmanager
async def running_gateway(
    settings: MqttSettings, controller: FakeController | None = None, *, connect: bool = True
) -> AsyncIterator[tuple[MqttGateway, FakeController]]:
    """The gateway running in a task; cancelled (clean shutdown) when the block ends."""
    controller = controller or FakeController()
    gateway = MqttGateway(settings, controller)
    task = asyncio.create_task(gateway.run(), name="gateway")
    try:
        if connect:
            waiter = asyncio.create_task(gateway.wait_connected(), name="wait-connected")
            try:
                done, _ = await asyncio.wait(
                    {task, waiter}, timeout=5.0, return_when=asyncio.FIRST_COMPLETED
                )
            finally:
                waiter.cancel()
            if task in done:
                task.result()  # raises what ended the gateway
            if waiter not in done:
                raise TimeoutError("the gateway did not connect within 5 s")
        yield gateway, controller
    finally:
        task.cancel()
        # Python 3.11's wait_for (inside aiomqtt's connect) can lose a cancel that races a
        # refused CONNACK (CPython gh-86296): the gateway then retries on. Ask again.
        for _ in range(50):
            done, _ = await asyncio.wait({task}, timeout=0.2)
            if done:
                break
            task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
