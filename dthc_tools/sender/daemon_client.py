"""The sender's MQTT side: requests with transaction ids, responses, and daemon events."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import itertools
import json
import random
import uuid
from collections.abc import AsyncIterator, Callable, Coroutine
from typing import Any, Protocol

import aiomqtt
import structlog

from dthc_bridge.backoff import backoff_delay_s
from dthc_bridge.mqtt.broker import BrokerSettings
from dthc_bridge.mqtt.cancellation import honour_cancellation

__all__ = [
    "INVALID", "DaemonClient", "DaemonError", "DaemonSeam", "gcode_args", "response_data",
]  # fmt: skip

log = structlog.get_logger("dthc_tools.sender")

INVALID = "__invalid__"  # what a subscription's handler gets for a payload that is not JSON
OFFLINE = b'{"state":"offline"}'
ONLINE = b'{"state":"online"}'
OFFLINE_CONFIRM_S = 0.25
"""How long an offline availability waits for our own disconnection before it counts as the
daemon's death: a broker shutting down sends the daemon's will, then drops us in ms."""


class DaemonError(Exception):
    """The daemon answered with an error, or did not answer in time."""


class DaemonSeam(Protocol):
    """What the sender needs of the daemon: :class:`DaemonClient` over MQTT, or the
    daemon's controller service in the same process (``dthc_tools.sim.program``)."""

    def on_event(self, handler: Callable[[dict[str, Any]], None]) -> None: ...

    def on_telemetry(self, handler: Callable[[dict[str, Any]], None]) -> None: ...

    def on_offline(self, handler: Callable[[], None]) -> None: ...

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        """The response's data; DaemonError on an error response."""
        ...

    async def notify(self, name: str, /, **args: Any) -> None:
        """A report whose answer is not awaited."""
        ...

    async def gcode(
        self,
        line: str,
        *,
        line_number: int | None = None,
        xy: tuple[float, float] | None = None,
        dialect: str | None = None,
    ) -> dict[str, Any]: ...


