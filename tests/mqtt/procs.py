"""Processes the will tests kill with SIGKILL.

``python -m tests.mqtt.procs gateway PORT BASE`` runs an MqttGateway over the fake
controller; ``python -m tests.mqtt.procs sender PORT WILL_TOPIC`` is a sender whose MQTT
will is a retained ``{"state":"offline"}``. Each prints READY once connected, then waits.
"""

from __future__ import annotations

import asyncio
import sys

import aiomqtt

from dthc_bridge.logs import configure_logging
from dthc_bridge.mqtt import MqttGateway, MqttSettings

from .fakes import FakeController


async def gateway(port: int, base: str) -> None:
    settings = MqttSettings(
        host="127.0.0.1", port=port, base_topic=base, client_id=f"gw-{base}", keepalive_s=5
    )
    gw = MqttGateway(settings, FakeController())
    task = asyncio.create_task(gw.run())
    await gw.wait_connected()
    print("READY", flush=True)
    await task


async def sender(port: int, will_topic: str) -> None:
    will = aiomqtt.Will(will_topic, b'{"state":"offline"}', qos=1, retain=True)
    async with aiomqtt.Client("127.0.0.1", port, will=will, keepalive=5) as client:
        await client.publish(will_topic, b'{"state":"online"}', qos=1, retain=True)
        print("READY", flush=True)
        await asyncio.Event().wait()


def main() -> None:
    role, port, name = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    configure_logging("warning")  # stderr: stdout carries READY only
    asyncio.run(gateway(port, name) if role == "gateway" else sender(port, name))


if __name__ == "__main__":
    main()
