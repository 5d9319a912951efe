"""A G-code program run end to end in simulated time: ``dthc-bridge demo --program`` with the
broker and the processes taken out, so every program can run in every dialect in a test.

The parts are the real ones, in one process on one ``looptime`` loop:

* the reference sender (:class:`~dthc_tools.sender.Sender`, its own code: planning, dialect
  detection, the order of daemon lines and motion, pauses, cycle start at G200 S1);
* the daemon's controller service, built from a ``[controller]`` section as ``dthc-bridge
  run`` builds it (:class:`~.closed_loop.ClosedLoop`), over the wire protocol to the mock's
  :class:`~mock_device.sim.SimulatedBoard` (firmware, arc, plate, torch, gantry);
* between them, the gateway's own request decoding, request-to-controller mapping and
  response encoding (:func:`dthc_bridge.mqtt.payloads.decode_request`,
  :func:`dthc_bridge.requests.execute`), with its request deadline.

What it does not model: the broker (a lost connection, QoS, the sender's will, retained
state), MQTT's delivery order between an event and a response, the daemon's and the mock's
start-up and shut-down as processes. Those are what the real-time stack tests cover.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from dthc_bridge.config import ControllerSettings
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.events import ControllerEvent
from dthc_bridge.mqtt.payloads import (
    RequestRefused,
    decode_request,
    encode_json,
    response_payload,
)
from dthc_bridge.mqtt.settings import MqttSettings
from dthc_bridge.port import CommandResult
from dthc_bridge.requests import execute
from dthc_bridge.service import ControllerService
from mock_device.plant.gantry import Gantry, GcodeError

from ..demo.stack import StackResult
from ..sender import Sender, SendReport
from ..sender.backend import BackendError, MotionListener, Where
from ..sender.daemon_client import gcode_args, response_data
from .closed_loop import ClosedLoop

__all__ = ["GantryBackend", "InProcessDaemon", "run_program"]

POLL_S = 0.005  # the gantry steps with the board's sample batches


class InProcessDaemon:
    """The sender's daemon seam served by the controller service in this process: each
    request is encoded, decoded and answered as the MQTT gateway does it."""

    def __init__(self, service: ControllerService, mqtt: MqttSettings | None = None) -> None:
        self.service = service
        self.mqtt = mqtt or MqttSettings()
        self.events: list[dict[str, Any]] = []  # as the demo's observer records them
        self._event_handlers: list[Callable[[dict[str, Any]], None]] = []
        self._telemetry_handlers: list[Callable[[dict[str, Any]], None]] = []
        self._notes: set[asyncio.Task[CommandResult]] = set()
        service.add_event_listener(self._on_event)

    def _on_event(self, event: ControllerEvent) -> None:
        document: dict[str, Any] = json.loads(encode_json(event.as_payload()))
        self.events.append({"topic": "event", **document})
        for handler in self._event_handlers:
            handler(document)

    def telemetry(self, point: dict[str, Any]) -> None:
        for handler in self._telemetry_handlers:
            handler(point)

    def on_event(self, handler: Callable[[dict[str, Any]], None]) -> None:
        self._event_handlers.append(handler)

    def on_telemetry(self, handler: Callable[[dict[str, Any]], None]) -> None:
        self._telemetry_handlers.append(handler)

    def on_offline(self, handler: Callable[[], None]) -> None:
        """The daemon is this process: it does not go offline under the sender."""

    async def _answer(self, name: str, args: Mapping[str, Any]) -> CommandResult:
        try:
            request = decode_request(
                name, json.dumps(args).encode(), max_payload_bytes=self.mqtt.max_payload_bytes
            )
        except RequestRefused as exc:
            return CommandResult(False, error=exc.reason)
        try:
            async with asyncio.timeout(self.mqtt.request_deadline_s):
                return await execute(self.service, name, request)
        except TimeoutError:
            return CommandResult(False, error="timeout")

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        result = await self._answer(name, args)
        return response_data(json.loads(response_payload(result, None)))

    async def notify(self, name: str, /, **args: Any) -> None:
        task = asyncio.ensure_future(self._answer(name, args))  # its answer is not awaited
        self._notes.add(task)
        task.add_done_callback(self._notes.discard)

    async def gcode(
        self,
        line: str,
        *,
        line_number: int | None = None,
        xy: tuple[float, float] | None = None,
        dialect: str | None = None,
    ) -> dict[str, Any]:
        return await self.request("gcode", **gcode_args(line, line_number, xy, dialect))


class GantryBackend:
    """The motion backend on the simulated board's gantry, as the mock's gantry port
    (``dthc-mock --gantry-listen``) serves it to :class:`~..sender.SimGantryBackend`."""

    def __init__(self, gantry: Gantry) -> None:
        self.gantry = gantry

    async def queue(self, line: str, *, source_line: int | None = None) -> None:
        try:
            self.gantry.feed_line(line)
        except GcodeError as exc:
            raise BackendError(str(exc), line_number=source_line) from None

    def add_motion_listener(self, listener: MotionListener) -> None:
        """Nothing to report: the board measures the gantry's XY speed itself."""

    async def wait_idle(self) -> tuple[float, float]:
        while not self.gantry.idle:  # noqa: ASYNC110 - no event to wait on in the plant
            await asyncio.sleep(POLL_S)
        return self.gantry.x_mm, self.gantry.y_mm

    async def hold(self) -> None:
        self.gantry.hold()

    async def clear(self) -> None:
        self.gantry.clear()

    async def resume(self) -> None:
        self.gantry.resume()

    async def where(self) -> Where | None:
        g = self.gantry
        return Where(g.x_mm, g.y_mm, g.speed_mm_s, g.held)

    async def release_stale_hold(self) -> None:
        self.gantry.clear()
        self.gantry.resume()

    async def close(self) -> None:
        """Nothing to close."""


