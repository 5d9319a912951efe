"""Process death, broker restarts, the sender's last will, and authentication."""

from __future__ import annotations

import asyncio
import gc
import subprocess
import sys
import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import aiomqtt
import pytest

from dthc_bridge.mqtt import MqttGateway, MqttTls
from dthc_bridge.mqtt.broker import BrokerRefused
from dthc_tools.procs import die_with_parent

from .conftest import USERS, Broker
from .fakes import FakeController
from .helpers import fast_settings, open_probe, running_gateway, unique_base

pytestmark = pytest.mark.slow

REPO = Path(__file__).parents[2]


@asynccontextmanager
async def helper_process(
    role: str, broker: Broker, name: str
) -> AsyncIterator[subprocess.Popen[str]]:
    """tests/mqtt/procs.py as its own process, after it printed READY; SIGKILLed at the end."""
    proc = subprocess.Popen(  # noqa: ASYNC220 - the test needs the handle to SIGKILL it
        [sys.executable, "-m", "tests.mqtt.procs", role, str(broker.port), name],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        preexec_fn=die_with_parent(),
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = await asyncio.wait_for(asyncio.to_thread(proc.stdout.readline), 10.0)
        assert line.strip() == "READY", line
        yield proc
    finally:
        proc.kill()
        await asyncio.to_thread(proc.wait, 5)
        if proc.stdout is not None:
            proc.stdout.close()


async def test_the_last_will_says_offline_when_the_gateway_process_is_killed(
    broker: Broker,
) -> None:
    """availability is online while the gateway runs; kill -9 leaves no chance for a
    goodbye, and the broker publishes the will: offline, retained."""
    base = unique_base()
    topic = f"{base}/table1/availability"
    async with open_probe(broker, topic) as probe:
        async with helper_process("gateway", broker, base) as proc:
            online = await probe.wait_json(topic, lambda d: d["state"] == "online")
            proc.kill()
            offline = await probe.wait_json(topic, lambda d: d["state"] == "offline")
        async with open_probe(broker, topic) as late:
            retained = await late.wait_for(lambda m: m.topic.value == topic)
    assert online == {"state": "online"}
    assert offline == {"state": "offline"}
    assert retained.retain
    assert bytes(retained.payload) == b'{"state":"offline"}'


async def test_after_a_broker_restart_the_gateway_republishes_and_answers_again(
    own_broker: Broker,
) -> None:
    """The broker restarts empty (no persistence): the gateway reconnects by itself,
    republishes availability, board and state, and answers a request sent afterwards."""
    settings = fast_settings(own_broker)
    root = settings.topics.root
    async with running_gateway(settings) as (gateway, controller):
        controller.state = {"state": "idle", "armed": True, "line": 3}
        await asyncio.sleep(0.15)  # published before the restart
        own_broker.stop()
        await asyncio.sleep(0.3)
        assert not gateway.is_connected
        own_broker.start()
        await asyncio.wait_for(gateway.wait_connected(), 5.0)
        async with open_probe(own_broker, f"{root}/+", f"{root}/response/#") as probe:
            availability = await probe.wait_json(f"{root}/availability")
            state = await probe.wait_json(f"{root}/state")
            board = await probe.wait_json(f"{root}/board")
            await probe.publish_json(f"{root}/request/gcode", {"line": "M5", "transaction": "r"})
            response = await probe.wait_json(f"{root}/response/gcode")
        assert gateway.stats.connects == 2
        assert gateway.stats.disconnects == 1
    assert availability == {"state": "online"}
    assert state == {"state": "idle", "armed": True, "line": 3}
    assert board == {"state": "online", "reason": "handshake complete"}
    assert response == {"status": "ok", "data": {"line": "M5", "xy_mm": None}, "transaction": "r"}


async def test_a_response_finished_while_the_broker_is_down_is_published_after_reconnect(
    persistent_broker: Broker,
) -> None:
    """A 1 s dwell is running when the broker stops; the controller finishes meanwhile;
    after the restart its response goes out (the probe's persistent session queues it)."""
    broker = persistent_broker
    settings = fast_settings(broker)
    root = settings.topics.root
    probe_id = f"probe-{uuid.uuid4().hex[:8]}"
    persistent: dict[str, Any] = {"identifier": probe_id, "clean_session": False}
    async with running_gateway(settings) as (gateway, controller):
        async with open_probe(broker, f"{root}/response/#", **persistent) as probe:
            await probe.publish_json(
                f"{root}/request/gcode", {"line": "G4 P0.6", "transaction": "held"}
            )
            await asyncio.wait_for(controller.called.wait(), 2.0)
        broker.stop()
        await asyncio.sleep(1.0)
        assert controller.finished == ["G4 P0.6"]  # done while nobody could hear
        assert not gateway.is_connected
        broker.start()
        async with open_probe(broker, **persistent) as probe:
            response = await probe.wait_json(f"{root}/response/gcode", timeout_s=5.0)
    assert response == {
        "status": "ok", "data": {"line": "G4 P0.6", "xy_mm": None}, "transaction": "held"
    }  # fmt: skip


async def test_the_senders_last_will_mid_cut_calls_sender_lost(broker: Broker) -> None:
    """A sender process with a retained offline will is killed mid-cut: the broker
    publishes the will, and the gateway tells the controller the sender is lost."""
    will_topic = f"{unique_base()}/sender/availability"
    settings = fast_settings(broker, sender_will_topic=will_topic)
    async with (
        running_gateway(settings) as (_, controller),
        helper_process("sender", broker, will_topic) as sender,
    ):
        controller.state = {"state": "cutting", "armed": True, "line": 40}
        await asyncio.sleep(0.1)
        assert controller.sender_lost_calls == []  # its "online" is not a loss
        sender.kill()
        await controller.wait_sender_lost()
    assert controller.sender_lost_calls == [f"sender last will on {will_topic}"]


async def test_a_retained_offline_will_from_before_is_ignored_but_a_live_one_counts(
    broker: Broker,
) -> None:
    """A retained offline will already on the broker (a previous run's) must not stop a
    new cut; a live plain 'offline' or JSON offline does."""
    will_topic = f"{unique_base()}/sender/availability"
    settings = fast_settings(broker, sender_will_topic=will_topic)
    async with open_probe(broker) as sender:
        await sender.client.publish(will_topic, b'{"state":"offline"}', qos=1, retain=True)
        async with running_gateway(settings) as (_, controller):
            await asyncio.sleep(0.2)
            assert controller.sender_lost_calls == []
            await sender.client.publish(will_topic, b'{"state":"online"}', qos=1)
            await sender.client.publish(will_topic, b"offline", qos=1)
            await sender.client.publish(will_topic, b'{"state": "offline"}', qos=1)
            await controller.wait_sender_lost(2)
        await sender.client.publish(will_topic, b"", qos=1, retain=True)  # clear
    assert len(controller.sender_lost_calls) == 2


async def test_password_and_acl_example_admit_the_daemon_and_the_sender(
    auth_broker: Broker,
) -> None:
    """With passwords and the shipped ACL example: the daemon user connects and answers
    the sender user's request; a wrong password ends the gateway naming the refused user
    (no retry mends it) instead of retrying forever."""
    settings = fast_settings(
        auth_broker, base_topic="dthc", board_id="table1",
        username="dthc-daemon", password=USERS["dthc-daemon"],
        sender_will_topic="dthc/table1/sender/availability",
    )  # fmt: skip
    async with (
        running_gateway(settings) as (_, controller),
        open_probe(
            auth_broker, "dthc/table1/#", username="dthc-sender", password=USERS["dthc-sender"]
        ) as probe,
    ):
        await probe.publish_json("dthc/table1/request/gcode", {"line": "M5", "transaction": 1})
        response = await probe.wait_json("dthc/table1/response/gcode")
        await probe.client.publish("dthc/table1/sender/availability", b"offline", qos=1)
        await controller.wait_sender_lost()
        state = await probe.wait_json("dthc/table1/state", lambda d: d["state"] == "aborted")
    assert response["status"] == "ok"
    assert state["state"] == "aborted"

    wrong = settings.model_copy(update={"password": None, "client_id": "gw-wrong"})
    gateway = MqttGateway(wrong, FakeController())
    with pytest.raises(BrokerRefused, match="refused the login of user 'dthc-daemon'"):
        await asyncio.wait_for(gateway.run(), 5.0)
    assert not gateway.is_connected


async def test_an_unknown_user_cannot_connect_to_the_auth_broker(auth_broker: Broker) -> None:
    """Sanity check of the fixture: anonymous clients are refused, so the test above
    really exercised the passwords."""
    with pytest.raises(aiomqtt.MqttError):
        async with open_probe(auth_broker, "dthc/#"):
            pass


async def test_tls_with_a_private_ca_connects(tls_broker: Broker) -> None:
    """tls.ca_file reaches the client: the broker's self-signed certificate is trusted."""
    assert tls_broker.tls is not None
    cert = tls_broker.tls[0]
    settings = fast_settings(tls_broker, tls={"ca_file": cert})
    root = settings.topics.root
    trusting = aiomqtt.TLSParameters(ca_certs=str(cert))
    async with (
        running_gateway(settings),
        open_probe(tls_broker, f"{root}/response/#", tls_params=trusting) as probe,
    ):
        await probe.publish_json(f"{root}/request/status", {"transaction": "tls"})
        response = await probe.wait_json(f"{root}/response/status")
    assert response["status"] == "ok"


# paho-mqtt 2.2 does not close its SSLSocket when the TLS handshake fails (_ssl_wrap_socket),
# so each refused attempt leaves a ResourceWarning for the garbage collector.
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
async def test_tls_without_the_brokers_ca_does_not_connect(tls_broker: Broker) -> None:
    """With the system CA store the self-signed broker is refused: the certificate is
    really verified; the gateway ends naming it (no retry mends it) instead of crashing
    or retrying forever."""
    settings = fast_settings(tls_broker, tls=MqttTls())
    gateway = MqttGateway(settings, FakeController())
    with pytest.raises(BrokerRefused, match="not trusted by the system's CA store"):
        await asyncio.wait_for(gateway.run(), 5.0)
    assert gateway.stats.connects == 0
    gc.collect()  # paho's unclosed socket (above) is collected here, not in the next test


async def test_a_broker_shutting_down_sends_the_senders_will_but_the_cut_goes_on(
    own_broker: Broker,
) -> None:
    """mosquitto publishes every client's will as it shuts down, then drops the daemon: that
    will is the broker going away (THC is local, the cut goes on), not the sender dying."""
    will_topic = f"{unique_base()}/sender/availability"
    settings = fast_settings(own_broker, sender_will_topic=will_topic)
    async with (
        running_gateway(settings) as (_, controller),
        helper_process("sender", own_broker, will_topic),
    ):
        controller.state = {"state": "cutting", "armed": True, "line": 40}
        await asyncio.sleep(0.2)
        own_broker.stop()
        await asyncio.sleep(0.6)  # well past the confirmation window
        own_broker.start()
        await asyncio.sleep(0.3)
    assert controller.sender_lost_calls == []


async def test_a_will_on_a_connection_whose_stream_broke_is_not_a_dead_sender(
    broker: Broker,
) -> None:
    """The read loop marks its connection lost at once, before the other loops wind down
    (a publish may still wait for its acknowledgement, the connection still looking up):
    a will that came on that connection is the broker going away. Found by the fault
    bench: 2 of 7 broker restarts ended the cut before this."""
    will_topic = f"{unique_base()}/sender/availability"
    controller = FakeController()
    gateway = MqttGateway(fast_settings(broker, sender_will_topic=will_topic), controller)
    gateway._connected.set()  # connected, as far as the other loops know
    gateway._lost_epoch = gateway._epoch  # but the message stream broke
    await gateway._confirm_sender_lost(will_topic)
    assert controller.sender_lost_calls == []
    gateway._lost_epoch = -1  # a healthy connection: the will is the sender's death
    await gateway._confirm_sender_lost(will_topic)
    assert controller.sender_lost_calls == [f"sender last will on {will_topic}"]
