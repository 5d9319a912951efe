"""ControllerService: the plasma controller driving the board, as the MQTT layer sees it.

The pure :class:`~.controller.plasma.PlasmaController` decides; this class does the I/O:
board telemetry goes into the cut sequence in the link's receive callback (so the THC's
Z velocity leaves in the same callback as the samples arrived: the hot path), board
requests run in order on one worker task, completions come back as events, and the
sequence's replies answer the sender's pending M3/M5.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from typing import Any

import structlog

import firmware_protocol as fp

from .board import SENSOR_FLOAT, SENSOR_OHMIC, BoardClient, Telemetry
from .controller import actions as act
from .controller.commands import Command, CommandError
from .controller.gcode import parse_line, parse_request
from .controller.plasma import PlasmaController
from .controller.sequence import CutSequence, with_board_limits
from .link import LinkError, LinkState, LinkSupervisor
from .mqtt.port import CommandResult

__all__ = ["ControllerService", "feed_samples"]

log = structlog.get_logger("dthc_bridge.service")

_FEED = re.compile(r"(?i)\bF\s*([0-9]*\.?[0-9]+)")
_CUTTING_MOTION = re.compile(r"(?i)\bG0*[123]\b")
EVENT_QUEUE_SIZE = 256


class ControllerService:
    def __init__(
        self,
        controller: PlasmaController,
        supervisor: LinkSupervisor,
        client: BoardClient,
        *,
        command_timeout_s: float = 60.0,
        board_setup: Callable[[BoardClient], Awaitable[None]] | None = None,
    ) -> None:
        self.controller = controller
        self.seq = controller.seq
        self.supervisor = supervisor
        self.client = client
        self.command_timeout_s = command_timeout_s
        self.board_setup = board_setup
        self._loop = asyncio.get_running_loop()
        self._clock0 = time.monotonic()
        self._work: asyncio.Queue[act.BoardAction] = asyncio.Queue()
        self._reply: asyncio.Future[act.CommandReply] | None = None
        self._command_lock = asyncio.Lock()
        self._events: list[asyncio.Queue[dict[str, object]]] = []
        self._background: set[asyncio.Task[None]] = set()
        self._requested_feed_mm_s: float | None = None
        self._last_batch: tuple[float, float, float | None] | None = None  # t, z, xy speed
        self._link: tuple[str, str] = (str(supervisor.state), "")
        self._board_limits_set = False
        client.add_listener(self._on_board)
        self._previous_on_state = supervisor.on_state
        supervisor.on_state = self._on_link_state

    @property
    def now(self) -> float:
        return time.monotonic() - self._clock0

    # --- the ControllerPort seam -----------------------------------------------------------

    async def execute_gcode(
        self, line: str, *, line_number: int | None = None, xy_mm: tuple[float, float] | None = None
    ) -> CommandResult:
        try:
            parsed = parse_line(line, line_number=line_number)
        except CommandError as exc:
            return CommandResult(False, error=str(exc))
        if parsed.motion:
            self._note_feed(parsed.motion)
        data: dict[str, object] = {"commands": [type(c).__name__ for c in parsed.commands]}
        for command in parsed.commands:
            result = await self._execute(command, xy_mm)
            if not result.ok:
                return result
            data.update(result.data)
        return CommandResult(True, data)

    async def execute_request(self, name: str, args: Mapping[str, object]) -> CommandResult:
        if name == "status":
            return CommandResult(True, self.snapshot())
        try:
            command = parse_request(name, args)
        except CommandError as exc:
            return CommandResult(False, error=str(exc))
        return await self._execute(command, None)

    async def sender_lost(self, reason: str) -> None:
        if self.seq.busy:
            log.warning("sender_lost_mid_cut", reason=reason)
            self.seq.abort(f"sender lost: {reason}")
            self._pump()

    def snapshot(self) -> dict[str, object]:
        state = self.seq.snapshot()
        state["board"] = self._link[0]
        state["resume_point"] = (
            None
            if self.controller.last_resume_point is None
            else {
                "line": self.controller.last_resume_point.line,
                "index": self.controller.last_resume_point.index,
            }
        )
        return state

    def link_state(self) -> tuple[str, str]:
        return self._link

    def diagnostics(self) -> dict[str, object]:
        out: dict[str, object] = {"link": self.supervisor.stats.as_dict()}
        session = self.supervisor.session
        if session is not None:
            out["decoder"] = session.decoder.stats.as_dict()
        out["pierces"] = self.seq.pierce_count
        return out

    def telemetry(self) -> dict[str, object] | None:
        if self._last_batch is None:
            return None
        t, z_mm, xy = self._last_batch
        thc = self.seq.thc
        return {
            "t": round(t, 4),
            "state": str(self.seq.state),
            "voltage_v": thc.filtered_v,
            "target_v": thc.target_v,
            # While a steady slow-down is followed: the voltage it is held at.
            "slow_target_v": thc.slow_target_v,
            "z_mm": z_mm,
            "xy_speed_mm_s": xy,
            "locks": sorted(str(lock) for lock in thc.locks(t)),
        }

    async def subscribe_events(self) -> AsyncIterator[dict[str, object]]:
        queue: asyncio.Queue[dict[str, object]] = asyncio.Queue(EVENT_QUEUE_SIZE)
        self._events.append(queue)
        try:
            while True:
                yield await queue.get()
        finally:
            self._events.remove(queue)

    # --- commands --------------------------------------------------------------------------

    async def _execute(self, command: Command, xy_mm: tuple[float, float] | None) -> CommandResult:
        async with self._command_lock:  # one plasma command at a time, in arrival order
            try:
                outcome = self.controller.handle(command, self.now, xy_mm)
            except CommandError as exc:
                return CommandResult(False, error=str(exc))
            if outcome.data.get("resume_line") is not None or "index" in outcome.data:
                self._publish_event({"type": "resume_point", **outcome.data})
            if not outcome.deferred:
                self._pump()
                return CommandResult(True, outcome.data)
            self._reply = self._loop.create_future()
            self._pump()
            try:
                reply = await asyncio.wait_for(asyncio.shield(self._reply), self.command_timeout_s)
            except TimeoutError:
                self.seq.abort(f"{type(command).__name__} not completed in time")
                self._pump()
                return CommandResult(False, error="timeout: the sequence did not complete")
            except asyncio.CancelledError:
                # The requester gave up (deadline): a cut nobody waits for is ended safely.
                self.seq.abort(f"{type(command).__name__} cancelled by its requester")
                self._pump()
                raise
            finally:
                self._reply = None
            return CommandResult(reply.ok, {"command": reply.command}, reply.error)

    def _note_feed(self, motion: str) -> None:
        if _CUTTING_MOTION.search(motion):
            match = _FEED.search(motion)
            if match:
                self._requested_feed_mm_s = float(match.group(1)) / 60.0

    # --- actions ---------------------------------------------------------------------------

    def _pump(self) -> None:
        """Take the sequence's actions: Z velocity at once, the rest to the worker in order."""
        for action in self.seq.drain():
            if isinstance(action, act.ZVelocity):
                self._send_velocity(action.velocity_mm_s)
            elif isinstance(action, act.CommandReply):
                if self._reply is not None and not self._reply.done():
                    self._reply.set_result(action)
            elif isinstance(action, act.PauseProgram):
                kind = "arc_lost" if action.reason == "arc lost" else "pause"
                self._publish_event({"type": kind, "reason": action.reason})
            else:
                self._work.put_nowait(action)

    def _send_velocity(self, velocity_mm_s: float) -> None:
        try:
            self.client.z_velocity(velocity_mm_s)
        except LinkError as exc:
            log.debug("z_velocity_dropped", error=str(exc))

    async def run(self) -> None:
        """Execute board actions in order until cancelled."""
        while True:
            action = await self._work.get()
            try:
                await self._perform(action)
            except (TimeoutError, LinkError) as exc:
                self.seq.on_action_failed(action, str(exc))
            self._pump()

    async def _perform(self, action: act.BoardAction) -> None:
        client = self.client
        if isinstance(action, act.Torch):
            await client.torch(action.on)
        elif isinstance(action, act.OhmicSense):
            await client.ohmic_sense(action.on)
        elif isinstance(action, act.MoveZ):
            seq = await client.start_move_z(action.target_mm, action.feed_mm_s)
            self._spawn(self._await_move(seq, action.token))
        elif isinstance(action, act.ProbeZ):
            sensors = (SENSOR_OHMIC if action.ohmic else 0) | (
                SENSOR_FLOAT if action.float_switch else 0
            )
            seq = await client.start_probe(action.feed_mm_s, action.max_travel_mm, sensors)
            self._spawn(self._await_probe(seq))
        elif isinstance(action, act.StopZ):
            await client.z_stop()
        elif isinstance(action, act.SetCurrent):
            await client.set_current(action.current_a)
        elif isinstance(action, act.ResetFaults):
            await client.fault_reset()

    def _spawn(self, work: Any) -> None:
        task = asyncio.create_task(work, name="board-completion")
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    async def _await_move(self, seq: int, token: int) -> None:
        try:
            done = await self.client.wait_report(fp.MotionDone, seq, self.command_timeout_s)
        except LinkError as exc:
            self.seq.on_action_failed(act.MoveZ(0, 0, token), str(exc))
        else:
            self.seq.on_motion_done(token, done.result == fp.MotionResult.REACHED, done.z_um / 1000)
        self._pump()

    async def _await_probe(self, seq: int) -> None:
        try:
            done = await self.client.wait_report(fp.ProbeResult, seq, self.command_timeout_s)
        except LinkError as exc:
            self.seq.on_action_failed(act.ProbeZ(0, 0, False, False), str(exc))
        else:
            self.seq.on_probe_done(
                done.result == fp.ProbeOutcome.CONTACT, bool(done.sensor & SENSOR_OHMIC),
                done.contact_z_um / 1000, done.stop_z_um / 1000,
            )  # fmt: skip
        self._pump()

    # --- board events ----------------------------------------------------------------------

    def _on_board(self, item: Telemetry) -> None:
        seq = self.seq
        now = self.now
        if isinstance(item, fp.Samples):
            z_mm, xy = feed_samples(seq, item, self._requested_feed_mm_s, now)
            # Only what the batch brought is kept here; telemetry() builds the point at the
            # MQTT rate, not at the sample rate.
            self._last_batch = (now, z_mm, xy)
        elif isinstance(item, fp.Event):
            seq.on_inputs(item.inputs, item.z_um / 1000, now)
        elif isinstance(item, fp.Fault):
            name = _fault_name(item.code)
            self._publish_event({"type": "fault", "code": name, "faults": item.faults})
            seq.on_board_fault(name)
        self._pump()

    def _on_link_state(self, state: LinkState, reason: str) -> None:
        if self._previous_on_state is not None:
            self._previous_on_state(state, reason)
        self._link = (str(state), reason)
        self._publish_event({"type": "link", "state": str(state), "reason": reason})
        if reason == "board_rebooted":
            self._publish_event({"type": "board_rebooted"})
        if state is LinkState.ONLINE:
            session = self.supervisor.session
            if session is not None and session.info is not None:
                info = session.info
                self.seq.config = with_board_limits(
                    self.seq.config, info.z_min_um / 1000, info.z_max_um / 1000
                )
            if self.board_setup is not None:
                self._spawn(self._setup_board(self.board_setup))
            status = session.initial_status if session is not None else None
            if status is not None and status.faults:
                # A fault latched while we were away (the lease ran out during an unplug):
                # the operator re-arms before the next cut, which also resets the board.
                self.seq.on_board_fault(_fault_names(status.faults))
                self._pump()
        elif state in (LinkState.OFFLINE, LinkState.INCOMPATIBLE):
            self.seq.on_link_down(reason)
            # The torch-off request cannot reach an absent board; the board's lease does it.
            self._pump()

    async def _setup_board(self, setup: Callable[[BoardClient], Awaitable[None]]) -> None:
        try:
            await setup(self.client)
        except LinkError as exc:
            log.warning("board_setup_failed", error=str(exc))

    def _publish_event(self, event: dict[str, object]) -> None:
        event = {"t": round(self.now, 3), **event}
        for queue in self._events:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait(event)

    async def shutdown(self) -> None:
        """SIGTERM/SIGINT: abort any cut, torch off, Z velocity zero; bounded in time."""
        self.seq.abort("daemon stopping")
        self.seq.drain()
        with contextlib.suppress(LinkError, asyncio.TimeoutError):
            self._send_velocity(0.0)
            await asyncio.wait_for(self.client.torch(False), 0.5)


def feed_samples(
    seq: CutSequence, batch: fp.Samples, requested_feed_mm_s: float | None, now: float
) -> tuple[float, float | None]:
    """One SAMPLES batch into the cut sequence, in its units; returns (Z mm, XY mm/s)."""
    z_mm = batch.z_um / 1000
    seq.on_inputs(batch.inputs, z_mm, now)
    xy = batch.xy_speed_dmm_s / 10 if batch.has_xy_speed else None
    volts = [cv / 100 for cv in batch.samples_cv]
    seq.on_samples(volts, batch.period_us / 1e6, z_mm, xy, requested_feed_mm_s, now)
    return z_mm, xy


def _fault_names(faults: int) -> str:
    return ", ".join(_fault_name(code) for code in range(16) if faults & (1 << code))


def _fault_name(code: int) -> str:
    try:
        return fp.FaultCode(code).name
    except ValueError:
        return f"fault {code}"
