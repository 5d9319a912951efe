"""MqttGateway: the daemon's MQTT side (aiomqtt 2.x).

Requests arrive on ``<base>/<board_id>/request/<name>`` and are answered on
``response/<name>`` (zigbee2mqtt contract, ``transaction`` copied; also on the MQTT v5
Response Topic with the Correlation Data). Every request gets exactly one response: bad
input is refused before it reaches the controller, and each accepted request runs as its
own task under a deadline, so a long M3 never blocks a status request.

The gateway also publishes retained ``availability`` (the MQTT will says offline),
``board`` and ``state`` documents, ``event`` (QoS 1), ``telemetry`` (QoS 0, decimated) and
retained ``diagnostics``. When the broker goes away the controller keeps running; the
gateway reconnects with capped, jittered backoff, republishes its retained documents and
sends the responses and events that waited in the outbox.
"""

from __future__ import annotations

import asyncio
import random
import socket
from collections.abc import AsyncGenerator, Callable
from dataclasses import asdict, dataclass
from typing import Final, TypeVar

import aiomqtt
import structlog
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from ..backoff import backoff_delay_s
from ..port import CommandResult, ControllerPort
from ..requests import execute
from .broker import BrokerRefused, describe_broker_error, is_refusal
from .cancellation import honour_cancellation
from .denials import DenialWatch
from .outbox import Outbox, Outgoing
from .payloads import (
    GcodeRequest,
    Request,
    RequestRefused,
    Transaction,
    decode_request,
    encode_json,
    is_offline_payload,
    peek_transaction,
    response_payload,
)
from .settings import MqttSettings
from .topics import REQUEST_NAME, topic_error
from .transactions import TransactionCache

__all__ = ["GatewayStats", "MqttGateway"]

log = structlog.get_logger("dthc_bridge.mqtt")

ONLINE: Final = b'{"state":"online"}'
OFFLINE: Final = b'{"state":"offline"}'
GOODBYE_TIMEOUT_S: Final = 2.0  # shutdown: flush responses and say offline, at most this
SENDER_LOST_TIMEOUT_S: Final = 5.0
SENDER_WILL_CONFIRM_S: Final = 0.25
"""How long a sender's will waits for our own disconnection before it counts as the sender's
death (the sender waits as long for the daemon's will, for the same reason)."""
RESPONSE_TOPIC_MAX_BYTES: Final = 1024

T = TypeVar("T")


@dataclass(slots=True)
class GatewayStats:
    """Gateway counters, published on ``diagnostics`` under ``mqtt``."""

    connects: int = 0
    disconnects: int = 0
    requests: int = 0
    refused: int = 0
    timeouts: int = 0
    responses_ok: int = 0
    responses_error: int = 0
    published: int = 0
    publish_refused: int = 0  # paho refused the message (e.g. a bad response topic)
    dropped: int = 0  # outbox overflow or held too long
    inflight: int = 0
    outbox: int = 0
    sender_lost: int = 0
    repeated: int = 0  # a transaction seen before: answered, not executed again
    broker_refused: int = 0  # publications and subscriptions the broker's ACL refused

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


@dataclass(slots=True)
class _Reply:
    """Where and how to answer one request."""

    name: str
    received_s: float
    transaction: Transaction | None = None
    response_topic: str | None = None
    correlation_data: bytes | None = None


