"""ControllerService: the plasma controller driving the board, as the MQTT layer sees it.

The pure :class:`~.controller.plasma.PlasmaController` decides; this class does the I/O:
board telemetry goes into the cut sequence in the link's receive callback (so the THC's
Z velocity leaves in the same callback as the samples arrived: the hot path), board
requests run in order on one worker task, completions come back as events, and the
sequence's replies answer the sender's pending M3/M5.

Time is the board's: the sequence and the THC run on the sample timestamps (on the link's
continuous timeline), and a command from the sender takes effect at the latest board time
seen. A listener bug while handling board data is caught at the link, which calls
:meth:`_on_handler_error`: the cut ends through the fault path (docs/DESIGN.md invariant 6).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from typing import Any

import structlog

import firmware_protocol as fp

from .board import Batch, BoardClient, BoardReport, HomingPlan, InputChange
from .consumables import ConsumableLog
from .controller import actions as act
from .controller.commands import Abort, Command, CommandError, CycleStart, ProbeTest, ThcHold
from .controller.dialect import Dialect
from .controller.gcode import parse_line
from .controller.plasma import PlasmaController
from .controller.sequence import CutSequence, State, with_board_limits
from .controller.words import cutting_feed_mm_min
from .events import (
    ArcLost,
    BoardFaulted,
    BoardRestarted,
    ControllerEvent,
    LinkChanged,
    ProgramPaused,
    ResumePointMarked,
    SequenceChanged,
)
from .link import LinkError, LinkState, LinkStateChange, LinkSupervisor
from .materials import (
    TEMPORARY_BASE,
    MaterialError,
    MaterialStore,
    material_from_dict,
    material_to_dict,
)
from .port import CommandResult
from .requests import serve_request

__all__ = ["ControllerService", "EventListener", "feed_samples"]

log = structlog.get_logger("dthc_bridge.service")

EVENT_QUEUE_SIZE = 256
TORCH_OFF_REPEAT_S = 0.1  # board time between direct torch-offs while handlers keep failing

EventListener = Callable[[ControllerEvent], None]
_ENVELOPE = ("transaction", "deadline_ms")
INPUT_NAMES = {bit.name.lower(): int(bit) for bit in fp.InputBit}
HOST_SPEED_STALE_S = 0.45
"""A sender's ``motion`` report counts this long (board time): it polls its motion
controller at 5-20 Hz, so this covers two report periods at 5 Hz (one missed report at 10
Hz); older counts as no speed (THC locked, ``no_speed``)."""


class ControllerService:
    def __init__(
        self,
        controller: PlasmaController,
        supervisor: LinkSupervisor,
        client: BoardClient,
        *,
        command_timeout_s: float = 60.0,
        board_setup: Callable[[BoardClient], Awaitable[None]] | None = None,
        dialect: Dialect = Dialect.MASSO,
        materials: MaterialStore | None = None,
        codes: Mapping[str, str] | None = None,
        consumables: ConsumableLog | None = None,
        homing: HomingPlan | None = None,
    ) -> None:
        self.controller = controller
        self.homing = homing or HomingPlan()
        self._home_after_rearm = False  # homing waits for a latched fault's re-arm
        # Pierces and arc-on time (consumable life), counted from the board's batches.
        self.consumables = consumables or ConsumableLog(None)
        self._pierces_seen = controller.sequence.pierce_count
        self._burning = False
        self.dialect = dialect  # of lines whose request names none
        self.codes = dict(codes or {})  # the shop's own codes, told to senders at program_start
        self.material_store = materials
        self.sequence = controller.sequence
        self.supervisor = supervisor
        self.client = client
        self.command_timeout_s = command_timeout_s
        self.board_setup = board_setup
        self._loop = asyncio.get_running_loop()
        self._work: asyncio.Queue[act.BoardAction] = asyncio.Queue()
        self._reply: asyncio.Future[act.CommandReply] | None = None
        self._command_lock = asyncio.Lock()
        self._event_listeners: list[EventListener] = []
        self._background: set[asyncio.Task[None]] = set()
        self._requested_feed_mm_s: float | None = None
        # The sender's measured XY speed (``motion`` request) and the board time it came at:
        # the anti-dive input when the board has no XY speed input of its own.
        self._host_speed: tuple[float, float] | None = None
        self._board_has_xy = False  # it reported an XY speed of its own: the host's is moot
        self._last_batch: tuple[float, float, float | None] | None = None  # t, z, xy speed
        self._last_io = (0, 0)  # the last batch's input snapshot and board status bits
        self._link: tuple[str, str] = (str(supervisor.state), "")
        self._torch_off: asyncio.Task[None] | None = None
        self._torch_off_sent_s = -math.inf
        # Published as a ``sequence`` event whenever it changes.
        self._state_seen = controller.sequence.state
        client.add_samples_listener(self._on_batch)
        client.add_report_listener(self._on_report)
        client.add_state_listener(self._on_link_state)
        client.add_error_listener(self._on_handler_error)

    @property
    def now(self) -> float:
        """Board time, in seconds: when a command from the sender takes effect."""
        return self.client.board_time_s

    # --- the ControllerPort seam (dthc_bridge.port) -------------------------------------

    async def execute_gcode(
        self,
        line: str,
        *,
        line_number: int | None = None,
        xy_mm: tuple[float, float] | None = None,
        dialect: Dialect | None = None,
    ) -> CommandResult:
        try:
            parsed = parse_line(line, line_number=line_number, dialect=dialect or self.dialect)
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
        """A named request, served by its entry in the request table (:mod:`.requests`)."""
        return await serve_request(self, name, args)

    # --- the request handlers (requests.RequestHandlers) --------------------------------------

    async def execute_command(self, command: Command) -> CommandResult:
        return await self._execute(command, None)

    async def reset_consumables(self) -> CommandResult:
        await asyncio.to_thread(self.consumables.reset)
        return CommandResult(True, {"consumables": self.consumables.counters.as_dict()})

    def start_program(self) -> CommandResult:
        if self.sequence.busy:
            return CommandResult(False, error=f"program_start: a cut is running "
                                 f"({self.sequence.state})")  # fmt: skip
        # The sender learns the shop's set-up here: the dialect to assume when a program
        # says nothing dialect-specific, and the code table it rewrites lines with.
        started = self.controller.begin_program()
        return CommandResult(
            True, {**started, "dialect": str(self.dialect), "codes": dict(self.codes)}
        )

    def end_program(self) -> CommandResult:
        if self.sequence.busy:
            return CommandResult(False, error=f"program_end: a cut is running "
                                 f"({self.sequence.state})")  # fmt: skip
        return CommandResult(True, self.controller.end_program())

    async def sender_lost(self, reason: str) -> None:
        if self.sequence.busy:
            log.warning("sender_lost_mid_cut", reason=reason)
            self.sequence.abort(f"sender lost: {reason}")
            self.pump()

    def materials(self) -> dict[str, object]:
        """The library as the retained ``materials`` topic shows it (temporaries included:
        they are what a running program cuts with)."""
        table = self.controller.materials
        return {
            "selected": table.selected_number,
            "materials": [
                {"number": m.number, **material_to_dict(m)}
                for m in (self.controller.default_material, *table.materials.values())
            ],
        }

    def host_motion(
        self, speed_mm_s: float, feed_mm_min: float | None, state: str | None
    ) -> CommandResult:
        """``motion`` {xy_speed_mm_s, feed_mm_min?, state?}: the XY speed the sender measured
        from its motion controller's status reports (grbl's position, polled). Used for the
        anti-dive only when the board reports no XY speed; stale after HOST_SPEED_STALE_S."""
        used = not self._board_has_xy
        if used:
            self._host_speed = (speed_mm_s, self.now)
            if feed_mm_min is not None:
                self._requested_feed_mm_s = feed_mm_min / 60.0
        log.debug(
            "host_motion", speed_mm_s=speed_mm_s, feed_mm_min=feed_mm_min, state=state, used=used
        )
        return CommandResult(True, {"used": used})

    def _host_speed_now(self, t_s: float) -> float | None:
        if self._host_speed is None:
            return None
        speed, at_s = self._host_speed
        # Negative age: the board rebooted and its clock started again; not fresh.
        return speed if 0.0 <= t_s - at_s <= HOST_SPEED_STALE_S else None

    def material_request(self, name: str, args: Mapping[str, object]) -> CommandResult:
        """``materials``, ``material_get``/``_set``/``_delete`` {number, ...}: the library,
        written to its file (crash-safe) before the answer."""
        if name == "materials":
            return CommandResult(True, self.materials())
        raw = args.get("number")
        if isinstance(raw, bool) or not isinstance(raw, int):
            return CommandResult(False, error=f"{name} number: {raw!r} is not a material number")
        try:
            if name == "material_get":
                material = self.controller.materials.get(raw, where=f"{name} number")
                return CommandResult(True, {"number": raw, **material_to_dict(material)})
            store = self.material_store
            if store is None:
                return CommandResult(False, error=f"{name}: no materials_file is configured")
            if raw == 0 or raw >= TEMPORARY_BASE:
                return CommandResult(
                    False, error=f"{name} number: {raw} is not a library material (1..999999)"
                )
            fields = {k: v for k, v in args.items() if k not in ("number", *_ENVELOPE)}
            if name == "material_set":
                store.set(material_from_dict(raw, fields))
            else:
                if fields:
                    return CommandResult(False, error=f"{name} {next(iter(fields))}: "
                                         "unknown argument")  # fmt: skip
                store.delete(raw)
        except MaterialError as exc:
            return CommandResult(False, error=str(exc))
        except OSError as exc:
            return CommandResult(False, error=f"{name}: cannot write the materials file: {exc}")
        self.controller.set_library(store.all())
        return CommandResult(True, {"number": raw})

    def snapshot(self) -> dict[str, object]:
        state = self.sequence.snapshot()
        state["board"] = self._link[0]
        state["consumables"] = self.consumables.counters.as_dict()
        point = self.controller.last_resume_point
        state["resume_point"] = (
            None if point is None else {"line": point.line, "index": point.index}
        )
        return state

    @property
    def handler_errors(self) -> int:
        """Bugs caught while handling board data (counted by the link, invariant 6)."""
        return self.supervisor.stats.handler_errors

    def link_state(self) -> tuple[str, str]:
        return self._link

    def diagnostics(self) -> dict[str, object]:
        out: dict[str, object] = {"link": self.supervisor.stats.as_dict()}
        session = self.supervisor.session
        if session is not None:
            out["decoder"] = session.decoder.stats.as_dict()
        out["pierces"] = self.sequence.pierce_count
        out["handler_errors"] = self.handler_errors
        return out

    def telemetry(self) -> dict[str, object] | None:
        if self._last_batch is None:
            return None
        t, z_mm, xy = self._last_batch
        thc = self.sequence.thc
        inputs, status = self._last_io
        return {
            "t": round(t, 4),
            "state": str(self.sequence.state),
            "voltage_v": thc.filtered_v,
            "target_v": thc.target_v,
            # While a steady slow-down is followed: the voltage it is held at.
            "slow_target_v": thc.slow_target_v,
            "z_mm": z_mm,
            # Above the plate: the surface this cut probed, else the last one probed.
            "height_mm": self._height_mm(z_mm),
            "xy_speed_mm_s": xy,
            "locks": sorted(str(lock) for lock in thc.locks(t)),
            # Raw levels, as the board's pins read them: the panel's input lights.
            "inputs": {name: bool(inputs & (1 << bit)) for name, bit in INPUT_NAMES.items()},
            "torch_on": bool(status & fp.StatusBit.TORCH_ON),
        }

    def _height_mm(self, z_mm: float) -> float | None:
        surface = self.sequence.surface_mm
        if surface is None or math.isnan(z_mm):
            return None
        return round(z_mm - surface, 3)

    def add_event_listener(self, listener: EventListener) -> None:
        """Every event, synchronously, as it happens."""
        self._event_listeners.append(listener)

    async def subscribe_events(self) -> AsyncIterator[ControllerEvent]:
        """Events as an async stream (bounded: the oldest are dropped if unread)."""
        queue: asyncio.Queue[ControllerEvent] = asyncio.Queue(EVENT_QUEUE_SIZE)

        def enqueue(event: ControllerEvent) -> None:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait(event)

        self._event_listeners.append(enqueue)
        try:
            while True:
                yield await queue.get()
        finally:
            self._event_listeners.remove(enqueue)

    # --- commands --------------------------------------------------------------------------

    async def _execute(self, command: Command, xy_mm: tuple[float, float] | None) -> CommandResult:
        if isinstance(command, CycleStart | Abort | ThcHold):
            # Cycle start answers the M3 that waits for it (G200 S1), a stop ends it, and an
            # operator's pause must hold now: queued behind that M3 each would wait for it.
            # None defers, so none needs a turn.
            result = self._apply(command, xy_mm)
            assert result is not None
            return result
        async with self._command_lock:  # one plasma command at a time, in arrival order
            result = self._apply(command, xy_mm)
            if result is not None:
                return result
            assert self._reply is not None
            try:
                reply = await asyncio.wait_for(asyncio.shield(self._reply), self.command_timeout_s)
            except TimeoutError:
                self.sequence.abort(f"{type(command).__name__} not completed in time")
                self.pump()
                return CommandResult(False, error="timeout: the sequence did not complete")
            except asyncio.CancelledError:
                # The requester gave up (deadline): a cut nobody waits for is ended safely.
                self.sequence.abort(f"{type(command).__name__} cancelled by its requester")
                self.pump()
                raise
            finally:
                self._reply = None
            data: dict[str, object] = {"command": reply.command}
            if isinstance(command, ProbeTest) and reply.ok:
                surface = self.sequence.surface_mm  # what the operator tested for
                data["surface_z_mm"] = None if surface is None else round(surface, 3)
            return CommandResult(reply.ok, data, reply.error)

    def _apply(self, command: Command, xy_mm: tuple[float, float] | None) -> CommandResult | None:
        """Apply a command and take the sequence's actions: its result, or None when the
        sequence answers later (deferred: ``_reply`` is then the future it resolves)."""
        try:
            outcome = self.controller.handle(command, self.now, xy_mm)
        except CommandError as exc:
            return CommandResult(False, error=str(exc))
        if outcome.store is not None and self.material_store is not None:
            try:
                self.material_store.set(outcome.store)
            except OSError as exc:
                log.error("material_not_stored", number=outcome.store.number, error=str(exc))
            self.controller.set_library(self.material_store.all())
        point = outcome.resume_point
        if point is not None:
            self._publish_event(ResumePointMarked(self.now, point.line, point.index))
        if outcome.deferred:
            self._reply = self._loop.create_future()
        self.pump()
        return None if outcome.deferred else CommandResult(True, outcome.data)

    def _note_feed(self, motion: str) -> None:
        feed_mm_min = cutting_feed_mm_min(motion)
        if feed_mm_min is not None:
            self._requested_feed_mm_s = feed_mm_min / 60.0

    # --- actions ---------------------------------------------------------------------------

    def pump(self) -> None:
        """Take the sequence's actions: Z velocity at once, the rest to the worker in order.

        Called after everything that can change the sequence (here, and by the closed-loop
        simulation after it pokes the sequence directly)."""
        for action in self.sequence.drain():
            if isinstance(action, act.SetZVelocity):
                self._send_velocity(action.velocity_mm_s)
            elif isinstance(action, act.CommandReply):
                if self._reply is not None and not self._reply.done():
                    self._reply.set_result(action)
            elif isinstance(action, act.PauseProgram):
                if action.cause is act.PauseCause.ARC_LOST:
                    self._publish_event(ArcLost(self.now, action.reason))
                else:
                    self._publish_event(ProgramPaused(self.now, action.reason, str(action.cause)))
            else:
                self._work.put_nowait(action)
        state = self.sequence.state  # compared as it is: pump runs for every sample batch
        if state is not self._state_seen:
            error = self.sequence.error if state is State.FAULTED else ""
            self._publish_event(SequenceChanged(self.now, str(state), str(self._state_seen), error))
            self._state_seen = state

    def _send_velocity(self, velocity_mm_s: float) -> None:
        try:
            self.client.z_velocity(velocity_mm_s)
        except LinkError as exc:
            log.debug("z_velocity_dropped", error=str(exc))

    async def run(self) -> None:
        """Execute board actions in order until cancelled; then cancel and await every task
        the service (and its board client) started: none outlives it."""
        try:
            while True:
                action = await self._work.get()
                try:
                    await self._perform(action)
                except (TimeoutError, LinkError) as exc:
                    self.sequence.on_action_failed(action, str(exc))
                self.pump()
        finally:
            await self._stop_background()

    async def _stop_background(self) -> None:
        tasks = {*self._background, *([self._torch_off] if self._torch_off else [])}
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)
        await self.client.stop_background()

    async def _perform(self, action: act.BoardAction) -> None:
        """One board action as board requests (its completion comes back as an event); a
        Z velocity never comes here (``pump`` sends it at once)."""
        client = self.client
        if isinstance(action, act.SwitchTorch):
            await client.torch(action.on)
        elif isinstance(action, act.SwitchOhmicSense):
            await client.ohmic_sense(action.on)
        elif isinstance(action, act.MoveZ):
            seq = await client.start_move_z(action.target_mm, action.feed_mm_s)
            self._spawn(self._await_move(seq, action.token))
        elif isinstance(action, act.ProbeZ):
            sensors = (fp.InputMask.OHMIC if action.ohmic else 0) | fp.InputMask.FLOAT
            seq = await client.start_probe(
                action.feed_mm_s, action.max_travel_mm, sensors, away=action.away
            )
            self._spawn(self._await_probe(seq, action.away))
        elif isinstance(action, act.ApplyCurrent):
            await client.set_current(action.current_a)
        elif isinstance(action, act.ResetFaults):
            await client.fault_reset()
            if self._home_after_rearm:
                self._home_after_rearm = False
                if self._needs_homing(await client.status()):
                    self._spawn(self._home_z(), "homing")

    def _spawn(self, work: Any, name: str = "board-completion") -> None:
        task = asyncio.create_task(work, name=name)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    async def _await_move(self, seq: int, token: int) -> None:
        try:
            done = await self.client.wait_move(seq, self.command_timeout_s)
        except LinkError as exc:
            self.sequence.on_action_failed(act.MoveZ(0, 0, token), str(exc))
        else:
            self.sequence.on_motion_done(token, done.reached, done.z_mm)
        self.pump()

    async def _await_probe(self, seq: int, away: bool = False) -> None:
        """The probe's outcome to the sequence: ``contact`` is the probe's goal reached,
        contact (down) or every sensor released (away), at ``contact_z`` (the release's Z)."""
        try:
            done = await self.client.wait_probe(seq, self.command_timeout_s)
        except LinkError as exc:
            self.sequence.on_action_failed(act.ProbeZ(0, 0, False, away), str(exc))
        else:
            goal = fp.ProbeOutcome.RELEASED if away else fp.ProbeOutcome.CONTACT
            self.sequence.on_probe_done(
                done.result == goal, bool(done.sensor & fp.InputMask.OHMIC),
                done.contact_z_mm, done.stop_z_mm,
            )  # fmt: skip
        self.pump()

    # --- board events ----------------------------------------------------------------------

    def _on_batch(self, batch: Batch) -> None:
        """A SAMPLES batch, in SI units (the board client converted it): the hot path."""
        t_s = batch.t_s
        self._board_has_xy = self._board_has_xy or batch.xy_speed_mm_s is not None
        host_speed = self._host_speed_now(t_s)
        xy = feed_samples(self.sequence, batch, self._requested_feed_mm_s, host_speed)
        # Only what the batch brought is kept here; telemetry() builds the point at the MQTT
        # rate, not at the sample rate.
        self._last_batch = (t_s, batch.z_mm, xy)
        self._last_io = (batch.inputs, batch.status)
        self._count_consumables(batch)
        self.pump()

    def _on_report(self, report: BoardReport) -> None:
        sequence = self.sequence
        t_s = report.t_s
        if isinstance(report, InputChange):
            sequence.on_inputs(report.inputs, report.z_mm, t_s)  # never behind (timeline)
        else:
            name = _fault_name(report.code, report.detail)
            if report.idle_lapse and not sequence.busy:
                # The lease ran out with nothing lit and Z at rest (a CPU spike, a stalled
                # link): the board latched nothing and goes on with the next frame, as the
                # daemon does: logged, not a fault to re-arm.
                log.warning("lease_lapsed_idle", t=round(t_s, 3))
            else:
                self._publish_event(BoardFaulted(t_s, name, report.faults))
                sequence.on_board_fault(name)
        self.pump()

    def _count_consumables(self, batch: Batch) -> None:
        """A pierce per arc transfer; arc-on time while the relay is on and Arc OK reads;
        saved (in a thread: the hot path never waits for a disk) when the arc goes out."""
        counters = self.consumables
        while self._pierces_seen < self.sequence.pierce_count:
            self._pierces_seen += 1
            counters.pierced()
        burning = bool(batch.status & fp.StatusBit.TORCH_ON and batch.inputs & fp.InputMask.ARC_OK)
        if burning:
            counters.burned(batch.duration_s)
        elif self._burning:
            content = counters.pending()
            if content is not None:
                self._spawn(asyncio.to_thread(counters.write, content), "consumables-write")
        self._burning = burning

    def _on_handler_error(self, error: Exception) -> None:
        """A bug while handling board data (docs/DESIGN.md invariant 6): end the cut through
        the fault path.

        The sequence may be the part that failed, so what keeps the table safe does not rely
        on it: the torch-off request and a zero Z velocity go out first, directly."""
        self._send_velocity(0.0)
        # One torch-off in flight and one per TORCH_OFF_REPEAT_S at most: a bug that fires on
        # every batch must not fill the board's request window.
        due = self.now - self._torch_off_sent_s >= TORCH_OFF_REPEAT_S
        if due and (self._torch_off is None or self._torch_off.done()):
            self._torch_off_sent_s = self.now
            self._torch_off = asyncio.create_task(self._torch_off_quietly(), name="torch-off")
        try:
            self.sequence.abort(f"internal error: {type(error).__name__}: {error}")
            self.pump()
        except Exception:  # the sequence itself is broken: the board's lease ends the cut
            log.exception("fault_path_failed")
            self._publish_event(ProgramPaused(self.now, f"internal error: {error}"))

    async def _torch_off_quietly(self) -> None:
        with contextlib.suppress(LinkError, asyncio.TimeoutError):
            await self.client.torch(False)

    def _on_link_state(self, change: LinkStateChange) -> None:
        state, reason = change.state, change.reason
        self._link = (str(state), reason)
        self._publish_event(LinkChanged(self.now, str(state), reason))
        if change.board_rebooted:
            self._publish_event(BoardRestarted(self.now))
        if state is LinkState.ONLINE:
            session = self.supervisor.session
            z_range = self.client.z_range_mm()
            if z_range is not None:
                self.sequence.config = with_board_limits(self.sequence.config, *z_range)
            status = session.initial_status if session is not None else None
            if self.board_setup is not None:
                self._spawn(self._setup_board(self.board_setup))
            if self.homing.mode != "off":
                if status is not None and status.faults:
                    # The board refuses Z_HOME while a fault is latched (an E-stop held at
                    # power-up): it homes once the operator has re-armed.
                    self._home_after_rearm = True
                    self.sequence.unhomed = (
                        "Z is not homed: a fault was latched when the board came online; it "
                        "homes once re-armed"
                    )
                elif self._needs_homing(status):
                    # Decided here, not in the task: an M3 already queued must find it refused.
                    self._spawn(self._home_z(), "homing")
            if status is not None and status.faults:
                # A fault latched while we were away (the lease ran out during an unplug):
                # the operator re-arms before the next cut, which also resets the board.
                self.sequence.on_board_fault(_fault_names(status.faults))
                self.pump()
        elif state in (LinkState.OFFLINE, LinkState.INCOMPATIBLE):
            self.sequence.on_link_down(reason)
            # The torch-off request cannot reach an absent board; the board's lease does it.
            self.pump()

    def _needs_homing(self, status: fp.Status | None) -> bool:
        """[board.homing] at_start / required, the board just online: whether Z homes now
        (a daemon restart finds it homed and leaves it); cuts and Z commands wait from this
        moment, before the homing task first runs."""
        settings, sequence = self.homing, self.sequence
        required = settings.mode == "required"
        if not self.client.can_home():
            sequence.unhomed = (
                'Z cannot home: [board.homing] mode is "required" but the board has no home '
                "switch input (HELLO_INFO lacks HOMING, or its protocol predates 1.3)"
                if required
                else ""
            )
            log.warning("homing_unsupported", mode=settings.mode)
            return False
        if status is not None and status.status & fp.StatusBit.HOMED:
            sequence.unhomed = ""
            log.info("homing_kept", z_mm=status.z_um / 1000)
            return False
        sequence.unhomed = "Z is homing: the cut waits until it has found its home switch"
        sequence.homing = True
        log.info("homing_started", mode=settings.mode)
        return True

    async def _home_z(self) -> None:
        """Home Z (``_needs_homing`` said so); with ``required`` cuts are refused until it
        has homed."""
        settings, sequence = self.homing, self.sequence
        required = settings.mode == "required"
        failure = ""
        try:
            ended = await self.client.home(
                seek_mm_s=settings.seek_mm_s,
                locate_mm_s=settings.locate_mm_s,
                backoff_mm=settings.backoff_mm,
                max_travel_mm=settings.max_travel_mm,
                timeout_s=settings.timeout_s,
            )
        except (TimeoutError, LinkError) as exc:
            failure = f"Z homing failed: {exc}"
        finally:
            sequence.homing = False
        if not failure:
            if ended.homed:
                log.info("homed", z_mm=ended.z_mm, shift_mm=ended.shift_mm)
            else:
                failure = (
                    f"Z homing failed: {ended.outcome} (the home switch, Z_LIMIT_MAX, within "
                    f"{settings.max_travel_mm:g} mm and {settings.timeout_s:g} s of "
                    "[board.homing])"
                )
        if failure:
            log.warning("homing_failed", error=failure)
        sequence.unhomed = (
            f'{failure}; [board.homing] mode is "required": no cut until Z has homed (mend '
            "the switch, then restart the service or reconnect the board: it homes again)"
            if failure and required
            else ""
        )

    async def _setup_board(self, setup: Callable[[BoardClient], Awaitable[None]]) -> None:
        try:
            await setup(self.client)
        except LinkError as exc:
            log.warning("board_setup_failed", error=str(exc))

    def _publish_event(self, event: ControllerEvent) -> None:
        for listener in list(self._event_listeners):
            listener(event)

    async def shutdown(self) -> None:
        """SIGTERM/SIGINT: abort any cut, torch off, Z velocity zero; bounded in time."""
        self.sequence.abort("daemon stopping")
        self.sequence.drain()
        self.consumables.save()
        with contextlib.suppress(LinkError, asyncio.TimeoutError):
            self._send_velocity(0.0)
            await asyncio.wait_for(self.client.torch(False), 0.5)


def feed_samples(
    sequence: CutSequence,
    batch: Batch,
    requested_feed_mm_s: float | None,
    host_speed_mm_s: float | None = None,
) -> float | None:
    """One batch into the cut sequence at its board time (that of its last sample). The
    board's XY speed when it has the input, else the sender's (``host_speed_mm_s``).
    Returns the XY speed used (mm/s, or None)."""
    t_s, z_mm = batch.t_s, batch.z_mm
    sequence.on_inputs(batch.inputs, z_mm, t_s)
    xy = batch.xy_speed_mm_s
    if xy is None:
        xy = host_speed_mm_s
    sequence.on_samples(batch.volts, batch.period_s, z_mm, xy, requested_feed_mm_s, t_s)
    return xy


def _fault_names(faults: int) -> str:
    return ", ".join(_fault_name(code) for code in range(16) if faults & (1 << code))


def _fault_name(code: int, detail: int | None = None) -> str:
    """A fault's name; an INTERNAL one with the self-check that failed (its detail)."""
    try:
        name = fp.FaultCode(code).name
    except ValueError:
        return f"fault {code}"
    if code == fp.FaultCode.INTERNAL and detail is not None:
        try:
            check = fp.InternalFault(detail).name.lower().replace("_", " ")
        except ValueError:
            check = f"self-check {detail}"
        name = f"{name} ({check})"
    return name
