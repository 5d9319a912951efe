"""The panel's MQTT side: what the daemon and the sender publish, kept as one live view and
fanned out to every open page; controls sent as requests with transactions.

The panel is an MQTT client like the sender, so the daemon's hot path never serves HTTP
and a hung browser cannot slow the THC."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Mapping
from typing import Any

import structlog

from dthc_tools.sender.daemon_client import DaemonClient

from .controls import ControlError, LiveView, enabled, route
from .history import CutHistory, CutRecorder
from .labels import describe_params

__all__ = ["PanelHub"]

log = structlog.get_logger("dthc_tools.panel")

VIEW_PERIOD_S = 0.2  # the link state is looked at this often; the rest pushes on change
PAGE_QUEUE = 256  # messages an open page may fall behind by before the oldest are dropped
# The state's measurements, which change at every poll during a cut: pages get them from the
# telemetry (10/s), so a view is pushed when something else changes (a view is a full redraw).
MEASURED = frozenset({
    "voltage_v", "target_v", "slow_target_v", "z_mm", "height_mm", "work_z_mm", "locks",
})  # fmt: skip


class PanelHub:
    def __init__(self, client: DaemonClient, history: CutHistory) -> None:
        self.client = client
        self.history = history
        self.recorder = CutRecorder(first_number=history.next_number)
        self.view = LiveView()
        self._pages: set[asyncio.Queue[str]] = set()
        self._last_view = ""
        self.path: dict[str, Any] | None = None  # the running program's toolpath (sender/path)
        client.on_topic("state", self._on_state)
        client.on_topic("board", self._on_board)
        client.on_topic("materials", self._on_materials)
        client.on_topic("sender/availability", self._on_sender)
        client.on_topic("sender/progress", self._on_progress)
        client.on_topic("sender/path", self._on_path)
        client.on_topic("sender/response/+", client.answer)
        client.on_telemetry(self._on_telemetry)
        client.on_event(self._on_event)

    # --- what arrives -------------------------------------------------------------------

    def _on_state(self, _topic: str, document: dict[str, Any]) -> None:
        self.view.state = document
        params = document.get("params")
        if isinstance(params, dict):
            self.recorder.set_context(cut_height_mm=params.get("cut_height_mm"))
        self._push_view()

    def _on_board(self, _topic: str, document: dict[str, Any]) -> None:
        self.view.board = str(document.get("state", "unknown"))
        self._push_view()

    def _on_materials(self, _topic: str, document: dict[str, Any]) -> None:
        self.view.materials = document
        self.recorder.set_context(material=document.get("selected"))
        self._push_view()

    def _on_sender(self, _topic: str, document: dict[str, Any]) -> None:
        self.view.sender = document.get("state") == "online"
        self._push_view()

    def _on_progress(self, _topic: str, document: dict[str, Any]) -> None:
        self.view.progress = document
        if self.recorder.current is None:
            self.recorder.set_context(line=document.get("line"), program=document.get("program"))
        self._push_view()

    def _on_path(self, _topic: str, document: dict[str, Any]) -> None:
        """A program's toolpath, once per program start: the preview draws it."""
        self.path = document if isinstance(document.get("moves"), list) else None
        self._push("path", self.path or {})

    def _on_telemetry(self, point: dict[str, Any]) -> None:
        self.recorder.on_telemetry(point)
        self._push("telemetry", point)

    def _on_event(self, event: dict[str, Any]) -> None:
        self._push("event", event)
        if event.get("type") != "sequence":
            return
        record = self.recorder.on_sequence(event)
        if record is not None:
            self.history.add(record)
            log.info("cut_recorded", number=record.number, error=record.error)
            self._push("cut", record.summary())

    # --- what the pages get -------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        view = self.view
        return {
            "broker": view.broker, "daemon": view.daemon, "board": view.board,
            "state": _shown_state(view.state), "sender": view.sender,
            "progress": view.progress if view.sender else None,
            "materials": view.materials, "controls": enabled(view),
            "params_shown": describe_params((view.state or {}).get("params")),
        }  # fmt: skip

    def _push_view(self) -> None:
        document = self.snapshot()
        text = json.dumps(document, sort_keys=True)
        if text != self._last_view:
            self._last_view = text
            self._push("view", document)

    def _push(self, kind: str, document: Mapping[str, Any]) -> None:
        message = json.dumps({"kind": kind, "data": document})
        for queue in self._pages:
            if queue.full():
                queue.get_nowait()  # a page that cannot keep up loses the oldest, not the hub
            queue.put_nowait(message)

    @contextlib.asynccontextmanager
    async def page(self) -> AsyncIterator[asyncio.Queue[str]]:
        """An open page's stream: the view now, then every message as it comes."""
        queue: asyncio.Queue[str] = asyncio.Queue(PAGE_QUEUE)
        queue.put_nowait(json.dumps({"kind": "view", "data": self.snapshot()}))
        if self.path is not None:
            queue.put_nowait(json.dumps({"kind": "path", "data": self.path}))
        self._pages.add(queue)
        try:
            yield queue
        finally:
            self._pages.discard(queue)

    def close_pages(self) -> None:
        """Shutting down: every open stream ends (the page's EventSource reconnects)."""
        for queue in self._pages:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait("")

    async def watch_links(self) -> None:
        """Until cancelled: the broker and daemon links, which change without a message."""
        while True:
            self.view.broker = self.client.broker_connected
            self.view.daemon = self.client.daemon_online
            if not self.view.broker:
                self.view.sender = False  # its retained availability comes back with us
            self._push_view()
            await asyncio.sleep(VIEW_PERIOD_S)

    # --- controls -----------------------------------------------------------------------

    async def control(self, name: str, args: Mapping[str, Any]) -> dict[str, Any]:
        """Press a control: the answer's data, or ControlError/DaemonError with the reason."""
        role, request, request_args = route(name, args, self.view)
        log.info("control", name=name, role=role, request=request)
        if role == "sender":
            return await self.client.request_to("sender", request, **request_args)
        if not self.client.daemon_online:
            raise ControlError(f"{name}: the daemon is offline")
        return await self.client.request(request, **request_args)


def _shown_state(state: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The daemon's state as the view carries it: without the measurements (MEASURED), and
    the consumables' arc-on time in whole seconds (it grows at every poll while the arc
    burns; the page shows seconds)."""
    if state is None:
        return None
    shown = {key: value for key, value in state.items() if key not in MEASURED}
    consumables = shown.get("consumables")
    if isinstance(consumables, Mapping) and isinstance(consumables.get("arc_on_s"), int | float):
        shown["consumables"] = {**consumables, "arc_on_s": int(consumables["arc_on_s"])}
    return shown