class MqttGateway:
    def __init__(
        self,
        settings: MqttSettings,
        controller: ControllerPort,
        *,
        rng: random.Random | None = None,
    ) -> None:
        self.settings = settings
        self.controller = controller
        self.topics = settings.topics
        self.stats = GatewayStats()
        self._rng = rng or random.Random()
        self._v5 = settings.protocol == "5"
        self._outbox = Outbox(settings.outbox_max_messages, settings.outbox_hold_s)
        self._slots = asyncio.Semaphore(settings.max_concurrent_requests)
        self._inflight: set[asyncio.Task[None]] = set()
        self._transactions: TransactionCache[_Reply] = TransactionCache(
            settings.transaction_cache_size, settings.transaction_cache_s
        )
        self._background: set[asyncio.Task[None]] = set()
        self._connected = asyncio.Event()
        self._epoch = 0  # connections so far: a will is judged against the one it came on
        self._lost_epoch = -1  # the last connection whose message stream broke
        self._last_state: bytes | None = None
        self._last_board: bytes | None = None
        self._last_materials: bytes | None = None
        self._failing: set[str] = set()  # controller getters currently raising (log once)
        self._denials = DenialWatch()  # what the broker's ACL refuses us, said once per topic

    # --- public ------------------------------------------------------------------------------

    @property
    def is_connected(self) -> bool:
        return self._connected.is_set()

    @property
    def broker_refusals(self) -> dict[str, int]:
        """Topics the broker refused us (its ACL), with how often."""
        return dict(self._denials.refused)

    async def wait_connected(self) -> None:
        """Until the gateway is connected, subscribed and has announced itself online."""
        await self._connected.wait()

    async def run(self) -> None:
        """Serve MQTT until cancelled; on cancellation say offline and disconnect cleanly."""
        log.info(
            "mqtt_gateway_start", host=self.settings.host, port=self.settings.port,
            protocol=self.settings.protocol, root=self.topics.root,
        )  # fmt: skip
        events = asyncio.create_task(self._pump_events(), name="mqtt-events")
        try:
            await self._connection_loop()
        finally:
            events.cancel()
            await self._cancel_all(self._inflight)
            await self._cancel_all(self._background)
            await asyncio.wait({events})
            self._outbox.drop_all("gateway stopped")
            self._connected.clear()
            log.info("mqtt_gateway_stopped", **self._counters())

    # --- connection ----------------------------------------------------------------------------

    def _make_client(self) -> aiomqtt.Client:
        s = self.settings
        client = aiomqtt.Client(
            **s.client_options(),
            identifier=s.effective_client_id,
            will=aiomqtt.Will(self.topics.availability, OFFLINE, qos=1, retain=True),
            keepalive=s.keepalive_s,
            timeout=s.operation_timeout_s,
            # Without it Nagle holds each small publish until the previous one is acked.
            socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)],
        )
        self._denials.watch(client)
        return client

    async def _connection_loop(self) -> None:
        # A fresh Client per attempt rather than one reused Client (aiomqtt's documented
        # pattern): after an unexpected disconnect aiomqtt 2.5 keeps the old CONNACK future,
        # so a reused client's __aenter__ returns before the new CONNACK, and paho replays
        # QoS 1 messages left from the old connection after the ones we publish on
        # reconnect: a stale retained state would overwrite the fresh one. The outbox
        # already gives responses and events at-least-once delivery across reconnects.
        failures = 0
        while True:
            error = ""
            client = self._make_client()
            try:
                async with client:
                    failures = 0
                    await self._serve_connection(client)
            except* aiomqtt.MqttError as group:
                error = "; ".join(str(exc) for exc in group.exceptions) or "disconnected"
                refusal = next((e for e in group.exceptions if is_refusal(e, self.settings)), None)
                if refusal is not None and self.stats.connects == 0:
                    # Never logged in: a wrong password, user or CA, which no retry mends.
                    raise BrokerRefused(describe_broker_error(refusal, self.settings)) from None
            if self._connected.is_set():
                self._connected.clear()
                self.stats.disconnects += 1
            failures += 1
            delay_s = backoff_delay_s(
                failures,
                initial_s=self.settings.reconnect_initial_s,
                max_s=self.settings.reconnect_max_s,
                rng=self._rng,
            )
            log.warning(
                "mqtt_disconnected", host=self.settings.host, port=self.settings.port,
                error=error, attempt=failures, retry_in_s=round(delay_s, 3),
                outbox=len(self._outbox), inflight=len(self._inflight),
            )  # fmt: skip
            await asyncio.sleep(delay_s)

    async def _serve_connection(self, client: aiomqtt.Client) -> None:
        """Inside ``async with client``: subscribe, announce, run the loops until it drops."""
        try:
            if self._v5:
                # Retain As Published: a retained request keeps its flag even when it
                # arrives live, so it is refused then too (on 3.1.1 the broker clears the
                # flag on live delivery; the replay at the next subscribe is refused).
                options = SubscribeOptions(qos=1, retainAsPublished=True)
                granted = await client.subscribe(self.topics.request_filter, options=options)
            else:
                granted = await client.subscribe(self.topics.request_filter, qos=1)
            self._denials.check_subscribe(self.topics.request_filter, _codes(granted))
            will = self.settings.sender_will_filter
            if will is not None:
                self._denials.check_subscribe(will, _codes(await client.subscribe(will, qos=1)))
            self.stats.connects += 1
            self._epoch += 1
            await self._announce(client)
            self._connected.set()
            log.info(
                "mqtt_connected", host=self.settings.host, port=self.settings.port,
                client_id=client.identifier, connects=self.stats.connects,
                outbox=len(self._outbox),
            )  # fmt: skip
            async with asyncio.TaskGroup() as group:
                group.create_task(self._read(client), name="mqtt-read")
                group.create_task(self._send_outbox(client), name="mqtt-outbox")
                group.create_task(self._watch_state(client), name="mqtt-state")
                group.create_task(self._send_diagnostics(client), name="mqtt-diagnostics")
                if self.settings.telemetry_hz > 0:
                    group.create_task(self._send_telemetry(client), name="mqtt-telemetry")
        except asyncio.CancelledError:
            await self._goodbye(client)
            raise

    async def _announce(self, client: aiomqtt.Client) -> None:
        """On every (re)connect: online, then every retained document, fresh."""
        await client.publish(self.topics.availability, ONLINE, qos=1, retain=True)
        self._last_board = None
        self._last_state = None
        self._last_materials = None
        await self._publish_board(client)
        await self._publish_state(client)
        await self._publish_materials(client)
        await self._publish_diagnostics(client)

    async def _goodbye(self, client: aiomqtt.Client) -> None:
        """Clean shutdown: cancelled requests answered, outbox flushed, then offline."""
        self._connected.clear()
        await self._cancel_all(self._inflight)  # each one queues its "stopping" response
        loop = asyncio.get_running_loop()
        end_s = loop.time() + GOODBYE_TIMEOUT_S
        try:
            while loop.time() < end_s and (item := self._outbox.pop()) is not None:
                await self._publish_item(client, item, timeout_s=max(0.1, end_s - loop.time()))
            await client.publish(
                self.topics.availability, OFFLINE, qos=1, retain=True,
                timeout=max(0.1, end_s - loop.time()),
            )  # fmt: skip
            log.info("mqtt_offline_published")
        except aiomqtt.MqttError as exc:
            log.warning("mqtt_goodbye_failed", error=str(exc))

    # --- inbound -------------------------------------------------------------------------------

    async def _read(self, client: aiomqtt.Client) -> None:
        try:
            async for message in client.messages:
                try:
                    self._on_message(message)
                except Exception:  # never let one message end the connection
                    log.exception("mqtt_message_failed", topic=message.topic.value)
        except aiomqtt.MqttError:
            # Lost: say so now, not once the other loops have wound down (a publish may
            # wait for its acknowledgement first); a sender's will that came just before
            # is then seen for what it is, the broker going away.
            self._lost_epoch = self._epoch
            raise

    def _on_message(self, message: aiomqtt.Message) -> None:
        topic = message.topic.value
        name = self.topics.request_name(topic)
        if name is not None:
            self._on_request(name, message)
            return
        will = self.settings.sender_will_filter
        if will is not None and message.topic.matches(will):
            self._on_sender_will(message)
            return
        log.debug("mqtt_unexpected_message", topic=topic)

    def _on_request(self, name: str, message: aiomqtt.Message) -> None:
        if message.retain and not message.payload:
            # Someone clearing a retained request (empty retained message): not a request.
            log.info("mqtt_retained_request_cleared", topic=message.topic.value)
            return
        loop = asyncio.get_running_loop()
        self.stats.requests += 1
        reply = _Reply(name=name, received_s=loop.time())
        response_topic, reply.correlation_data = _v5_reply_properties(message)
        if response_topic is not None:
            problem = topic_error(response_topic)
            if problem is None and len(response_topic.encode()) > RESPONSE_TOPIC_MAX_BYTES:
                problem = "longer than 1024 bytes"
            if problem is None and not self.topics.may_reply_to(response_topic):
                problem = "would write over this board's own topics"
            if problem is None:
                reply.response_topic = response_topic
            else:
                log.warning("mqtt_response_topic_ignored", topic=response_topic, reason=problem)
        if message.retain:
            reply.transaction = peek_transaction(
                bytes(message.payload), max_payload_bytes=self.settings.max_payload_bytes
            )
            self._refuse(reply, "retained requests are refused: publish with retain=false")
            return
        if not REQUEST_NAME.fullmatch(name):
            self._refuse(reply, f"invalid request name {name!r}: expected [A-Za-z0-9_-]{{1,64}}")
            return
        try:
            request = decode_request(
                name, bytes(message.payload), max_payload_bytes=self.settings.max_payload_bytes
            )
        except RequestRefused as exc:
            reply.transaction = exc.transaction
            self._refuse(reply, exc.reason)
            return
        reply.transaction = request.transaction
        if request.transaction is not None and not self._admit(
            reply, request.transaction, bytes(message.payload), loop.time()
        ):
            return
        if len(self._inflight) >= self.settings.max_pending_requests:
            self._refuse(reply, f"busy: {len(self._inflight)} requests in progress")
            if request.transaction is not None:  # not executed: a retry may run it
                self._transactions.forget(name, request.transaction)
            return
        deadline_s = self.settings.request_deadline_s
        if request.deadline_s is not None:
            deadline_s = min(deadline_s, request.deadline_s)
        task = asyncio.create_task(
            self._serve(reply, request, reply.received_s + deadline_s),
            name=f"mqtt-request-{name}",
        )
        self._inflight.add(task)
        task.add_done_callback(self._inflight.discard)

    def _admit(self, reply: _Reply, transaction: Transaction, payload: bytes, now_s: float) -> bool:
        """True to execute; False for a repeat (answered now or when the first copy ends)
        or a transaction reused for another request (refused)."""
        seen = self._transactions.admit(reply.name, transaction, payload, reply, now_s)
        if seen.run:
            return True
        if seen.conflict and seen.used_for not in (None, reply.name):
            self._refuse(
                reply,
                f"transaction {transaction!r} was already used for a {seen.used_for!r} "
                f"request; this is a {reply.name!r} request: use a new transaction",
            )
            return False
        if seen.conflict:
            self._refuse(
                reply,
                f"transaction {transaction!r} was already used for a different "
                f"{reply.name} request: use a new transaction for a new request",
            )
            return False
        self.stats.repeated += 1
        log.info(
            "mqtt_request_repeated", name=reply.name, transaction=transaction,
            answered=seen.result is not None,
        )  # fmt: skip
        if seen.result is not None:
            self._respond(reply, seen.result)
        return False

    def _refuse(self, reply: _Reply, reason: str) -> None:
        self.stats.refused += 1
        log.warning(
            "mqtt_request_refused", name=reply.name, transaction=reply.transaction, reason=reason
        )
        self._respond(reply, CommandResult(False, error=reason))

    async def _serve(
        self, reply: _Reply, request: GcodeRequest | Request, deadline_s: float
    ) -> None:
        started = False
        scope = asyncio.timeout_at(deadline_s)
        try:
            async with scope, self._slots:
                started = True
                result = await execute(self.controller, reply.name, request)
        except TimeoutError as exc:
            if not scope.expired():
                result = _internal_error(reply.name, exc)
            else:
                self.stats.timeouts += 1
                result = CommandResult(
                    False, error="timeout" if started else "timeout: not started"
                )
        except asyncio.CancelledError:
            self._answer(reply, CommandResult(False, error="cancelled: the daemon is stopping"))
            raise
        except Exception as exc:
            result = _internal_error(reply.name, exc)
        if not isinstance(result, CommandResult):  # a broken controller is still answered
            result = _internal_error(reply.name, TypeError(f"controller returned {result!r}"))
        self._answer(reply, result)

    def _answer(self, reply: _Reply, result: CommandResult) -> None:
        """The executed request's response, and the same for each repeat that waited."""
        self._respond(reply, result)
        if reply.transaction is not None:
            now_s = asyncio.get_running_loop().time()
            for waiting in self._transactions.finish(reply.name, reply.transaction, result, now_s):
                self._respond(waiting, result)

    def _respond(self, reply: _Reply, result: CommandResult) -> None:
        payload = response_payload(result, reply.transaction)
        label = f"{reply.name}#{reply.transaction}" if reply.transaction is not None else reply.name
        self._outbox.put(Outgoing(self.topics.response(reply.name), payload, label=label))
        if reply.response_topic is not None:
            self._outbox.put(
                Outgoing(
                    reply.response_topic,
                    payload,
                    correlation_data=reply.correlation_data,
                    label=label,
                )
            )
        if result.ok:
            self.stats.responses_ok += 1
        else:
            self.stats.responses_error += 1
        elapsed_ms = round((asyncio.get_running_loop().time() - reply.received_s) * 1e3, 1)
        log.info(
            "mqtt_response", name=reply.name, transaction=reply.transaction,
            status="ok" if result.ok else "error", error=result.error or None,
            elapsed_ms=elapsed_ms,
        )  # fmt: skip

    def _on_sender_will(self, message: aiomqtt.Message) -> None:
        topic = message.topic.value
        if message.retain:
            # A retained will is from before we subscribed (maybe a previous run): it must
            # not stop a cut that started since. The board lease still covers a dead sender.
            log.info("sender_will_retained_ignored", topic=topic)
            return
        if not is_offline_payload(bytes(message.payload)):
            log.debug("sender_will_other", topic=topic)
            return
        task = asyncio.create_task(self._confirm_sender_lost(topic), name="mqtt-sender-lost")
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    async def _confirm_sender_lost(self, topic: str) -> None:
        """A broker shutting down publishes every client's will, the sender's too, then
        drops us within milliseconds: a will followed at once by our own disconnection is
        the broker going away (the cut goes on: THC is local), not the sender dying."""
        epoch = self._epoch
        await asyncio.sleep(SENDER_WILL_CONFIRM_S)
        if not self._connected.is_set() or self._epoch != epoch or self._lost_epoch == epoch:
            log.warning("sender_will_was_the_broker", topic=topic)
            return
        self.stats.sender_lost += 1
        log.warning("sender_lost", topic=topic)
        await self._call_sender_lost(f"sender last will on {topic}")

    async def _call_sender_lost(self, reason: str) -> None:
        try:
            async with asyncio.timeout(SENDER_LOST_TIMEOUT_S):
                await self.controller.sender_lost(reason)
        except Exception:
            log.exception("sender_lost_failed", reason=reason)

    # --- outbound ------------------------------------------------------------------------------

    async def _send_outbox(self, client: aiomqtt.Client) -> None:
        while True:
            honour_cancellation()
            item = await self._outbox.get()
            await self._publish_item(client, item, timeout_s=None)

    async def _publish_item(
        self, client: aiomqtt.Client, item: Outgoing, *, timeout_s: float | None
    ) -> None:
        properties = None
        if self._v5 and item.correlation_data is not None:
            # paho's Properties constructor carries no annotations
            properties = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
            properties.CorrelationData = item.correlation_data
        try:
            await client.publish(
                item.topic, item.payload, qos=item.qos, retain=item.retain,
                properties=properties, timeout=timeout_s,
            )  # fmt: skip
        except aiomqtt.MqttError:
            self._outbox.unget(item)  # not confirmed: send again after the reconnect
            raise
        except asyncio.CancelledError:
            self._outbox.unget(item)
            raise
        except (ValueError, TypeError) as exc:  # paho refuses this one message
            self.stats.publish_refused += 1
            log.warning("mqtt_publish_refused", topic=item.topic, error=str(exc))
            return
        self.stats.published += 1

    async def _publish_state(self, client: aiomqtt.Client) -> None:
        state = self._safely("snapshot", self.controller.snapshot)
        if state is None:
            return
        payload = encode_json(state)
        if payload != self._last_state:
            await client.publish(self.topics.state, payload, qos=1, retain=True)
            self._last_state = payload
            self.stats.published += 1

    async def _publish_board(self, client: aiomqtt.Client) -> None:
        link = self._safely("link_state", self.controller.link_state)
        if link is None:
            return
        state, reason = link
        payload = encode_json({"state": state, "reason": reason})
        if payload != self._last_board:
            await client.publish(self.topics.board, payload, qos=1, retain=True)
            self._last_board = payload
            self.stats.published += 1

    async def _publish_materials(self, client: aiomqtt.Client) -> None:
        document = self._safely("materials", self.controller.materials)
        if document is None:
            return
        payload = encode_json(document)
        if payload != self._last_materials:
            await client.publish(self.topics.materials, payload, qos=1, retain=True)
            self._last_materials = payload
            self.stats.published += 1

    async def _publish_diagnostics(self, client: aiomqtt.Client) -> None:
        document: dict[str, object] = dict(
            self._safely("diagnostics", self.controller.diagnostics) or {}
        )
        document["mqtt"] = self._counters()
        await client.publish(self.topics.diagnostics, encode_json(document), qos=0, retain=True)
        self.stats.published += 1

    async def _watch_state(self, client: aiomqtt.Client) -> None:
        while True:
            honour_cancellation()
            await asyncio.sleep(self.settings.state_poll_s)
            await self._publish_board(client)
            await self._publish_state(client)
            await self._publish_materials(client)

    async def _send_diagnostics(self, client: aiomqtt.Client) -> None:
        while True:
            honour_cancellation()
            await asyncio.sleep(self.settings.diagnostics_period_s)
            await self._publish_diagnostics(client)

    async def _send_telemetry(self, client: aiomqtt.Client) -> None:
        period_s = 1.0 / self.settings.telemetry_hz
        last: bytes | None = None
        while True:
            honour_cancellation()
            point = self._safely("telemetry", self.controller.telemetry)
            if point is not None:
                payload = encode_json(point)
                if payload != last:  # a frozen point (board offline) is not repeated
                    await client.publish(self.topics.telemetry, payload, qos=0)
                    self.stats.published += 1
                    last = payload
            await asyncio.sleep(period_s)

    async def _pump_events(self) -> None:
        """Controller events into the outbox, for the whole run (kept across reconnects)."""
        while True:
            iterator = self.controller.subscribe_events()
            try:
                async for event in iterator:
                    payload = encode_json(event.as_payload())
                    self._outbox.put(
                        Outgoing(self.topics.event, payload, kind="event", label=event.type)
                    )
            except Exception:
                log.exception("mqtt_event_stream_failed")
            else:
                log.warning("mqtt_event_stream_ended")
                return
            finally:
                if isinstance(iterator, AsyncGenerator):
                    await iterator.aclose()
            await asyncio.sleep(1.0)

    # --- helpers ---------------------------------------------------------------------------------

    def _safely(self, what: str, getter: Callable[[], T]) -> T | None:
        """A controller getter that raises is logged once (and its recovery), never fatal."""
        try:
            value = getter()
        except Exception:
            if what not in self._failing:
                self._failing.add(what)
                log.exception("controller_getter_failed", getter=what)
            return None
        if what in self._failing:
            self._failing.discard(what)
            log.info("controller_getter_recovered", getter=what)
        return value

    def _counters(self) -> dict[str, int]:
        self.stats.inflight = len(self._inflight)
        self.stats.outbox = len(self._outbox)
        self.stats.dropped = self._outbox.dropped
        self.stats.broker_refused = sum(self._denials.refused.values())
        return self.stats.as_dict()

    @staticmethod
    async def _cancel_all(tasks: set[asyncio.Task[None]]) -> None:
        pending = [task for task in tasks if not task.done()]
        for task in pending:
            task.cancel()
        if pending:
            await asyncio.wait(pending)


def _codes(granted: object) -> list[object]:
    """A SUBACK's reason codes (aiomqtt returns them as a tuple or a list)."""
    return list(granted) if isinstance(granted, tuple | list) else []


def _v5_reply_properties(message: aiomqtt.Message) -> tuple[str | None, bytes | None]:
    properties = message.properties
    if properties is None:
        return None, None
    topic = getattr(properties, "ResponseTopic", None)
    correlation = getattr(properties, "CorrelationData", None)
    return (
        topic if isinstance(topic, str) else None,
        bytes(correlation) if isinstance(correlation, bytes | bytearray) else None,
    )


def _internal_error(name: str, exc: BaseException) -> CommandResult:
    log.error("mqtt_request_failed", name=name, error=repr(exc), exc_info=exc)
    return CommandResult(False, error=f"internal error: {type(exc).__name__}: {exc}")
