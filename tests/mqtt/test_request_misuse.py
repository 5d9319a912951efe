"""Requests a sender sends by mistake: an empty payload. Each is refused with one error
response naming what was wrong; nothing runs."""

from __future__ import annotations

import asyncio

import pytest

from dthc_bridge.mqtt.payloads import RequestRefused, decode_request

from .conftest import Broker
from .helpers import fast_settings, open_probe, running_gateway

LIMIT = 4096


@pytest.mark.parametrize("payload", [b"", b"  \n"])
def test_an_empty_named_request_is_refused_not_run_without_arguments(payload: bytes) -> None:
    """An empty ``request/abort`` is a mistake (mosquitto_pub -n), not "abort, no arguments":
    refused, saying the payload is empty and a JSON object is expected."""
    with pytest.raises(RequestRefused) as refused:
        decode_request("abort", payload, max_payload_bytes=LIMIT)
    assert refused.value.reason.startswith("empty payload: expected a JSON object")
    assert "{}" in refused.value.reason  # how to send a request without arguments


def test_an_empty_json_object_is_still_a_request_without_arguments() -> None:
    """``{}`` is the way to send a request with no arguments and no transaction."""
    request = decode_request("status", b"{}", max_payload_bytes=LIMIT)
    assert request.transaction is None
    assert getattr(request, "args", None) == {}


@pytest.mark.slow
async def test_an_empty_abort_over_mqtt_gets_one_error_and_runs_nothing(broker: Broker) -> None:
    """The tester's probe: an empty message on request/abort ran the abort. Now: exactly one
    error response naming the empty payload, and the controller never sees an abort."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (gateway, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.client.publish(f"{root}/request/abort", b"", qos=1)
        refused = await probe.wait_json(f"{root}/response/abort")
        # A later request is answered, so a second answer to the empty one would be here.
        await probe.publish_json(f"{root}/request/status", {"transaction": "s-1"})
        await probe.wait_json(f"{root}/response/status")
    assert refused["status"] == "error"
    assert refused["error"].startswith("empty payload: expected a JSON object")
    assert len(probe.on(f"{root}/response/abort")) == 1
    assert controller.request_calls == [("status", {})]
    assert gateway.stats.refused == 1


@pytest.mark.slow
async def test_an_empty_retained_request_still_only_clears_it(broker: Broker) -> None:
    """Clearing a retained request (an empty retained message) is not a request: no
    response, nothing run."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (gateway, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.client.publish(f"{root}/request/abort", b"", qos=1, retain=True)
        await probe.publish_json(f"{root}/request/status", {"transaction": "s-2"})
        await probe.wait_json(f"{root}/response/status")
        await asyncio.sleep(0.1)
    assert probe.on(f"{root}/response/abort") == []
    assert controller.request_calls == [("status", {})]
    assert gateway.stats.refused == 0
