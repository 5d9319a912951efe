"""Requests over a real mosquitto: every request gets one response; bad ones change nothing."""

from __future__ import annotations

import asyncio
import json
import random
from typing import Any

import aiomqtt
import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from .conftest import Broker
from .helpers import fast_settings, open_probe, running_gateway

pytestmark = pytest.mark.slow


async def test_gcode_request_is_answered_over_mqtt_311_with_the_transaction(
    broker: Broker,
) -> None:
    """A 3.1.1 sender's G-code line reaches the controller; the response copies the transaction."""
    settings = fast_settings(broker, protocol="3.1.1")
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(
            f"{root}/request/gcode",
            {"line": "G0 X10 Y20", "line_number": 7, "x": 10, "y": 20.5, "transaction": "t-1"},
        )
        response = await probe.wait_json(f"{root}/response/gcode")
    assert response == {
        "status": "ok",
        "data": {"line": "G0 X10 Y20", "xy_mm": [10.0, 20.5]},
        "transaction": "t-1",
    }
    assert controller.gcode_calls == [("G0 X10 Y20", 7, (10.0, 20.5))]


async def test_v5_request_is_also_answered_on_its_response_topic_with_correlation_data(
    broker: Broker,
) -> None:
    """MQTT v5: the answer goes to the Response Topic with the Correlation Data, and to
    response/<name> as well."""
    settings = fast_settings(broker, protocol="5")
    root = settings.topics.root
    reply_topic = f"{root}/reply/sender-1"
    async with (
        running_gateway(settings),
        open_probe(
            broker, f"{root}/response/#", reply_topic, protocol=aiomqtt.ProtocolVersion.V5
        ) as probe,
    ):
        properties = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
        properties.ResponseTopic = reply_topic
        properties.CorrelationData = b"\x00corr\xff"
        await probe.client.publish(
            f"{root}/request/status", b'{"transaction": 42}', qos=1, properties=properties
        )
        direct = await probe.wait_for(lambda m: m.topic.value == reply_topic)
        by_name = await probe.wait_json(f"{root}/response/status")
    assert direct.properties is not None
    assert getattr(direct.properties, "CorrelationData", None) == b"\x00corr\xff"
    assert json.loads(bytes(direct.payload))["transaction"] == 42
    assert by_name["status"] == "ok"
    assert by_name["transaction"] == 42
    assert by_name["data"]["state"] == "idle"


async def test_a_v5_response_topic_over_the_boards_own_topics_is_not_written(
    broker: Broker,
) -> None:
    """A Response Topic pointing at the retained state would let a requester overwrite it:
    the gateway answers only on response/<name> then."""
    settings = fast_settings(broker, protocol="5")
    root = settings.topics.root
    async with (
        running_gateway(settings),
        open_probe(broker, f"{root}/#", protocol=aiomqtt.ProtocolVersion.V5) as probe,
    ):
        properties = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
        properties.ResponseTopic = f"{root}/state"
        await probe.client.publish(
            f"{root}/request/status", b'{"transaction": 1}', qos=1, properties=properties
        )
        await probe.wait_json(f"{root}/response/status")
        await asyncio.sleep(0.2)
    assert all("status" not in doc for doc in probe.json_on(f"{root}/state"))


async def test_named_requests_reach_the_controller_which_decides_unknown_names(
    broker: Broker,
) -> None:
    """request/<name> hands name and arguments over; an unknown name is the controller's
    error, answered like any other."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/echo", {"a": [1, {"b": None}], "transaction": 1})
        await probe.publish_json(f"{root}/request/frobnicate", {"transaction": 2})
        echo = await probe.wait_json(f"{root}/response/echo")
        unknown = await probe.wait_json(f"{root}/response/frobnicate")
    assert echo == {"status": "ok", "data": {"a": [1, {"b": None}]}, "transaction": 1}
    assert unknown == {
        "status": "error", "data": {}, "error": "unknown request 'frobnicate'", "transaction": 2,
    }  # fmt: skip
    assert controller.request_calls == [("echo", {"a": [1, {"b": None}]}), ("frobnicate", {})]


async def test_a_controller_that_raises_still_answers_and_the_gateway_carries_on(
    broker: Broker,
) -> None:
    """An exception inside the controller becomes an 'internal error' response; a failing
    snapshot() stops state updates only until it recovers."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#", f"{root}/state") as probe,
    ):
        await probe.publish_json(f"{root}/request/explode", {"transaction": 1})
        exploded = await probe.wait_json(f"{root}/response/explode")
        controller.state = {"explode": True}
        await asyncio.sleep(0.2)
        controller.state = {"state": "recovered"}
        recovered = await probe.wait_json(f"{root}/state", lambda d: d == {"state": "recovered"})
        await probe.publish_json(f"{root}/request/status", {"transaction": 2})
        status = await probe.wait_json(f"{root}/response/status")
    assert exploded["status"] == "error"
    assert exploded["error"] == "internal error: RuntimeError: boom"
    assert exploded["transaction"] == 1
    assert recovered == {"state": "recovered"}
    assert status["status"] == "ok"


