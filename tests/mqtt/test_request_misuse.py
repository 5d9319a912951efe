"""Requests a sender sends by mistake: an empty payload, a transaction reused for another
request. Each is refused with one error response naming what was wrong; nothing runs."""

from __future__ import annotations

import asyncio

import pytest

from dthc_bridge.mqtt.payloads import RequestRefused, decode_request
from dthc_bridge.mqtt.transactions import TransactionCache
from dthc_bridge.port import CommandResult

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


def test_the_cache_refuses_a_transaction_reused_under_another_name_naming_the_first() -> None:
    """The cache is keyed by the transaction alone: a 'gcode' transaction seen again on
    'abort' is a conflict that names 'gcode'; the gcode entry stays as it was."""
    cache: TransactionCache[str] = TransactionCache(size=8, hold_s=10.0)
    assert cache.admit("gcode", "x", b'{"line":"M3","transaction":"x"}', "w0", 0.0).run
    seen = cache.admit("abort", "x", b'{"transaction":"x"}', "w1", 0.1)
    assert (seen.run, seen.conflict, seen.used_for) == (False, True, "gcode")
    # The refused abort neither finishes nor forgets the gcode entry.
    assert cache.finish("abort", "x", CommandResult(True), 0.2) == []
    assert cache.forget("abort", "x") == []
    assert len(cache) == 1
    assert cache.finish("gcode", "x", CommandResult(True, data={"n": 1}), 0.3) == []
    repeat = cache.admit("gcode", "x", b'{"line":"M3","transaction":"x"}', "w2", 0.4)
    assert (repeat.run, repeat.result) == (False, CommandResult(True, data={"n": 1}))


def test_the_cache_keeps_repeat_and_payload_conflict_rules_under_one_name() -> None:
    """Same name and payload: a repeat (no conflict); same name, other payload: a conflict
    naming the same request."""
    cache: TransactionCache[str] = TransactionCache(size=8, hold_s=10.0)
    assert cache.admit("gcode", 7, b"M3", "w0", 0.0).run
    repeat = cache.admit("gcode", "7", b"M3", "w1", 0.1)  # 7 and "7": one transaction
    assert (repeat.run, repeat.conflict) == (False, False)
    other = cache.admit("gcode", 7, b"M5", "w2", 0.2)
    assert (other.run, other.conflict, other.used_for) == (False, True, "gcode")


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


@pytest.mark.slow
async def test_a_gcode_transaction_reused_for_abort_is_refused_naming_both(broker: Broker) -> None:
    """The tester's probe: transaction 'x' of a gcode line reused on request/abort ran the
    abort. Now it is refused, naming both requests, and only the gcode line ran."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/gcode", {"line": "M5", "transaction": "x"})
        await probe.wait_json(f"{root}/response/gcode")
        await probe.publish_json(f"{root}/request/abort", {"transaction": "x"})
        refused = await probe.wait_json(f"{root}/response/abort")
    assert refused == {
        "status": "error",
        "data": {},
        "error": "transaction 'x' was already used for a 'gcode' request; "
        "this is a 'abort' request: use a new transaction",
        "transaction": "x",
    }
    assert [line for line, _, _ in controller.gcode_calls] == ["M5"]
    assert controller.request_calls == []


@pytest.mark.slow
async def test_a_transaction_reused_while_its_first_request_runs_is_refused(
    broker: Broker,
) -> None:
    """An M3 still running under transaction 9; a status with transaction 9 is refused at
    once (not queued as a repeat), and the M3 still gets its own answer."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/gcode", {"line": "M3", "transaction": 9})
        await probe.publish_json(f"{root}/request/status", {"transaction": 9})
        refused = await probe.wait_json(f"{root}/response/status")
        answered = await probe.wait_json(f"{root}/response/gcode")
    assert "already used for a 'gcode' request; this is a 'status' request" in refused["error"]
    assert answered["status"] == "ok"
    assert controller.request_calls == []
