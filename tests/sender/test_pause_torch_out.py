"""The sender's side of invariant 7 and of the console's truth: a pause of a lit cut stops
the program where the torch is (nothing aborted: not a fault), cycle start resumes it
there; the torch's line comes from its position; a new run drops a hold left behind; the
summary after a resume counts the whole program once."""

from __future__ import annotations

import asyncio
import io
from typing import Any, cast

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.program.plan import ProgramPlan
from dthc_tools.sender import DaemonClient, Sender
from dthc_tools.sender.backend import Where
from dthc_tools.sender.console import OperatorConsole, _merged
from dthc_tools.sender.path import build_path
from dthc_tools.sender.remote import OperatorRemote
from dthc_tools.sender.sender import SendReport
from tests.sender.test_remote import Broker
from tests.sender.test_sender_lines import FakeBackend, FakeDaemon

PROGRAM = [
    "G21 G90", "T112 M6", "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S0",
    "G0 X10 Y10", "M3", "G1 X100 F3000", "M5", "G0 X0 Y0", "M30",
]  # fmt: skip


class CuttingDaemon(FakeDaemon):
    """thc_hold on while the cut runs ends it (as the daemon does), once; status: idle."""

    def __init__(self) -> None:
        super().__init__()
        self.args: list[tuple[str, dict[str, Any]]] = []
        self.cutting = False

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        self.args.append((name, args))
        if name == "thc_hold" and args.get("on"):
            ended, self.cutting = self.cutting, False
            return {"thc_held": True, "cut_ended": ended}
        if name == "status":
            return {"state": "idle"}
        return await super().request(name, **args)

    async def gcode(self, line: str, **kwargs: Any) -> dict[str, Any]:
        answer = await super().gcode(line, **kwargs)
        if line == "M3":
            self.cutting = True
        return answer


class SlowBackend(FakeBackend):
    """A cut's motion takes until released: the torch is mid-cut while it waits; reports
    its position (and a hold) like a real controller."""

    def __init__(self) -> None:
        super().__init__()
        self.moving = asyncio.Event()
        self.position = Where(55.0, 10.0, 50.0, False)
        self.released_stale = 0

    async def wait_idle(self) -> tuple[float, float]:
        if any(line.startswith("G1") for line in self.queued) and not self.moving.is_set():
            await self.moving.wait()
        return self.position.x_mm, self.position.y_mm

    async def where(self) -> Where | None:
        return self.position

    async def clear(self) -> None:  # the queue dropped: the torch rests where it is
        self.queued.clear()
        self.moving.set()

    async def release_stale_hold(self) -> None:
        self.released_stale += 1


async def until(check: Any, what: str) -> None:
    for _ in range(300):
        if check():
            return
        await asyncio.sleep(0.01)
    raise AssertionError(what)


async def test_a_pause_mid_cut_stops_where_the_torch_is_and_cycle_start_resumes_there() -> None:
    daemon, backend = CuttingDaemon(), SlowBackend()
    sender = Sender(cast(DaemonClient, daemon), backend)
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False, wait_operator=True)
    job = asyncio.ensure_future(console.run_job(PROGRAM, dialect=Dialect.MASSO))
    await until(lambda: daemon.cutting, "the cut never started")
    assert backend.released_stale == 1  # the run began by dropping a hold left behind
    await until(lambda: sender.progress.line == 6, "the tracker never put the torch on line 6")
    assert sender.progress.cut == 1
    await console.press("p")
    await until(lambda: console.paused is not None, "the program never paused")
    assert ("abort", {}) not in daemon.args  # a pause is not a stop: nothing to re-arm
    assert console.operator_stop
    assert "paused (c resumes here)" in console.status_line()
    assert console.messages[0].startswith("paused at line 6: torch off and raised")
    await console.press("c")  # resume here: the cut's M3 again where the torch stands
    report = await asyncio.wait_for(job, 5.0)
    assert report.ok, report.error
    assert daemon.lines.count("M3") == 2
    assert report.cuts_started == 1  # one cut, resumed: counted once for the whole program
    assert report.lines_run >= {5, 6, 7, 8, 9}


async def test_a_pause_with_nothing_lit_only_holds_and_cycle_start_releases_it() -> None:
    daemon = CuttingDaemon()
    sender = Sender(cast(DaemonClient, daemon), FakeBackend())
    sender.progress.running = True
    await sender.pause()
    assert sender.progress.operator_paused
    assert not sender._pause.is_set()
    await sender.cycle_start()
    assert not sender.progress.operator_paused


async def test_the_idle_tools_are_refused_while_the_program_runs() -> None:
    broker = Broker()
    sender = Sender(cast(DaemonClient, broker), FakeBackend())
    OperatorRemote(sender, cast(DaemonClient, broker), program="p.nc")
    sender.progress.running = True
    answer = await broker.press("jog_z", {"transaction": 1, "mm": 1})
    assert answer["error"] == "jog_z: the program is running (pause or stop it first)"
    assert ("jog_z", {"mm": 1}) not in broker.args
    sender.progress.running = False
    assert (await broker.press("probe_test", {"transaction": 2}))["status"] == "ok"
    assert ("probe_test", {}) in broker.args