async def test_invalid_request_names_are_refused_on_the_mirrored_response_topic(
    broker: Broker,
) -> None:
    """request/a/b and a name with a space never reach the controller; each is answered."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/a/b", {"transaction": 1})
        await probe.publish_json(f"{root}/request/bad name", {"transaction": 2})
        nested = await probe.wait_json(f"{root}/response/a/b")
        spaced = await probe.wait_json(f"{root}/response/bad name")
    assert nested["status"] == "error"
    assert "invalid request name 'a/b'" in nested["error"]
    assert spaced["status"] == "error"
    assert "invalid request name" in spaced["error"]
    assert controller.request_calls == []
    assert controller.gcode_calls == []


async def test_oversized_requests_are_refused_without_reaching_the_controller(
    broker: Broker,
) -> None:
    """A payload above max_payload_bytes gets an error naming the limit; nothing runs."""
    settings = fast_settings(broker, max_payload_bytes=512)
    root = settings.topics.root
    big = {"line": "G0 X1", "transaction": "big", "pad": "x" * 600}
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/gcode", big)
        response = await probe.wait_json(f"{root}/response/gcode")
    assert response["status"] == "error"
    assert response["error"].startswith("payload too large")
    assert "512" in response["error"]
    assert controller.gcode_calls == []


async def test_a_retained_request_is_refused_live_over_v5(broker: Broker) -> None:
    """A retained M3 would fire again for every new subscriber: refused, never executed."""
    settings = fast_settings(broker, protocol="5")
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(
            f"{root}/request/gcode", {"line": "M3", "transaction": "r"}, retain=True
        )
        response = await probe.wait_json(f"{root}/response/gcode")
        await probe.client.publish(f"{root}/request/gcode", b"", qos=1, retain=True)  # clear
    assert response["status"] == "error"
    assert "retained" in response["error"]
    assert response["transaction"] == "r"
    assert controller.gcode_calls == []


async def test_a_retained_request_waiting_on_the_broker_is_refused_at_subscribe_over_311(
    broker: Broker,
) -> None:
    """On 3.1.1 the broker replays a stored retained request when the gateway subscribes:
    refused, so a gateway restart never replays a command."""
    settings = fast_settings(broker, protocol="3.1.1")
    root = settings.topics.root
    async with open_probe(broker, f"{root}/response/#") as probe:
        await probe.publish_json(
            f"{root}/request/gcode", {"line": "M3", "transaction": "old"}, retain=True
        )
        async with running_gateway(settings) as (_, controller):
            response = await probe.wait_json(f"{root}/response/gcode")
        await probe.client.publish(f"{root}/request/gcode", b"", qos=1, retain=True)  # clear
    assert response["status"] == "error"
    assert "retained" in response["error"]
    assert controller.gcode_calls == []


async def test_an_expired_deadline_gives_a_timeout_response_and_cancels_the_command(
    broker: Broker,
) -> None:
    """deadline_ms caps the execution: a 5 s dwell with deadline_ms=200 is answered
    'timeout' after about 0.2 s and the controller's call is cancelled."""
    settings = fast_settings(broker, request_deadline_s=30.0)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        loop = asyncio.get_running_loop()
        sent_s = loop.time()
        await probe.publish_json(
            f"{root}/request/gcode", {"line": "G4 P5", "deadline_ms": 200, "transaction": 9}
        )
        response = await probe.wait_json(f"{root}/response/gcode")
        elapsed_s = loop.time() - sent_s
    assert response == {"status": "error", "data": {}, "error": "timeout", "transaction": 9}
    assert 0.15 < elapsed_s < 1.5
    assert controller.cancelled == ["G4 P5"]


async def test_the_configured_request_deadline_applies_without_deadline_ms(
    broker: Broker,
) -> None:
    """request_deadline_s bounds every request: no command waits forever for an answer."""
    settings = fast_settings(broker, request_deadline_s=0.3)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/gcode", {"line": "G4 P5", "transaction": 1})
        response = await probe.wait_json(f"{root}/response/gcode", timeout_s=2.0)
    assert response["error"] == "timeout"
    assert controller.cancelled == ["G4 P5"]


