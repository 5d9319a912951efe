"""What the gateway publishes by itself: availability, state, board, events, telemetry,
diagnostics; and the offline message on a clean shutdown."""

from __future__ import annotations

import asyncio

import pytest

from dthc_bridge.events import ArcLost, ProgramPaused

from .conftest import Broker
from .fakes import FakeController
from .helpers import fast_settings, open_probe, running_gateway

pytestmark = pytest.mark.slow


async def test_retained_state_reaches_a_late_subscriber_and_is_republished_on_change(
    broker: Broker,
) -> None:
    """state is retained (a subscriber arriving later gets it at once, flagged retained)
    and a change in the controller's snapshot is published within a poll or two."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with running_gateway(settings) as (_, controller):
        async with open_probe(broker, f"{root}/state") as late:
            first = await late.wait_for(lambda m: m.topic.value == f"{root}/state")
            assert first.retain
            assert first.qos == 1
            controller.state = {"state": "cutting", "armed": True, "line": 12}
            changed = await late.wait_json(f"{root}/state", lambda d: d["state"] == "cutting")
            await asyncio.sleep(0.3)  # unchanged snapshot: nothing more is published
        assert changed == {"state": "cutting", "armed": True, "line": 12}
        assert len(late.on(f"{root}/state")) == 2


async def test_availability_board_and_diagnostics_are_retained_on_connect(
    broker: Broker,
) -> None:
    """A fresh subscriber finds availability online, the board link state, and the
    diagnostics with the gateway's own counters, all retained."""
    settings = fast_settings(broker)
    root = settings.topics.root
    controller = FakeController()
    controller.link = ("connecting", "opening /dev/dthc0")
    async with running_gateway(settings, controller), open_probe(broker, f"{root}/+") as probe:
        availability = await probe.wait_json(f"{root}/availability")
        board = await probe.wait_json(f"{root}/board")
        diagnostics = await probe.wait_json(f"{root}/diagnostics")
        assert all(m.retain for m in probe.messages)
        controller.link = ("online", "handshake complete")
        board_now = await probe.wait_json(f"{root}/board", lambda d: d["state"] == "online")
    assert availability == {"state": "online"}
    assert board == {"state": "connecting", "reason": "opening /dev/dthc0"}
    assert board_now == {"state": "online", "reason": "handshake complete"}
    assert diagnostics["link"] == {"requests": 0, "timeouts": 0}
    assert diagnostics["mqtt"]["connects"] == 1


async def test_diagnostics_are_republished_periodically(broker: Broker) -> None:
    """diagnostics goes out every diagnostics_period_s with fresh counters."""
    settings = fast_settings(broker, diagnostics_period_s=0.2)
    root = settings.topics.root
    async with running_gateway(settings), open_probe(broker, f"{root}/diagnostics") as probe:
        await probe.wait_count(f"{root}/diagnostics", 4, timeout_s=2.0)


async def test_controller_events_are_published_in_order_at_qos_1_not_retained(
    broker: Broker,
) -> None:
    """subscribe_events() items appear on event in order, QoS 1, not retained."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/event") as probe,
    ):
        controller.emit(ArcLost(1.5, "arc lost"))
        controller.emit(ProgramPaused(2.0, "breakaway"))
        await probe.wait_count(f"{root}/event", 2)
    assert probe.json_on(f"{root}/event") == [
        {"type": "arc_lost", "reason": "arc lost", "t": 1.5},
        {"type": "pause", "reason": "breakaway", "cause": "fault", "t": 2.0},
    ]
    assert all(m.qos == 1 and not m.retain for m in probe.on(f"{root}/event"))


async def test_telemetry_is_decimated_to_telemetry_hz(broker: Broker) -> None:
    """A point changing every 5 ms is published at about telemetry_hz (5 Hz here), QoS 0."""
    settings = fast_settings(broker, telemetry_hz=5.0)
    root = settings.topics.root
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(broker, f"{root}/telemetry") as probe,
    ):
        for step in range(200):  # 1 s of points at 200 Hz
            controller.point = {"voltage_v": 100.0 + step / 10, "z_mm": 3.0, "state": "cutting"}
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.05)
    points = probe.json_on(f"{root}/telemetry")
    assert 3 <= len(points) <= 8, len(points)
    assert all(m.qos == 0 and not m.retain for m in probe.on(f"{root}/telemetry"))
    assert points[-1]["voltage_v"] > points[0]["voltage_v"]


async def test_clean_shutdown_answers_in_flight_requests_then_publishes_offline(
    broker: Broker,
) -> None:
    """Cancelling run(): the pending M3 is answered (error, stopping), then availability
    goes offline, retained; a clean DISCONNECT sends no will, so this is the gateway's own."""
    settings = fast_settings(broker)
    root = settings.topics.root
    async with open_probe(broker, f"{root}/availability", f"{root}/response/#") as probe:
        async with running_gateway(settings) as (_, controller):
            controller.m3_delay_s = 10.0
            await probe.publish_json(f"{root}/request/gcode", {"line": "M3", "transaction": 5})
            await asyncio.wait_for(controller.called.wait(), 2.0)
        offline = await probe.wait_json(f"{root}/availability", lambda d: d["state"] == "offline")
        async with open_probe(broker, f"{root}/availability") as late:
            retained = await late.wait_for(lambda m: m.topic.value == f"{root}/availability")
    assert offline == {"state": "offline"}
    assert retained.retain
    assert bytes(retained.payload) == b'{"state":"offline"}'
    topics = [m.topic.value.rsplit("/", 1)[1] for m in probe.messages]
    assert topics == ["availability", "gcode", "availability"]  # online, answer, offline
    assert probe.json_on(f"{root}/response/gcode") == [
        {"status": "error", "data": {}, "error": "cancelled: the daemon is stopping",
         "transaction": 5}
    ]  # fmt: skip
    assert controller.cancelled == ["M3"]
