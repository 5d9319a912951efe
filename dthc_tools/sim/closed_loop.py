"""The daemon's controller service, closing the loop over a simulated board in simulated time.

Not a model of the daemon: the daemon itself. A ``ControllerService`` built as ``dthc-bridge
run`` builds it (``daemon.controller_service`` on the daemon's own ``[controller]``
defaults unless given others), with its ``LinkSupervisor`` and ``BoardClient`` built as
the daemon builds them (``daemon.board_link``), talks the wire protocol to a
:class:`~mock_device.sim.SimulatedBoard` over :class:`~.link.SimulatedLink`. So the
actions-to-protocol and reports-to-sequence mappings the benchmarks measure are the
daemon's own.

Time is simulated twice over, in step: the board advances one sample batch per step, and
the daemon's event loop is a ``looptime`` loop whose clock jumps ahead instead of sleeping,
so seconds of cutting take milliseconds and every run repeats exactly. The API is
synchronous (each call runs the loop until its condition holds), for tests and benchmarks.

The "sender" is the harness: motion goes to the plant's gantry; plasma lines and the
motion lines' feeds go to the service as G-code, as the reference sender sends them; a
pause from the daemon holds the gantry.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import threading
import weakref
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import dataclass, field
from typing import Any, TypeVar

import looptime

from dthc_bridge.config import BoardSettings, ControllerSettings
from dthc_bridge.consumables import ConsumableLog
from dthc_bridge.controller.sequence import CutSequence, SequenceConfig, State
from dthc_bridge.controller.thc import ThcConfig
from dthc_bridge.daemon import board_link, controller_service
from dthc_bridge.events import ArcLost, ControllerEvent, ProgramPaused
from dthc_bridge.mqtt.settings import MqttSettings
from dthc_bridge.port import CommandResult
from dthc_bridge.transport import BytesCallback, LostCallback, Transport
from mock_device.sim import SimulatedBoard

from .link import SimulatedLink

__all__ = ["BATCH_S", "ClosedLoop", "Reply", "Trace"]

BATCH_S = 0.005  # one step: a 5-sample batch at 1 kHz, the board's default
_T = TypeVar("_T")


@dataclass(frozen=True)
class Reply:
    """The daemon's answer to one G-code line or request."""

    command: str  # "M3", "M5", ... for deferred commands; else the line or request name
    ok: bool
    error: str = ""
    data: dict[str, object] = field(default_factory=dict)


@dataclass
class Trace:
    state: list[str] = field(default_factory=list)  # the sequence state after each step


