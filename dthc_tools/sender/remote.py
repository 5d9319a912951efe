"""The operator's controls over MQTT: what the console's keys do, for a panel on the network.

The sender owns the motion, so pause, cycle start and stop go through it, not straight to
the daemon: a pause is a feed hold *and* a THC hold, a stop holds the motion *and* ends the
cut. The sender answers on its own topics, next to the daemon's:

    <base>/<board>/sender/request/<name>    {"transaction": ..., ...args}   (QoS 1, never retained)
    <base>/<board>/sender/response/<name>   {"status": "ok"|"error", "data", "error", "transaction"}
    <base>/<board>/sender/progress          retained: line n/N, cut n/m, waiting, paused, error
    <base>/<board>/sender/availability      retained: {"state": "online"}; its will says offline

Names: ``cycle_start``, ``pause``, ``stop``, ``feed_override`` {step: "+10"|"-10"|"reset"};
after an error (the program paused where the torch stopped, see :mod:`.recovery`):
``path_move`` {mm, feed_mm_min?}, ``recovery_offset`` {x_mm, y_mm, feed_mm_min?},
``resume`` (here), ``restart`` (from the cut's start), ``quit``; and forwarded to the
daemon as they are: ``torch_up``, ``torch_down``, ``height_override``, ``thc``, ``rearm``,
and, while no program runs or it is paused, ``ohmic_test``, ``probe_test``, ``jog_z``.
``sender/path`` (retained) is the program's XY path for a panel's preview, once per start.
Every request gets exactly one response, an unknown name or argument an error naming it.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
from collections.abc import Awaitable, Callable
from dataclasses import asdict
from pathlib import PurePosixPath
from typing import Any

import structlog

from dthc_bridge.mqtt.cancellation import honour_cancellation

from .backend import BackendError
from .console import PAUSED_ACTIONS, OperatorConsole
from .daemon_client import INVALID, DaemonClient, DaemonError
from .sender import Sender

__all__ = ["PROGRESS_PERIOD_S", "OperatorRemote"]

log = structlog.get_logger("dthc_tools.sender.remote")

PROGRESS_PERIOD_S = 0.2
"""Progress goes out on change, at most this often: a program line at cutting feed takes
longer than this, and a panel redraws at about this rate."""
FEED_STEPS = ("+10", "-10", "reset")
FORWARDED = ("torch_up", "torch_down", "height_override", "thc", "rearm")
"""The daemon's requests a panel sends through the sender (dthc_bridge/mqtt/roles.py)."""
IDLE_TOOLS = ("ohmic_test", "probe_test", "jog_z")
"""Forwarded too, but only while no program runs (or it is paused): they move Z or
energise the torch's ohmic circuit, which a running program owns."""


class OperatorRemote:
    """Serves ``sender/request/+`` and publishes ``sender/progress`` for one sender."""

    def __init__(
        self,
        sender: Sender,
        client: DaemonClient,
        *,
        program: str = "",
        console: OperatorConsole | None = None,
    ) -> None:
        self.sender = sender
        self.console = console
        self.client = client
        self.program = PurePosixPath(program).name
        self._tasks: set[asyncio.Task[None]] = set()
        self._actions: dict[str, Callable[[dict[str, Any]], Awaitable[None]]] = {
            "cycle_start": self._cycle_start,
            "pause": lambda _args: sender.pause(),
            "stop": lambda _args: sender.stop(),
            "feed_override": self._feed_override,
        }
        for name in PAUSED_ACTIONS:
            self._actions[name] = functools.partial(self._paused_action, name)
        # The panel's torch and height controls: the broker lets only the sender's user send
        # the daemon requests that can light the torch or move Z, so the panel's go through
        # here (the daemon checks the arguments and the state).
        for name in FORWARDED:
            self._actions[name] = functools.partial(self._forward, name)
        for name in IDLE_TOOLS:
            self._actions[name] = functools.partial(self._idle_tool, name)
        client.on_topic("sender/request/+", self._on_request)

    def _on_request(self, topic: str, document: dict[str, Any]) -> None:
        name = topic.rsplit("/", 1)[-1]
        task = asyncio.ensure_future(self._serve(name, document))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _serve(self, name: str, document: dict[str, Any]) -> None:
        transaction = document.get("transaction")
        args = {k: v for k, v in document.items() if k != "transaction"}
        response: dict[str, Any] = {"status": "ok", "data": {}, "transaction": transaction}
        action = self._actions.get(name)
        try:
            if INVALID in document:
                raise BackendError(f"{name}: {document[INVALID]}")
            if action is None:
                raise BackendError(f"{name}: unknown sender request")
            await action(args)
        except (BackendError, DaemonError) as exc:
            response.update(status="error", error=str(exc))
        log.info("operator_request", name=name, status=response["status"],
                 error=response.get("error"))  # fmt: skip
        await self.client.publish(f"sender/response/{name}", response)

    async def _forward(self, name: str, args: dict[str, Any]) -> None:
        await self.client.request(name, **args)

    async def _idle_tool(self, name: str, args: dict[str, Any]) -> None:
        progress = self.sender.progress
        if progress.running and not progress.operator_paused:
            raise BackendError(f"{name}: the program is running (pause or stop it first)")
        await self.client.request(name, **args)

    async def _cycle_start(self, _args: dict[str, Any]) -> None:
        """Cycle start: the console's (a paused program resumes where the torch stands),
        else the sender's (an S1 stop, a pause with nothing lit)."""
        if self.console is not None:
            await self.console.cycle_start()
        else:
            await self.sender.cycle_start()

    async def _paused_action(self, name: str, args: dict[str, Any]) -> None:
        if self.console is None:
            raise BackendError(f"{name}: this sender has no operator console")
        await self.console.act(name, **args)

    async def _feed_override(self, args: dict[str, Any]) -> None:
        step = args.get("step")
        unknown = sorted(set(args) - {"step"})
        if unknown:
            raise BackendError(f"feed_override {unknown[0]}: unknown argument")
        if step not in FEED_STEPS:
            raise BackendError(f"feed_override step: {step!r} is not one of {FEED_STEPS}")
        self.sender.feed_override(str(step))

    def progress(self) -> dict[str, Any]:
        report = self.sender.report
        return {
            **asdict(self.sender.progress),
            "program": self.program,
            "error": report.error,
            "error_line": report.error_line,
            "restart_line": report.restart_line,
        }

    async def publish_progress(self) -> None:
        """Until cancelled: the progress whenever it changed, at most every PROGRESS_PERIOD_S;
        the last one (program ended) on the way out."""
        last = ""
        drawn: object = None  # the path last published (one per program start)
        try:
            while True:
                honour_cancellation()  # a QoS 1 publish may swallow it (cancellation.py)
                path = self.sender.path
                if path is not None and path is not drawn:
                    await self.client.publish(
                        "sender/path", path.document(self.program), retain=True
                    )
                    drawn = path
                document = self.progress()
                text = json.dumps(document, sort_keys=True)
                if text != last:
                    await self.client.publish("sender/progress", document, retain=True)
                    last = text
                await asyncio.sleep(PROGRESS_PERIOD_S)
        finally:
            with contextlib.suppress(Exception):
                await asyncio.shield(
                    self.client.publish("sender/progress", self.progress(), retain=True)
                )
