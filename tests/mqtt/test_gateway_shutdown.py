"""The gateway stops when asked, even when a publish swallows its cancellation.

Python 3.11's asyncio.wait_for, inside aiomqtt's QoS 1 publish, returns normally when the
PUBACK lands as the task is cancelled (CPython gh-86296). A publishing loop that ran on
then kept its TaskGroup, the gateway and the daemon's stop waiting forever: seen here as
rare 60 s hangs of the MQTT tests under load."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Coroutine
from typing import Any, cast

import aiomqtt
import pytest

from dthc_bridge.mqtt import MqttGateway, MqttSettings
from dthc_bridge.mqtt.outbox import Outgoing

from .fakes import FakeController


class SwallowingClient:
    """A client whose publish, cancelled, returns as if done: 3.11's wait_for when the
    acknowledgement and the cancellation arrive together."""

    def __init__(self) -> None:
        self.published = 0

    async def publish(self, *_args: Any, **_kwargs: Any) -> None:
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.sleep(0.05)
        self.published += 1


async def _cancelled_in_a_task_group(loop: Coroutine[Any, Any, None]) -> None:
    async def body() -> None:
        async with asyncio.TaskGroup() as group:
            group.create_task(loop)

    task = asyncio.create_task(body())
    await asyncio.sleep(0.12)  # inside a publish
    task.cancel()
    done, _ = await asyncio.wait({task}, timeout=2.0)
    assert done, "the loop ran on after its cancellation: its TaskGroup waits forever"
    assert task.cancelled()


@pytest.mark.parametrize("loop", ["outbox", "state", "diagnostics"])
async def test_each_publishing_loop_stops_when_a_publish_swallows_its_cancellation(
    loop: str,
) -> None:
    settings = MqttSettings(state_poll_s=0.01, diagnostics_period_s=0.1)
    controller = FakeController()
    gateway = MqttGateway(settings, controller)
    client = cast(aiomqtt.Client, SwallowingClient())
    if loop == "outbox":
        for n in range(100):
            gateway._outbox.put(Outgoing(f"t/{n}", b"{}"))
        await _cancelled_in_a_task_group(gateway._send_outbox(client))
    elif loop == "state":
        controller.snapshot = lambda: {"t": asyncio.get_running_loop().time()}  # type: ignore[method-assign]
        await _cancelled_in_a_task_group(gateway._watch_state(client))
    else:
        await _cancelled_in_a_task_group(gateway._send_diagnostics(client))
