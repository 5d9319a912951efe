"""The sender's controls over MQTT (a panel's cycle start, pause, stop): every request gets
exactly one response on ``sender/response/<name>``; the progress goes out retained."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any, cast

import pytest

from dthc_tools.sender import DaemonClient, Sender
from dthc_tools.sender.backend import BackendError
from dthc_tools.sender.daemon_client import INVALID
from dthc_tools.sender.remote import OperatorRemote
from tests.sender.test_operator import S1_PROGRAM, S1Daemon, waiting
from tests.sender.test_sender_lines import FakeBackend


class Broker(S1Daemon):
    """The fake daemon, plus what the remote needs of the client: topics and publishing."""

    def __init__(self) -> None:
        super().__init__()
        self.topics: dict[str, Callable[[str, dict[str, Any]], None]] = {}
        self.published: list[tuple[str, dict[str, Any], bool]] = []

    def on_topic(self, leaf: str, handler: Callable[[str, dict[str, Any]], None]) -> None:
        self.topics[leaf] = handler

    async def publish(self, leaf: str, document: dict[str, Any], *, retain: bool = False) -> None:
        self.published.append((leaf, document, retain))

    async def press(self, name: str, document: dict[str, Any]) -> dict[str, Any]:
        """Deliver a request as the broker would; the one response it got."""
        before = len(self.published)
        self.topics["sender/request/+"](f"dthc/t1/sender/request/{name}", document)
        for _ in range(200):
            answers = [p for p in self.published[before:] if p[0].startswith("sender/response/")]
            if answers:
                await asyncio.sleep(0.02)  # a second answer would show up by now
                answers = [p for p in self.published[before:]
                           if p[0].startswith("sender/response/")]  # fmt: skip
                assert len(answers) == 1, answers
                leaf, response, retained = answers[0]
                assert leaf == f"sender/response/{name}"
                assert not retained
                return response
            await asyncio.sleep(0.01)
        raise AssertionError(f"no response to {name}")


def remote_for(broker: Broker) -> tuple[Sender, OperatorRemote]:
    sender = Sender(cast(DaemonClient, broker), FakeBackend())
    return sender, OperatorRemote(sender, cast(DaemonClient, broker), program="/jobs/s1.nc")


async def test_a_panels_cycle_start_continues_an_s1_stop_and_is_answered_once() -> None:
    broker = Broker()
    sender, _ = remote_for(broker)
    job = asyncio.create_task(sender.run(S1_PROGRAM))
    await waiting(sender)
    response = await broker.press("cycle_start", {"transaction": "p-1"})
    assert response == {"status": "ok", "data": {}, "transaction": "p-1"}
    await waiting(sender)  # the second cut's stop
    await broker.press("cycle_start", {"transaction": "p-2"})
    report = await asyncio.wait_for(job, 5.0)
    assert report.ok, report.error
    assert report.cycle_starts == [5, 9]


@pytest.mark.parametrize(
    ("name", "document", "error"),
    [
        ("cycle_start", {}, "nothing to start (no program runs)"),
        ("launch", {}, "launch: unknown sender request"),
        ("feed_override", {"step": "+50"}, "feed_override step: '+50' is not one of"),
        ("feed_override", {"step": "+10", "x": 1}, "feed_override x: unknown argument"),
        ("pause", {INVALID: "the payload is not a JSON object"},
         "pause: the payload is not a JSON object"),
    ],
)  # fmt: skip
async def test_a_request_the_sender_cannot_do_gets_its_reason(
    name: str, document: dict[str, Any], error: str
) -> None:
    broker = Broker()
    remote_for(broker)
    response = await broker.press(name, {**document, "transaction": 9})
    assert response["status"] == "error"
    assert response["transaction"] == 9
    assert error in response["error"]


async def test_cycle_start_with_nothing_waiting_is_refused_not_ignored() -> None:
    sender, _ = remote_for(Broker())
    sender.progress.running = True
    with pytest.raises(BackendError, match="nothing waits for cycle start"):
        await sender.cycle_start()


async def test_progress_is_published_retained_on_change_and_at_the_end() -> None:
    broker = Broker()
    sender, remote = remote_for(broker)
    publishing = asyncio.create_task(remote.publish_progress())
    await asyncio.sleep(0.05)
    sender.progress.line, sender.progress.total_lines = 4, 12
    await asyncio.sleep(0.3)
    publishing.cancel()
    with pytest.raises(asyncio.CancelledError):
        await publishing
    progress = [doc for leaf, doc, retain in broker.published if leaf == "sender/progress"]
    assert all(retain for leaf, _, retain in broker.published if leaf == "sender/progress")
    assert progress[0]["line"] == 0
    assert progress[0]["program"] == "s1.nc"  # the name, not the shop PC's path
    assert progress[1]["line"] == 4
    assert len(progress) == 3  # the first, the change, the last on the way out


async def test_paused_motion_requests_go_to_the_console_and_answer_its_reason() -> None:
    """A panel's paused motion: the console does it (once the program has stopped); its
    refusal is the response's error."""
    from dthc_tools.sender.console import OperatorConsole

    broker = Broker()
    sender = Sender(cast(DaemonClient, broker), FakeBackend())
    console = OperatorConsole(sender, interactive=False, wait_operator=True)
    OperatorRemote(sender, cast(DaemonClient, broker), console=console)
    refused = await broker.press("path_move", {"mm": -20, "transaction": 1})
    assert refused["error"] == "path_move: no program is paused"
    sender.progress.running = True
    refused = await broker.press("resume", {"transaction": 2})
    assert refused["error"] == "resume: the program is running (pause it, or stop it)"
    unknown = await broker.press("jump", {"transaction": 3})
    assert unknown["error"] == "jump: unknown sender request"


@pytest.mark.parametrize(
    ("name", "args"),
    [("torch_up", {"volts": 1.0}), ("torch_down", {"volts": 1.0}),
     ("height_override", {"mm": -0.1}), ("thc", {"on": False}), ("rearm", {})],
)  # fmt: skip
async def test_a_panels_torch_and_height_controls_are_forwarded_to_the_daemon_once(
    name: str, args: dict[str, Any]
) -> None:
    """The broker lets only the sender's user send the daemon requests that can light the
    torch or move Z; the panel's go through the sender, which sends each once, as given."""
    broker = Broker()
    remote_for(broker)
    response = await broker.press(name, {**args, "transaction": "p-7"})
    assert response == {"status": "ok", "data": {}, "transaction": "p-7"}
    assert broker.args == [(name, args)]


class SwallowingBroker(Broker):
    """A QoS 1 publish that returns as if done when cancelled (3.11's wait_for, gh-86296)."""

    async def publish(self, leaf: str, document: dict[str, Any], *, retain: bool = False) -> None:
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.sleep(0.3)
        self.published.append((leaf, document, retain))


async def test_the_progress_loop_stops_even_when_a_publish_swallows_its_cancellation() -> None:
    """Else ``dthc-bridge send`` never exits after its program (the loop runs on)."""
    broker = SwallowingBroker()
    sender, remote = remote_for(broker)
    publishing = asyncio.create_task(remote.publish_progress())
    await asyncio.sleep(0.1)  # inside the first publish
    publishing.cancel()
    for _ in range(10):
        sender.progress.line += 1  # a change: a loop running on would publish again
        await asyncio.sleep(0.1)
    assert publishing.done()
    assert len(broker.published) <= 2  # the one it was in, and the last on the way out