async def test_a_slow_m3_does_not_block_a_status_request(broker: Broker) -> None:
    """M3 takes a second; a status request sent after it is answered first and quickly."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        controller.m3_delay_s = 1.0
        loop = asyncio.get_running_loop()
        await probe.publish_json(f"{root}/request/gcode", {"line": "M3", "transaction": "m3"})
        await asyncio.wait_for(controller.called.wait(), 2.0)
        sent_s = loop.time()
        await probe.publish_json(f"{root}/request/status", {"transaction": "s"})
        status = await probe.wait_json(f"{root}/response/status")
        status_s = loop.time() - sent_s
        m3 = await probe.wait_json(f"{root}/response/gcode", timeout_s=3.0)
    assert status["status"] == "ok"
    assert status_s < 0.3
    assert m3 == {"status": "ok", "data": {"line": "M3", "xy_mm": None}, "transaction": "m3"}
    order = [m.topic.value.rsplit("/", 1)[1] for m in probe.messages]
    assert order == ["status", "gcode"]


async def test_requests_beyond_the_pending_limit_are_refused_busy(broker: Broker) -> None:
    """With one slot and two pending, a third slow request is refused 'busy' at once;
    the two accepted ones are answered."""
    settings = fast_settings(broker, max_concurrent_requests=1, max_pending_requests=2)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        for transaction in (1, 2, 3):
            await probe.publish_json(
                f"{root}/request/gcode", {"line": "G4 P0.3", "transaction": transaction}
            )
        busy = await probe.wait_json(f"{root}/response/gcode", lambda d: d["transaction"] == 3)
        assert busy["status"] == "error"
        assert busy["error"].startswith("busy")
        first = await probe.wait_json(f"{root}/response/gcode", lambda d: d["transaction"] == 1)
        second = await probe.wait_json(f"{root}/response/gcode", lambda d: d["transaction"] == 2)
    assert first["status"] == second["status"] == "ok"
    assert len(controller.gcode_calls) == 2


def _garbage(rng: random.Random) -> bytes:
    """One payload that must be refused on request/gcode: 12 families, from noise to
    almost-valid documents."""
    family = rng.randrange(12)
    tx = rng.choice([None, rng.randrange(10**6), f"tx-{rng.randrange(10**6)}"])
    base: dict[str, Any] = {"line": "G1 X1 Y1 F1000"}
    if tx is not None:
        base["transaction"] = tx
    if family == 0:  # random bytes
        return rng.randbytes(rng.randrange(1, 200))
    if family == 1:  # truncated JSON
        text = json.dumps(base)
        return text[: rng.randrange(1, len(text) - 1)].encode()
    if family == 2:  # JSON that is not an object or a string
        return json.dumps(
            rng.choice([None, True, 3, -1.5, [], [1, "x"], [{"line": "M3"}]])
        ).encode()
    if family == 3:  # line of the wrong type
        return json.dumps(
            {**base, "line": rng.choice([None, 1, 2.5, True, [], {}, ["M3"]])}
        ).encode()
    if family == 4:  # empty, blank, too long or multi-line line
        bad = rng.choice(["", "   ", "G1" * 200, "M3\nM5", "M3\r", "G0\x00X1", "M3\x7f"])
        return json.dumps({**base, "line": bad}).encode()
    if family == 5:  # unknown field
        return json.dumps({**base, rng.choice(["lines", "X", "cmd", "Line"]): 1}).encode()
    if family == 6:  # x without y, or a non-finite / out-of-range coordinate
        extras: list[dict[str, Any]] = [
            {"x": 1.0},
            {"y": 2},
            {"x": 1e9, "y": 0},
            {"x": "1", "y": 2},
        ]
        extra = rng.choice(extras)
        return json.dumps({**base, **extra}).encode()
    if family == 7:  # NaN / Infinity literals
        return (json.dumps(base)[:-1] + ', "x": NaN, "y": Infinity}').encode()
    if family == 8:  # bad line_number
        return json.dumps({**base, "line_number": rng.choice([-1, "7", 1.5, 2**40, True])}).encode()
    if family == 9:  # bad transaction
        return json.dumps(
            {**base, "transaction": rng.choice([[1], {"a": 1}, 1.5, True, "x" * 200, 2**60])}
        ).encode()
    if family == 10:  # bad deadline_ms
        return json.dumps({**base, "deadline_ms": rng.choice([0, -5, "100", 1.5, 10**9])}).encode()
    # deeply nested or invalid UTF-8
    return rng.choice([b"[" * 2000 + b"]" * 2000, b'{"line": "\xff\xfe"}', b"{" * 3000, b""])


async def test_a_thousand_fuzzed_payloads_each_get_an_error_and_none_reaches_the_controller(
    broker: Broker,
) -> None:
    """1,000 seeded garbage and almost-valid payloads on request/gcode: 1,000 error
    responses, execute_gcode never called, and the gateway still serves a valid line."""
    settings = fast_settings(broker)
    root = settings.topics.root
    rng = random.Random(20240611)
    payloads = [_garbage(rng) for _ in range(1000)]
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        for payload in payloads:
            await probe.client.publish(f"{root}/request/gcode", payload, qos=1)
        await probe.wait_count(f"{root}/response/gcode", 1000, timeout_s=20.0)
        responses = probe.json_on(f"{root}/response/gcode")
        assert controller.gcode_calls == []
        await probe.publish_json(f"{root}/request/gcode", {"line": "M5", "transaction": "after"})
        after = await probe.wait_json(
            f"{root}/response/gcode", lambda d: d.get("transaction") == "after"
        )
    assert len(responses) == 1000
    assert all(r["status"] == "error" and r["error"] for r in responses)
    assert after["status"] == "ok"
    assert controller.gcode_calls == [("M5", None, None)]
