"""Settings, topic helpers and the outbox, without a broker."""

from __future__ import annotations

import aiomqtt
import pytest
from pydantic import ValidationError

from dthc_bridge.mqtt import MqttSettings, Topics
from dthc_bridge.mqtt.outbox import Outbox, Outgoing
from dthc_bridge.mqtt.topics import filter_error


def test_defaults_give_the_documented_topics() -> None:
    """Base dthc, board table1: every topic sits under dthc/table1/."""
    settings = MqttSettings()
    topics = settings.topics
    assert topics.request_filter == "dthc/table1/request/#"
    assert topics.response("gcode") == "dthc/table1/response/gcode"
    assert topics.state == "dthc/table1/state"
    assert settings.effective_client_id == "dthc-bridge-table1"
    assert settings.protocol == "5"
    assert settings.telemetry_hz == 10.0


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"hots": "x"}, "hots"),
        ({"board_id": "table 1"}, "board_id"),
        ({"base_topic": "dthc/#"}, "base_topic"),
        ({"telemetry_hz": 60}, "telemetry_hz"),
        ({"protocol": "4"}, "protocol"),
        ({"port": 0}, "port"),
        ({"sender_will_topic": "a/#/b"}, "'#' must be a whole level"),
        ({"sender_will_topic": "dthc/table1/request/x"}, "overlaps the gateway's own topic"),
        ({"sender_will_topic": "dthc/+/state"}, "overlaps"),
        ({"reconnect_initial_s": 5, "reconnect_max_s": 1}, "reconnect_max_s"),
        ({"max_concurrent_requests": 8, "max_pending_requests": 4}, "max_pending_requests"),
        ({"tls": {"cert_file": "/c.pem"}}, "cert_file and key_file"),
    ],
)
def test_bad_settings_are_refused_naming_the_key(values: dict[str, object], message: str) -> None:
    """Unknown keys, out-of-range values and overlapping topics name what is wrong."""
    with pytest.raises(ValidationError, match=message):
        MqttSettings.model_validate(values)


def test_a_sender_will_topic_beside_the_gateways_own_is_fine() -> None:
    """dthc/table1/sender/availability is not a topic the gateway publishes."""
    settings = MqttSettings(sender_will_topic="dthc/table1/sender/availability")
    assert settings.sender_will_topic == "dthc/table1/sender/availability"


def test_the_password_never_shows_in_a_repr() -> None:
    """SecretStr keeps the broker password out of logs and tracebacks."""
    settings = MqttSettings.model_validate({"username": "u", "password": "hunter2"})
    assert "hunter2" not in repr(settings)


@pytest.mark.parametrize(
    ("topic_filter", "topic", "matches"),
    [
        ("a/b", "a/b", True),
        ("a/+", "a/b", True),
        ("a/+", "a/b/c", False),
        ("a/#", "a", True),
        ("a/#", "a/b/c", True),
        ("+/+", "a", False),
        ("a/b", "a/c", False),
    ],
)
def test_topic_filter_matching(topic_filter: str, topic: str, matches: bool) -> None:
    """+ is one level, # is the rest (including the parent level): aiomqtt's matching, which
    the sender-will overlap check and the gateway's will dispatch rely on."""
    assert aiomqtt.Topic(topic).matches(topic_filter) is matches


def test_filter_validation() -> None:
    """Wildcards must fill whole levels; # only at the end."""
    assert filter_error("a/+/b/#") is None
    assert filter_error("a/b#") is not None
    assert filter_error("a/#/b") is not None
    assert filter_error("a+/b") is not None


def test_v5_response_topics_may_not_overwrite_the_boards_own_topics() -> None:
    """Replies may go anywhere outside the board's tree, or to its response/ and reply/."""
    topics = Topics.for_board("dthc", "table1")
    assert topics.may_reply_to("sender/replies/1")
    assert topics.may_reply_to("dthc/table1/reply/sender-1")
    assert topics.may_reply_to("dthc/table1/response/x")
    assert not topics.may_reply_to("dthc/table1/state")
    assert not topics.may_reply_to("dthc/table1/availability")


async def test_the_outbox_keeps_order_drops_stale_and_overflowing_messages() -> None:
    """Oldest first; a message held longer than hold_s or pushed out by overflow is
    dropped and counted, never sent late."""
    now = [0.0]
    outbox = Outbox(max_messages=3, hold_s=10.0, clock=lambda: now[0])
    for index in range(4):
        outbox.put(Outgoing(f"t/{index}", b"", created_s=now[0]))
    assert outbox.dropped == 1  # t/0 pushed out
    first = await outbox.get()
    assert first.topic == "t/1"
    outbox.unget(first)
    assert (await outbox.get()).topic == "t/1"
    now[0] = 20.0
    outbox.put(Outgoing("t/fresh", b"", created_s=now[0]))
    assert (await outbox.get()).topic == "t/fresh"  # t/2 and t/3 were too old
    assert outbox.dropped == 3
    assert len(outbox) == 0
    outbox.put(Outgoing("t/late", b"", created_s=0.0))
    assert outbox.pop() is None  # only a stale one left: pop never blocks
    assert outbox.dropped == 4