class _Runtime:
    """The event loop, its tasks and what the daemon's callbacks write to. Nothing here
    refers back to the ClosedLoop, so a dropped ClosedLoop is collected and its loop closed
    (``weakref.finalize``) instead of living, with its plant, until the process ends."""

    def __init__(self, board: SimulatedBoard) -> None:
        # One no-op cycle before the clock jumps: enough for tasks woken in the same
        # instant to run first, and cheap (the default 42 would dominate the step cost).
        self.loop: asyncio.AbstractEventLoop = looptime.new_event_loop(noop_cycles=1)
        self.tasks: list[asyncio.Task[Any]] = []
        self.board = board
        self.link: SimulatedLink | None = None
        self.replies: list[Reply] = []
        self.pauses: list[str] = []
        self.events: list[ControllerEvent] = []
        self.holds_on_pause = True  # the harness is the sender (not a real one's)

    async def open_link(self, on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
        self.link = SimulatedLink(self.board, on_bytes, on_lost, record_velocities=True)
        return self.link

    def on_event(self, event: ControllerEvent) -> None:
        self.events.append(event)
        if isinstance(event, ArcLost | ProgramPaused):
            self.pauses.append(event.reason)
            if self.holds_on_pause:
                self.board.plant.gantry.hold()  # what the sender does with a pause

    def note_reply(self, what: str, task: asyncio.Task[CommandResult]) -> None:
        if task.cancelled():
            return
        result = task.result()
        command = str(result.data.get("command", what))
        self.replies.append(Reply(command, result.ok, result.error, dict(result.data)))

    def close(self) -> None:
        if self.loop.is_closed():
            return
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            self._shut_down()
        else:  # collected while another loop runs in this thread: ours runs in another
            worker = threading.Thread(target=self._shut_down, name="closed-loop-close")
            worker.start()
            worker.join()

    def _shut_down(self) -> None:
        loop = self.loop
        # Every task of the loop (the service's completions too), cancelled again while one
        # lingers: a cancellation can be lost where a wait and its result race (3.11's
        # wait_for). Bounded, in simulated time: nothing here waits for the real world.
        for _ in range(10):
            pending = [task for task in asyncio.all_tasks(loop) if not task.done()]
            if not pending:
                break
            for task in pending:
                task.cancel()
            loop.run_until_complete(asyncio.wait(pending, timeout=1.0))
        loop.run_until_complete(loop.shutdown_asyncgens())
        loop.close()


class ClosedLoop:
    def __init__(
        self,
        scenario: str = "flat_clean",
        seed: int = 1,
        *,
        config: SequenceConfig | None = None,
        thc: ThcConfig | None = None,
        board: SimulatedBoard | None = None,
        settings: ControllerSettings | None = None,
        holds_on_pause: bool = True,
    ) -> None:
        # The daemon's [controller] section (its defaults unless given): plasma mode at
        # start, dialect, codes, material library, as ``dthc-bridge run`` applies them.
        self.settings = settings or ControllerSettings()
        self.board = board or SimulatedBoard(scenario, seed=seed)
        self.plant = self.board.plant
        self.trace = Trace()
        # The feed (mm/min) the sender reports for the motion it sends, when it differs
        # from what the gantry runs (a PlasmaC M67 E3 velocity reduction slows the
        # machine, not the reference).
        self.reported_feed_mm_min: float | None = None
        self._runtime = _Runtime(self.board)
        # False where a real sender drives the gantry and holds it itself (.program).
        self._runtime.holds_on_pause = holds_on_pause
        self.replies = self._runtime.replies
        self.pauses = self._runtime.pauses
        self.events = self._runtime.events
        weakref.finalize(self, self._runtime.close)
        self._run(self._start(config, thc))

    # --- wiring ----------------------------------------------------------------------------

    async def _start(self, config: SequenceConfig | None, thc: ThcConfig | None) -> None:
        # The daemon's own defaults (no file, no environment), where the caller names none.
        configs = self.settings.configs()
        runtime = self._runtime
        self.supervisor, self.client = board_link(
            BoardSettings(link="sim://board"), opener=runtime.open_link
        )
        self.service = controller_service(
            self.settings, self.supervisor, self.client,
            configs=configs._replace(sequence=config or configs.sequence, thc=thc or configs.thc),
            consumables=ConsumableLog(None),  # counted, never written to an owner's file
            command_timeout_s=MqttSettings().request_deadline_s + 5.0,
        )  # fmt: skip
        self.service.add_event_listener(runtime.on_event)
        loop = asyncio.get_running_loop()
        self._runtime.tasks += [
            loop.create_task(self.supervisor.run(), name="link"),
            loop.create_task(self.service.run(), name="controller"),
        ]
        await self.supervisor.wait_online(5.0)

    def close(self) -> None:
        self._runtime.close()

    def __enter__(self) -> ClosedLoop:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- what the daemon runs --------------------------------------------------------------

    @property
    def sequence(self) -> CutSequence:
        return self.service.sequence

    @property
    def velocities(self) -> list[float]:
        """Every Z velocity (mm/s) the daemon sent the board."""
        link = self._runtime.link
        return link.velocities_mm_s if link is not None else []

    @property
    def now(self) -> float:
        return self.board.t_s

    def pump(self) -> None:
        """After poking the sequence directly: hand its actions to the service."""
        self.service.pump()

    # --- time ------------------------------------------------------------------------------

    def _run(self, work: Coroutine[Any, Any, _T]) -> _T:
        return self._runtime.loop.run_until_complete(work)

    def step(self) -> None:
        """One sample batch of board time."""
        self.run_until(lambda: False, BATCH_S)

    def run_until(self, done: Callable[[], bool], max_s: float) -> bool:
        """Step until ``done()`` holds (True) or ``max_s`` of board time passed (False)."""
        return self._run(self._run_until(done, max_s))

    async def _run_until(self, done: Callable[[], bool], max_s: float) -> bool:
        await _settle()
        end = self.now + max_s - 1e-9
        while self.now < end:
            self.board.advance_ms(BATCH_S * 1000)
            link = self._runtime.link
            if link is not None:
                link.deliver()  # the service's hot path runs in here
            await asyncio.sleep(BATCH_S)
            self._record()
            if done():
                return True
        return False

    def _record(self) -> None:
        """After each step: subclasses account what they measure."""
        self.trace.state.append(str(self.sequence.state))

    def complete(self, work: Awaitable[_T], max_s: float = 30.0) -> _T:
        """Run ``work`` on the daemon's loop while the board steps, until it completes."""
        task = self._runtime.loop.create_task(_awaited(work))
        self._run(_settle())
        if not task.done() and not self.run_until(task.done, max_s):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                self._run(_awaited(task))
            raise TimeoutError(f"not completed within {max_s} s of board time")
        return task.result()

    # --- the sender's side -----------------------------------------------------------------

    def submit(self, line: str, line_number: int | None = None) -> asyncio.Task[CommandResult]:
        """Send a G-code line to the daemon without waiting; its reply lands in ``replies``."""
        xy = (self.plant.gantry.x_mm, self.plant.gantry.y_mm)
        task = self._runtime.loop.create_task(
            self.service.execute_gcode(line, line_number=line_number, xy_mm=xy)
        )
        task.add_done_callback(functools.partial(self._runtime.note_reply, line))
        return task

    def gcode(self, line: str, line_number: int | None = None, max_s: float = 30.0) -> Reply:
        """Send a G-code line and run until the daemon answers it."""
        before = len(self.replies)
        task = self.submit(line, line_number)
        assert self.run_until(task.done, max_s), (line, self.sequence.state)
        assert len(self.replies) == before + 1
        return self.replies[-1]

    def request(self, name: str, max_s: float = 30.0, **args: object) -> Reply:
        """A named request (``rearm``, ``cycle_start``, ``ohmic_test``, ...)."""
        result = self.complete(self.service.execute_request(name, args), max_s)
        return Reply(name, result.ok, result.error, dict(result.data))

    def submit_request(self, name: str, **args: object) -> asyncio.Task[CommandResult]:
        """Send a named request without waiting (not recorded in ``replies``)."""
        return self._runtime.loop.create_task(self.service.execute_request(name, args))

    def m3(self, max_s: float = 20.0) -> Reply:
        return self.gcode("M3", max_s=max_s)

    def m5(self, max_s: float = 10.0) -> Reply:
        return self.gcode("M5", max_s=max_s)

    def move(self, *lines: str, max_s: float = 60.0) -> bool:
        """Run motion lines on the gantry; False if the cut faulted (the sender paused).

        The daemon is sent each line as well (its feed is the anti-dive reference), or
        ``reported_feed_mm_min`` when the sender reports a feed other than the one run."""
        for line in lines:
            self.plant.gantry.feed_line(line)
            self.submit(line)
        if self.reported_feed_mm_min is not None:
            self.submit(f"G1 F{self.reported_feed_mm_min:g}")
        return (
            self.run_until(
                lambda: self.plant.gantry.idle or self.sequence.state is State.FAULTED, max_s
            )
            and self.sequence.state is not State.FAULTED
        )

    def cut(self, *lines: str) -> tuple[Reply, bool, Reply]:
        started = self.m3()
        ok = started.ok and self.move(*lines)
        ended = self.m5()
        return started, ok, ended


async def _awaited(work: Awaitable[_T]) -> _T:
    return await work


async def _settle() -> None:
    """Let what was just submitted (a command, a pumped action) reach the board first."""
    for _ in range(3):
        await asyncio.sleep(0)