def run_program(
    lines: Sequence[str],
    workdir: Path,
    *,
    settings: ControllerSettings | None = None,
    dialect: Dialect | None = None,
    codes: Mapping[str, str] | None = None,
    scenario: str = "flat_clean",
    seed: int = 1,
    telemetry_hz: float = 50.0,
    max_s: float = 3600.0,
) -> StackResult:
    """``lines`` sent as ``dthc-bridge demo --program`` sends them (cycle start pressed at
    each G200 S1 stop), ``max_s`` of board time at most; the result has the stack's shape,
    for :func:`~..demo.summary.summarize`. The plant's record goes to ``workdir``."""
    with ClosedLoop(scenario, seed, settings=settings, holds_on_pause=False) as loop:
        daemon = InProcessDaemon(loop.service)
        telemetry: list[dict[str, Any]] = []

        async def sample() -> None:
            last: dict[str, object] | None = None
            while True:
                point = loop.service.telemetry()
                if point is not None and point != last:
                    document: dict[str, Any] = json.loads(encode_json(point))
                    telemetry.append(document)
                    daemon.telemetry(document)
                    last = point
                await asyncio.sleep(1.0 / telemetry_hz)

        async def send() -> SendReport:
            sampler = asyncio.ensure_future(sample())
            try:
                sender = Sender(daemon, GantryBackend(loop.plant.gantry), auto_cycle_start=True)
                return await sender.run(list(lines), dialect=dialect, codes=codes)
            finally:
                sampler.cancel()

        report = loop.complete(send(), max_s)
        loop.run_until(lambda: False, 0.3)  # the last reports land, as the demo waits
        truth = loop.plant.truth
        workdir.mkdir(parents=True, exist_ok=True)
        truth_path = workdir / "truth.jsonl"
        truth.write_jsonl(truth_path)
        mock_exit = {
            "cuts": [dataclasses.asdict(cut) for cut in truth.summary().cuts],
            "violations": truth.violations,
            "torch_on": loop.board.firmware.torch_on,
        }
        return StackResult(report, mock_exit, None, 0.0, telemetry, daemon.events, truth_path)