async def test_the_path_is_published_once_per_program_for_the_panels_preview() -> None:
    broker = Broker()
    sender = Sender(cast(DaemonClient, broker), FakeBackend())
    remote = OperatorRemote(sender, cast(DaemonClient, broker), program="/jobs/part.nc")
    plan = ProgramPlan([*PROGRAM[:5], "G3 X30 Y10 I10 J0 F3000", *PROGRAM[6:]], Dialect.MASSO, {})
    sender.path = build_path(plan)
    publishing = asyncio.create_task(remote.publish_progress())
    await asyncio.sleep(0.5)
    publishing.cancel()
    paths = [doc for leaf, doc, _ in broker.published if leaf == "sender/path"]
    assert len(paths) == 1
    path = paths[0]
    assert path["program"] == "part.nc"
    cut = [m for m in path["moves"] if m["cut"] == 0]
    assert cut[0]["line"] == 6
    assert len(cut[0]["points"]) > 10  # the arc, as points
    # Counter-clockwise from (10, 10) about (20, 10): under its centre, down to y 0.
    assert min(p[1] for p in cut[0]["points"]) < 0.1
    assert path["bounds"][0] == 0.0


def test_the_summary_after_a_resume_counts_the_whole_program() -> None:
    first = SendReport(cuts_started=2, cut_lines=[5, 12], lines_run={1, 2, 5, 6, 12},
                       error="paused: paused by the operator", error_line=13)  # fmt: skip
    resumed = SendReport(cuts_started=2, cut_lines=[12, 20], lines_run={12, 13, 20, 21})
    whole = _merged(first, resumed)
    assert whole.ok
    assert whole.cuts_started == 3
    assert whole.cut_lines == [5, 12, 20]
    assert whole.lines_run == {1, 2, 5, 6, 12, 13, 20, 21}


def test_an_interactive_console_says_each_message_once() -> None:
    out = io.StringIO()
    sender = Sender(cast(DaemonClient, FakeDaemon()), FakeBackend())
    console = OperatorConsole(sender, out=out, interactive=True)
    console._say("re-armed")
    assert out.getvalue().count("re-armed") == 1


async def test_a_hold_from_the_controllers_own_button_is_a_pause_that_ends_the_cut() -> None:
    """grbl's feed-hold button (or a door switch) holds the motion without the sender: the
    torch must not burn on at a standstill, so the sender pauses the cut as for p."""
    daemon, backend = CuttingDaemon(), SlowBackend()
    sender = Sender(cast(DaemonClient, daemon), backend)
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False, wait_operator=True)
    job = asyncio.ensure_future(console.run_job(PROGRAM, dialect=Dialect.MASSO))
    await until(lambda: sender.progress.line == 6, "the torch never reached the cut")
    backend.position = Where(60.0, 10.0, 0.0, True)  # held by the controller itself
    await until(lambda: console.paused is not None, "the held program never paused")
    assert ("thc_hold", {"on": True}) in daemon.args
    assert console.operator_stop
    await console.press("q")
    await asyncio.wait_for(job, 5.0)


async def test_a_program_with_no_cut_and_codes_nobody_knows_is_refused_before_it_moves() -> None:
    """As check-program: a shop's M10/M11 torch codes unmapped would run the motion with
    the torch never lit; the sender names them and the --code mapping instead."""
    backend = FakeBackend()
    sender = Sender(cast(DaemonClient, FakeDaemon()), backend)
    report = await sender.run(["G21", "G0 X1", "M10", "G1 X5 F100", "M11"], dialect=Dialect.RELAY)
    assert report.error_line == 3
    assert report.error.startswith("M10: not a code the daemon knows")
    assert "--code M10=M3 --code M11=M5" in report.error
    assert backend.queued == []  # nothing moved


async def test_the_rearm_key_rearms_the_daemon_and_is_refused_while_a_program_runs() -> None:
    daemon = CuttingDaemon()
    sender = Sender(cast(DaemonClient, daemon), FakeBackend())
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False)
    await console.press("a")
    assert ("rearm", {}) in daemon.args
    assert console.messages == ["re-armed"]
    sender.progress.running = True
    await console.press("a")
    assert daemon.args.count(("rearm", {})) == 1
    assert "a program is running or paused" in console.messages[-1]


async def test_at_the_end_the_line_is_the_files_last_and_the_count_is_the_files() -> None:
    """The console's line n/N: N is the file's line count (comments and blanks included)
    and a finished program stands at N, not at the last line that moved."""
    program = [*PROGRAM, "", "(end of the job)"]
    sender = Sender(cast(DaemonClient, CuttingDaemon()), FakeBackend())
    report = await sender.run(program, dialect=Dialect.MASSO)
    assert report.ok, report.error
    assert sender.progress.total_lines == len(program) == 11
    assert sender.progress.line == 11