class DaemonClient:
    """The daemon's request/response contract, over a connection that survives the broker.

    The broker may restart mid-program: the client reconnects (capped, jittered backoff),
    subscribes again and re-publishes every request still without an answer, with the
    same transaction. The daemon answers a repeated transaction from its cache instead of
    running it again (``dthc_bridge/mqtt/transactions.py``), so an ``M3`` is neither lost
    nor run twice. Requests are also re-published whenever the daemon announces itself
    online, in case it reconnected to a broker that had lost them.
    """

    def __init__(
        self,
        broker: BrokerSettings,
        *,
        base_topic: str = "dthc",
        board_id: str = "table1",
        timeout_s: float = 60.0,
        reconnect_initial_s: float = 0.2,
        reconnect_max_s: float = 5.0,
        role: str = "sender",
    ) -> None:
        self.broker = broker
        self.root = f"{base_topic}/{board_id}"
        self.timeout_s = timeout_s
        self.reconnect_initial_s = reconnect_initial_s
        self.reconnect_max_s = reconnect_max_s
        identifier = f"dthc-{role}-{uuid.uuid4().hex[:8]}"
        # The sender's own availability (its will says offline): a panel shows whether a
        # program runs, and a daemon configured with sender_will_topic stops a cut at once.
        self.availability_topic = f"{self.root}/{role}/availability"
        will = aiomqtt.Will(self.availability_topic, OFFLINE, qos=1, retain=True)
        # Read now: a password or certificate file that cannot be used fails here, naming
        # the file, not as a reconnect loop later.
        options = broker.client_options()
        self._new_client = functools.partial(
            aiomqtt.Client, **options, identifier=identifier, timeout=10.0, will=will
        )
        self.role = role
        self._subscriptions: dict[str, Callable[[str, dict[str, Any]], None]] = {}
        self._client: aiomqtt.Client | None = None  # while connected and subscribed
        self._ids = itertools.count(1)
        # Transactions are unique per run: the daemon answers a repeated transaction from
        # its cache instead of running it (exactly-once), so a second run must not reuse
        # the first run's "s1", "s2", ...
        self._run_id = uuid.uuid4().hex[:8]
        self._waiting: dict[str, asyncio.Future[dict[str, Any]]] = {}
        self._unanswered: dict[str, tuple[str, str]] = {}  # transaction: (topic, payload)
        self._event_handlers: list[Callable[[dict[str, Any]], None]] = []
        self._offline_handlers: list[Callable[[], None]] = []
        self._telemetry_handlers: list[Callable[[dict[str, Any]], None]] = []
        self._task: asyncio.Task[None] | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._broker_lost = asyncio.Event()  # set from a connection loss to the reconnect
        self._rng = random.Random()
        self.reconnects = 0
        self.republished = 0  # requests sent again after a reconnect (same transaction)
        self.notified = 0  # reports published (``notify``)
        self.outages_s: list[float] = []  # connection lost -> subscribed again, per reconnect
        # A request published while the daemon is not subscribed would be dropped by the
        # broker: wait for its availability (retained, republished on every reconnect).
        self._online = asyncio.Event()
        self._gone = asyncio.Event()  # its will came and no broker restart explains it

    @property
    def broker_connected(self) -> bool:
        return self._client is not None

    @property
    def daemon_online(self) -> bool:
        """The daemon's availability said online (retained; its will says offline)."""
        return self._online.is_set()

    @contextlib.asynccontextmanager
    async def connected(self) -> AsyncIterator[DaemonClient]:
        """Connected for the block; the first connection must succeed (else its
        ``aiomqtt.MqttError``), a later loss is reconnected in the background."""
        first: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._task = asyncio.create_task(self._run(first), name="sender-mqtt")
        try:
            await first
            yield self
        finally:
            client = self._client
            if client is not None:  # a clean end is not a death: say so before leaving
                with contextlib.suppress(aiomqtt.MqttError):
                    await client.publish(self.availability_topic, OFFLINE, qos=1, retain=True)
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await self._task

    async def _run(self, first: asyncio.Future[None]) -> None:
        failures = 0
        loop = asyncio.get_running_loop()
        lost_at = 0.0
        while True:
            try:
                async with self._new_client() as client:
                    for leaf in ("response/#", "event", "availability", "telemetry"):
                        await client.subscribe(f"{self.root}/{leaf}", qos=1)
                    for leaf in self._subscriptions:
                        await client.subscribe(f"{self.root}/{leaf}", qos=1)
                    await client.publish(self.availability_topic, ONLINE, qos=1, retain=True)
                    self._client = client
                    self._broker_lost.clear()
                    if first.done():
                        self.reconnects += 1
                        self.outages_s.append(round(loop.time() - lost_at, 3))
                        log.info(
                            "broker_reconnected", attempts=failures,
                            down_s=round(loop.time() - lost_at, 3),
                            unanswered=len(self._unanswered),
                        )  # fmt: skip
                        await self._republish(client)
                    else:
                        first.set_result(None)
                    failures = 0
                    await self._pump(client)
            except aiomqtt.MqttError as exc:
                if self._client is not None:
                    lost_at = loop.time()
                self._client = None
                self._broker_lost.set()
                # The broker, not the daemon, went away: the daemon's availability comes
                # again (retained) after the reconnect; pending requests wait for it.
                self._online.clear()
                if not first.done():
                    first.set_exception(exc)  # the caller names the broker it could not reach
                    return
                failures += 1
                delay = backoff_delay_s(
                    failures, initial_s=self.reconnect_initial_s,
                    max_s=self.reconnect_max_s, rng=self._rng,
                )  # fmt: skip
                log.warning("broker_lost", error=str(exc), retry_in_s=round(delay, 3))
                await asyncio.sleep(delay)

    async def _confirm_offline(self) -> None:
        """A broker shutting down publishes every client's will, the daemon's too, and then
        drops us: an offline followed at once by our own disconnection is the broker going
        away (reconnect and go on), not the daemon dying (fail what is pending, hold)."""
        try:
            await asyncio.wait_for(self._broker_lost.wait(), OFFLINE_CONFIRM_S)
        except TimeoutError:
            if not self._online.is_set():
                self._went_offline()
            return
        log.warning("daemon_offline_was_the_broker", note="its will, sent at broker shutdown")

    def _background(self, work: Coroutine[Any, Any, None]) -> None:
        task = asyncio.create_task(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _republish(self, client: aiomqtt.Client) -> None:
        for topic, payload in list(self._unanswered.values()):
            await client.publish(topic, payload, qos=1)
            self.republished += 1

    def on_event(self, handler: Callable[[dict[str, Any]], None]) -> None:
        self._event_handlers.append(handler)

    def on_telemetry(self, handler: Callable[[dict[str, Any]], None]) -> None:
        """Each telemetry point (arc voltage, height, state) as the daemon publishes it."""
        self._telemetry_handlers.append(handler)

    def on_topic(self, leaf: str, handler: Callable[[str, dict[str, Any]], None]) -> None:
        """Another topic under the board's (``sender/request/+``, ``state``): its JSON
        documents with their topic, from the next connection on (call before connecting)."""
        self._subscriptions[leaf] = handler

    async def publish(self, leaf: str, document: dict[str, Any], *, retain: bool = False) -> None:
        """A document of ours under the board's topics (QoS 1); dropped while the broker is
        away: what is published here is a state, and the next one replaces it."""
        client = self._client
        if client is None:
            return
        with contextlib.suppress(aiomqtt.MqttError):
            await client.publish(f"{self.root}/{leaf}", json.dumps(document), qos=1, retain=retain)

    def on_offline(self, handler: Callable[[], None]) -> None:
        """The daemon's availability turned offline (killed, crashed or stopped)."""
        self._offline_handlers.append(handler)

    def _went_offline(self) -> None:
        """Nobody will answer what is pending: fail it now, not after the timeout."""
        self._gone.set()
        for waiter in self._waiting.values():
            if not waiter.done():
                waiter.set_exception(DaemonError("the daemon went offline"))
        for handler in self._offline_handlers:
            handler()

    async def _pump(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            honour_cancellation()  # a republish may have swallowed it (cancellation.py)
            try:
                document = json.loads(bytes(message.payload))
            except ValueError:
                document = None
            if not isinstance(document, dict):
                # A request to us still gets its one answer: an error saying why.
                self._dispatch(message.topic, {INVALID: "the payload is not a JSON object"})
                continue
            if message.topic.matches(f"{self.root}/availability"):
                if document.get("state") == "online":
                    self._gone.clear()
                    if self._unanswered:
                        # The daemon is (back) on the broker: what it may have missed is sent
                        # again; a repeat is answered from its cache, never run twice.
                        await self._republish(client)
                    self._online.set()
                elif self._online.is_set():  # online -> offline: its will, or a clean stop
                    self._online.clear()
                    self._background(self._confirm_offline())
                elif self._waiting:
                    # Offline found after a reconnect (retained) with requests pending: the
                    # daemon died while the broker was away; nobody will answer them.
                    self._background(self._confirm_offline())
                continue
            if message.topic.matches(f"{self.root}/event"):
                for handler in self._event_handlers:
                    handler(document)
                continue
            if message.topic.matches(f"{self.root}/telemetry"):
                for handler in self._telemetry_handlers:
                    handler(document)
                continue
            if self._dispatch(message.topic, document):
                continue
            self.answer(message.topic.value, document)

    def answer(self, _topic: str, document: dict[str, Any]) -> None:
        """A response: to the request waiting for its transaction (``on_topic`` handler for
        another client's responses, as ``sender/response/+``)."""
        transaction = str(document.get("transaction"))
        self._unanswered.pop(transaction, None)
        waiter = self._waiting.pop(transaction, None)
        if waiter is not None and not waiter.done():
            waiter.set_result(document)

    def _dispatch(self, topic: aiomqtt.Topic, document: dict[str, Any]) -> bool:
        for leaf, handler in self._subscriptions.items():
            if topic.matches(f"{self.root}/{leaf}"):
                handler(topic.value, document)
                return True
        return False

    async def _wait_online(self, name: str) -> None:
        """Until the daemon is online; a daemon that died meanwhile fails it at once."""
        if self._online.is_set():
            return
        online = asyncio.ensure_future(self._online.wait())
        gone = asyncio.ensure_future(self._gone.wait())
        try:
            await asyncio.wait({online, gone}, timeout=self.timeout_s,
                               return_when=asyncio.FIRST_COMPLETED)  # fmt: skip
        finally:
            online.cancel()
            gone.cancel()
        if self._online.is_set():
            return
        if self._gone.is_set():
            raise DaemonError(f"{name}: the daemon went offline")
        raise DaemonError(f"{name}: the daemon is not online")

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        """Publish a request, wait for its response; DaemonError on an error response.
        (``name`` is positional-only: a material's fields include a ``name``.)

        A broker restart meanwhile is ridden out: the request is published again, with
        the same transaction, once the connection is back."""
        await self._wait_online(name)
        transaction, future = self._expect_answer()
        topic = f"{self.root}/request/{name}"
        payload = json.dumps({**args, "transaction": transaction})
        self._unanswered[transaction] = (topic, payload)
        try:
            client = self._client
            if client is not None:
                with contextlib.suppress(aiomqtt.MqttError):  # lost: sent again on reconnect
                    await client.publish(topic, payload, qos=1)
            response = await asyncio.wait_for(future, self.timeout_s)
        except TimeoutError:
            raise DaemonError(f"{name}: no response within {self.timeout_s:.0f} s") from None
        finally:
            self._waiting.pop(transaction, None)
            self._unanswered.pop(transaction, None)
        return response_data(response)

    async def request_to(self, role: str, name: str, /, **args: Any) -> dict[str, Any]:
        """A request to another client of the board (``sender``): published once, answered
        on ``<role>/response/<name>`` (subscribe it with ``on_topic(..., self.answer)``);
        DaemonError on an error response or none within the timeout."""
        client = self._client
        if client is None:
            raise DaemonError(f"{name}: not connected to the broker")
        transaction, future = self._expect_answer()
        payload = json.dumps({**args, "transaction": transaction})
        try:
            await client.publish(f"{self.root}/{role}/request/{name}", payload, qos=1)
            response = await asyncio.wait_for(future, self.timeout_s)
        except TimeoutError:
            raise DaemonError(f"{name}: the {role} did not answer within "
                              f"{self.timeout_s:.0f} s") from None  # fmt: skip
        except aiomqtt.MqttError as exc:
            raise DaemonError(f"{name}: {exc}") from None
        finally:
            self._waiting.pop(transaction, None)
        return response_data(response)

    def _expect_answer(self) -> tuple[str, asyncio.Future[dict[str, Any]]]:
        """A new transaction, unique to this run, and the future its response resolves."""
        transaction = f"{self._run_id}-{next(self._ids)}"
        future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._waiting[transaction] = future
        return transaction, future

    async def notify(self, name: str, /, **args: Any) -> None:
        """A report, not a command: published at QoS 0 without a transaction, its answer not
        awaited, never re-sent (a stale ``motion`` speed is worse than none: the daemon
        counts a missing one as unknown and holds the THC)."""
        client = self._client
        if client is None or not self._online.is_set():
            return
        with contextlib.suppress(aiomqtt.MqttError):
            await client.publish(f"{self.root}/request/{name}", json.dumps(args), qos=0)
        self.notified += 1

    async def gcode(
        self,
        line: str,
        *,
        line_number: int | None = None,
        xy: tuple[float, float] | None = None,
        dialect: str | None = None,
    ) -> dict[str, Any]:
        return await self.request("gcode", **gcode_args(line, line_number, xy, dialect))


def gcode_args(
    line: str, line_number: int | None, xy: tuple[float, float] | None, dialect: str | None
) -> dict[str, Any]:
    """A ``gcode`` request's arguments: the line, and what is known of it."""
    args: dict[str, Any] = {"line": line}
    if dialect is not None:
        args["dialect"] = dialect
    if line_number is not None:
        args["line_number"] = line_number
    if xy is not None:
        args["x"], args["y"] = xy
    return args


def response_data(response: dict[str, Any]) -> dict[str, Any]:
    """A response's data; DaemonError with its error when it is not ok."""
    if response.get("status") != "ok":
        raise DaemonError(str(response.get("error") or "error"))
    data: dict[str, Any] = response.get("data") or {}
    return data
