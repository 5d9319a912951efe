"""A fake ControllerPort: records every call, M3 takes a while, G4 P<s> dwells, events queue."""

from __future__ import annotations

import asyncio
import re
from collections.abc import AsyncIterator, Mapping

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.events import ControllerEvent
from dthc_bridge.port import CommandResult

__all__ = ["FakeController"]

_DWELL = re.compile(r"(?i)^G0*4\s*P\s*([0-9]*\.?[0-9]+)")


class FakeController:
    def __init__(self, *, m3_delay_s: float = 0.3) -> None:
        self.m3_delay_s = m3_delay_s
        self.gcode_calls: list[tuple[str, int | None, tuple[float, float] | None]] = []
        self.request_calls: list[tuple[str, dict[str, object]]] = []
        self.sender_lost_calls: list[str] = []
        self.cancelled: list[str] = []
        self.finished: list[str] = []
        self.state: dict[str, object] = {"state": "idle", "armed": False, "line": None}
        self.link: tuple[str, str] = ("online", "handshake complete")
        self.diag: dict[str, object] = {"link": {"requests": 0, "timeouts": 0}}
        self.point: dict[str, object] | None = None
        self._events: asyncio.Queue[ControllerEvent] = asyncio.Queue()
        self.called = asyncio.Event()  # set on every execute_* call
        self.dialects: list[Dialect | None] = []
        self._lost = asyncio.Event()

    # --- ControllerPort --------------------------------------------------------------------

    async def execute_gcode(
        self,
        line: str,
        *,
        line_number: int | None,
        xy_mm: tuple[float, float] | None,
        dialect: Dialect | None = None,
    ) -> CommandResult:
        self.gcode_calls.append((line, line_number, xy_mm))
        self.dialects.append(dialect)
        self.called.set()
        try:
            if line.strip().upper().startswith("M3"):
                await asyncio.sleep(self.m3_delay_s)
            elif match := _DWELL.match(line.strip()):
                await asyncio.sleep(float(match.group(1)))
        except asyncio.CancelledError:
            self.cancelled.append(line)
            raise
        self.finished.append(line)
        if line.strip().upper().startswith("BAD"):
            return CommandResult(False, error=f"unknown word in {line!r}")
        self.state = {**self.state, "line": line, "line_number": line_number}
        return CommandResult(True, {"line": line, "xy_mm": list(xy_mm) if xy_mm else None})

    async def execute_request(self, name: str, args: Mapping[str, object]) -> CommandResult:
        self.request_calls.append((name, dict(args)))
        self.called.set()
        if name == "status":
            return CommandResult(True, self.snapshot())
        if name == "echo":
            return CommandResult(True, dict(args))
        if name == "explode":
            raise RuntimeError("boom")
        return CommandResult(False, error=f"unknown request {name!r}")

    async def sender_lost(self, reason: str) -> None:
        self.sender_lost_calls.append(reason)
        self.state = {**self.state, "state": "aborted"}
        self._lost.set()

    def snapshot(self) -> dict[str, object]:
        if self.state.get("explode"):
            raise RuntimeError("snapshot failed")
        return dict(self.state)

    def link_state(self) -> tuple[str, str]:
        return self.link

    def materials(self) -> dict[str, object]:
        return {"selected": 0, "materials": []}

    def diagnostics(self) -> dict[str, object]:
        return dict(self.diag)

    def telemetry(self) -> dict[str, object] | None:
        return self.point

    async def subscribe_events(self) -> AsyncIterator[ControllerEvent]:
        while True:
            yield await self._events.get()

    # --- test controls ---------------------------------------------------------------------

    def emit(self, event: ControllerEvent) -> None:
        self._events.put_nowait(event)

    async def wait_sender_lost(self, count: int = 1, timeout_s: float = 5.0) -> None:
        async with asyncio.timeout(timeout_s):
            while len(self.sender_lost_calls) < count:
                self._lost.clear()
                await self._lost.wait()
