"""Publications and subscriptions the broker refuses: said once per topic, never silent.

A broker's ACL that denies the daemon one of its own topics (a ``materials`` missing from
the ACL file) drops those messages: under MQTT 3.1.1 silently, under MQTT 5 with a reason
code in the PUBACK. aiomqtt 2.x completes a publish whatever the PUBACK says, so the codes
are read from the paho client beneath it (``Client._client``, the one handle aiomqtt gives
to it): a wrapper on paho's ``publish`` remembers each message id's topic, and one on
``on_publish`` looks at the reason code that came back for it.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import aiomqtt
import structlog

__all__ = ["DenialWatch"]

log = structlog.get_logger("dthc_bridge.mqtt")

_MAX_TRACKED = 4096  # QoS 1 message ids awaiting a PUBACK; beyond it the oldest are forgotten


class DenialWatch:
    """Counts refusals per topic and logs the first refusal of each topic (a warning)."""

    def __init__(self) -> None:
        self.refused: dict[str, int] = {}

    def watch(self, client: aiomqtt.Client) -> None:
        paho = client._client
        topics: dict[int, str] = {}
        publish = paho.publish
        on_publish = paho.on_publish

        def tracked_publish(topic: str, *args: Any, **kwargs: Any) -> Any:
            info = publish(topic, *args, **kwargs)
            # aiomqtt passes (topic, payload, qos, retain, properties); only QoS 1 and 2
            # are acknowledged, with a reason code, so only they wait here for it.
            qos = kwargs.get("qos", args[1] if len(args) > 1 else 0)
            if qos:
                if len(topics) >= _MAX_TRACKED:
                    topics.pop(next(iter(topics)))
                topics[info.mid] = topic
            return info

        def checked_on_publish(*args: Any) -> None:
            # paho's VERSION2 callback: (client, userdata, mid, reason_code, properties)
            mid, reason_code = args[2], args[3]
            topic = topics.pop(mid, None)
            if topic is not None and getattr(reason_code, "is_failure", False):
                self.denied(topic, str(reason_code), "publish")
            if on_publish is not None:
                on_publish(*args)

        paho.publish = tracked_publish  # type: ignore[method-assign]
        paho.on_publish = checked_on_publish

    def check_subscribe(self, topic_filter: str, reason_codes: Iterable[Any]) -> None:
        """The SUBACK of ``topic_filter``: a failure code means we will never hear it."""
        for code in reason_codes:
            if getattr(code, "is_failure", False) or getattr(code, "value", 0) >= 0x80:
                self.denied(topic_filter, str(code), "subscribe")

    def denied(self, topic: str, reason: str, what: str) -> None:
        count = self.refused.get(topic, 0) + 1
        self.refused[topic] = count
        if count == 1:
            log.warning(
                "mqtt_broker_refused", topic=topic, operation=what, reason=reason,
                hint="the broker's ACL does not let this client use this topic",
            )  # fmt: skip
