"""Exactly-once requests over a real mosquitto: a repeated transaction is never run twice.

A sender that lost its response (a broker restart) sends the same request again with the
same transaction; each copy gets one response, the controller runs it once.
"""

from __future__ import annotations

import pytest

from dthc_bridge.mqtt.transactions import TransactionCache
from dthc_bridge.port import CommandResult

from .conftest import Broker
from .helpers import fast_settings, open_probe, running_gateway

pytestmark = pytest.mark.slow


async def test_a_repeat_while_the_first_copy_runs_waits_for_its_answer(broker: Broker) -> None:
    """An M3 sent twice while the first is still running: one execution, two responses,
    both with the first copy's result."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (gateway, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        request = {"line": "M3", "transaction": "m3-7"}
        await probe.publish_json(f"{root}/request/gcode", request)
        await probe.publish_json(f"{root}/request/gcode", request)
        await probe.wait_count(f"{root}/response/gcode", 2)
    answers = probe.json_on(f"{root}/response/gcode")
    assert [a["transaction"] for a in answers] == ["m3-7", "m3-7"]
    assert [a["status"] for a in answers] == ["ok", "ok"]
    assert [line for line, _, _ in controller.gcode_calls] == ["M3"]
    assert gateway.stats.repeated == 1


async def test_a_repeat_after_the_answer_is_answered_from_the_cache(broker: Broker) -> None:
    """The answer was lost, the sender asks again: the same answer, not a second M3."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        request = {"line": "M3", "line_number": 12, "transaction": 41}
        await probe.publish_json(f"{root}/request/gcode", request)
        first = await probe.wait_json(f"{root}/response/gcode", timeout_s=5.0)
        await probe.publish_json(f"{root}/request/gcode", request)
        await probe.wait_count(f"{root}/response/gcode", 2)
    second = probe.json_on(f"{root}/response/gcode")[1]
    assert second == first
    assert len(controller.gcode_calls) == 1


async def test_a_transaction_reused_for_another_request_is_refused(broker: Broker) -> None:
    """Transaction 5 was an M3; a later M5 with transaction 5 is refused, naming it, and
    not run."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/gcode", {"line": "M3", "transaction": 5})
        await probe.wait_json(f"{root}/response/gcode")
        await probe.publish_json(f"{root}/request/gcode", {"line": "M5", "transaction": 5})
        refused = await probe.wait_json(f"{root}/response/gcode", lambda d: d["status"] == "error")
    assert "transaction 5 was already used for a different gcode request" in refused["error"]
    assert [line for line, _, _ in controller.gcode_calls] == ["M3"]


async def test_requests_without_a_transaction_run_each_time(broker: Broker) -> None:
    """Without a transaction a repeat cannot be recognised: both copies run."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/response/#") as probe,
    ):
        await probe.publish_json(f"{root}/request/gcode", {"line": "G4 P0.01"})
        await probe.publish_json(f"{root}/request/gcode", {"line": "G4 P0.01"})
        await probe.wait_count(f"{root}/response/gcode", 2)
    assert len(controller.gcode_calls) == 2


def test_the_cache_is_bounded_and_forgets_old_answers() -> None:
    """At most ``size`` answered entries and none older than ``hold_s``; an entry still
    running is never dropped, and its repeat waits for it."""
    cache: TransactionCache[str] = TransactionCache(size=2, hold_s=10.0)
    done = CommandResult(True)
    for tx in range(3):
        assert cache.admit("gcode", tx, b"M3", f"r{tx}", now_s=0.0).run
        cache.finish("gcode", tx, done, now_s=0.0)
    assert len(cache) == 2
    assert cache.admit("gcode", 0, b"M3", "again", now_s=1.0).run  # the oldest was dropped
    assert cache.admit("gcode", "long", b"M3", "first", now_s=1.0).run
    assert cache.admit("gcode", 2, b"M3", "late", now_s=20.0).run  # older than hold_s
    repeat = cache.admit("gcode", "long", b"M3", "repeat", now_s=20.0)
    assert not repeat.run
    assert repeat.result is None  # it waits for the running copy
    assert cache.finish("gcode", "long", done, now_s=21.0) == ["repeat"]
