"""The operator's side of the sender: cycle start after a G200 S1 stop, pause, stop, torch
up/down, and a restart from a resume point or the start of the failed cut."""

from __future__ import annotations

import asyncio
import io
from collections.abc import Callable
from typing import Any, cast

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.program.plan import MotionStep
from dthc_tools.sender import DaemonClient, Sender
from dthc_tools.sender.backend import BackendError
from dthc_tools.sender.console import OperatorConsole
from dthc_tools.sender.daemon_client import DaemonError
from dthc_tools.sender.sender import RestartPosition, SendReport
from tests.sender.test_sender_lines import FakeBackend, FakeDaemon

S1_PROGRAM = [
    "G21 G90", "T112 M6", "G200 F300 P3.8 D300 C1.5 V0 A90 O1 S1",
    "G0 X10 Y10", "M3", "G1 X50 F3000", "M5",
    "G0 X10 Y60", "M3", "G1 X50 F3000", "M5", "M30",
]  # fmt: skip


class S1Daemon(FakeDaemon):
    """An M3 is answered only after cycle start, as the daemon does in a G200 S1 stop."""

    def __init__(self) -> None:
        super().__init__()
        self.handlers: list[Callable[[dict[str, Any]], None]] = []
        self.released = asyncio.Event()
        self.args: list[tuple[str, dict[str, Any]]] = []

    def on_event(self, handler: Callable[[dict[str, Any]], None]) -> None:
        self.handlers.append(handler)

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        self.args.append((name, args))
        if name == "cycle_start":
            self.released.set()
        return await super().request(name, **args)

    async def gcode(self, line: str, **kwargs: Any) -> dict[str, Any]:
        answer = await super().gcode(line, **kwargs)
        if line == "M3":
            self.released.clear()
            for handler in self.handlers:
                handler({"type": "pause", "cause": "stop_after_pierce", "reason": "S1"})
            await asyncio.wait_for(self.released.wait(), 2.0)
        return answer


async def waiting(sender: Sender) -> None:
    """Until the sender shows an S1 stop (a flag the console polls too)."""
    for _ in range(200):
        if sender.progress.waiting_cycle_start:
            return
        await asyncio.sleep(0.01)
    raise AssertionError("no S1 stop within 2 s")


async def test_yes_cycle_start_runs_a_g200_s1_program_to_its_end_and_says_where() -> None:
    daemon = S1Daemon()
    sender = Sender(cast(DaemonClient, daemon), FakeBackend(), auto_cycle_start=True)
    report = await sender.run(S1_PROGRAM, dialect=Dialect.MASSO)
    assert report.ok, report.error
    assert report.cycle_starts == [5, 9]  # the two M3 lines
    assert report.cut_lines == [5, 9]
    assert sender.progress.cut == sender.progress.total_cuts == 2


async def test_without_an_operator_an_s1_stop_waits_and_a_key_releases_it() -> None:
    daemon = S1Daemon()
    sender = Sender(cast(DaemonClient, daemon), FakeBackend())
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False)
    job = asyncio.ensure_future(console.run_job(S1_PROGRAM, dialect=Dialect.MASSO))
    for _ in range(2):
        await waiting(sender)
        assert "waiting for cycle start" in console.status_line()
        await console.press("c")
    report = await job
    assert report.ok, report.error
    assert report.cycle_starts == [5, 9]


async def test_pause_holds_motion_and_thc_and_cycle_start_resumes() -> None:
    daemon, backend = S1Daemon(), FakeBackend()
    calls: list[str] = []

    async def hold() -> None:
        calls.append("hold")

    async def resume() -> None:
        calls.append("resume")

    backend.hold, backend.resume = hold, resume  # type: ignore[method-assign]
    sender = Sender(cast(DaemonClient, daemon), backend)
    sender.progress.running = True
    await sender.pause()
    assert sender.progress.operator_paused
    await sender.cycle_start()
    assert calls == ["hold", "resume"]
    assert [a for a in daemon.args if a[0] == "thc_hold"] == [
        ("thc_hold", {"on": True}), ("thc_hold", {"on": False}),
    ]  # fmt: skip
    await sender.torch(+1.0)
    await sender.torch(-1.0)
    assert daemon.args[-2:] == [("torch_up", {"volts": 1.0}), ("torch_down", {"volts": 1.0})]


async def test_stop_ends_the_program_with_the_daemon_aborting_the_cut() -> None:
    daemon = S1Daemon()
    sender = Sender(cast(DaemonClient, daemon), FakeBackend())
    job = asyncio.ensure_future(sender.run(S1_PROGRAM, dialect=Dialect.MASSO))
    await waiting(sender)
    await sender.stop()
    daemon.released.set()  # the daemon answers the M3 (with its abort error, here ok)
    report = await job
    assert not report.ok
    assert "stopped by the operator" in report.error
    assert ("abort", {}) in daemon.args
    assert report.error_line == 5


def test_the_restart_line_is_the_last_resume_point_or_the_failed_cuts_start() -> None:
    report = SendReport(error="arc lost", error_line=14, cut_lines=[5, 12], resume_points=[3])
    assert report.restart_line == 12
    report.resume_points = [3, 13]
    assert report.restart_line == 13
    assert SendReport(error="x", error_line=2, cut_lines=[5]).restart_line is None
    assert SendReport().restart_line is None


def test_a_restart_goes_to_where_the_skipped_lines_end_in_their_units_and_mode() -> None:
    position = RestartPosition()
    for line in ["G20 G90", "G0 X1 Y2", "G1 X3 F60", "G91", "G1 Y0.5"]:
        position.skip(MotionStep(line, 1, line))
    assert position.lines() == ["G20 G90", "G0 X3.0000 Y2.5000", "G1F60", "G91"]
    assert position.lines() == []  # once


async def test_a_restart_from_a_line_positions_xy_first() -> None:
    daemon, backend = FakeDaemon(), FakeBackend()
    program = ["G21 G90", "G0 X10 Y10", "M3", "G1 X50 F3000", "M5", "G0 X70 Y80", "M3",
               "G1 X90 F2000", "M5"]  # fmt: skip
    report = await Sender(cast(DaemonClient, daemon), backend).run(
        program, start_line=7, dialect=Dialect.MASSO
    )
    assert report.ok, report.error
    assert backend.queued[:3] == ["G21 G90", "G0 X70.0000 Y80.0000", "F3000"]  # G0 in force
    assert daemon.lines[0] == "M3"


async def test_a_failing_key_is_shown_not_raised() -> None:
    class Refusing(FakeDaemon):
        async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
            raise DaemonError(f"{name}: nothing waits for cycle start (idle)")

    sender = Sender(cast(DaemonClient, Refusing()), FakeBackend())
    sender.progress.waiting_cycle_start = sender.progress.running = True
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False)
    await console.press("c")
    assert console.messages == ["c: cycle_start: nothing waits for cycle start (idle)"]


@pytest.mark.parametrize("line", [1, 6])
def test_the_status_line_shows_progress(line: int) -> None:
    sender = Sender(cast(DaemonClient, FakeDaemon()), FakeBackend())
    sender.progress.line, sender.progress.total_lines = line, 12
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False)
    console.telemetry.update(
        {"voltage_v": 118.25, "target_v": 117.0, "z_mm": 22.26, "height_mm": 1.5,
         "state": "cutting"}
    )  # fmt: skip
    text = console.status_line()
    assert f"line {line}/12" in text
    assert "arc  118.2 V, target 117.0 V" in text
    assert "height  1.50 mm" in text  # above the plate, not machine Z
    assert "22.26" not in text
    assert "cutting" in text
    assert text.count("#") == round(line / 12 * 20)


async def test_a_feed_key_without_a_feed_override_says_so() -> None:
    sender = Sender(cast(DaemonClient, FakeDaemon()), FakeBackend())
    console = OperatorConsole(sender, out=io.StringIO(), interactive=False)
    await console.press(">")
    assert console.messages == [">: this motion backend has no feed override"]


async def test_a_daemon_pause_holds_the_motion_at_once_not_when_the_loop_looks() -> None:
    """The loop may wait for room in grbl's buffer for seconds: the hold must not."""
    daemon, backend = S1Daemon(), FakeBackend()
    held = asyncio.Event()

    async def hold() -> None:
        held.set()

    backend.hold = hold  # type: ignore[method-assign]
    Sender(cast(DaemonClient, daemon), backend)
    for handler in daemon.handlers:
        handler({"type": "arc_lost", "reason": "arc lost"})
    await asyncio.wait_for(held.wait(), 1.0)


@pytest.mark.parametrize(
    ("skipped", "restart"),
    [
        # The work offset and the motion mode come back (a modal X60 after it is a cut).
        (["G55 G90 G1 X10 Y10 F2000", "X50"], ["G21 G90 G55", "G0 X50.0000 Y10.0000", "G1F2000"]),
        # Millimetres kept when the program changes units.
        (["G20 G90 G0 X1", "G21 G0 Y10"], ["G21 G90", "G0 X25.4000 Y10.0000"]),
        # An origin line's X and Y are no target.
        (["G90 G0 X5 Y5", "G10 L20 P1 X0 Y0", "G92 X1 Y1"], ["G21 G90", "G0 X5.0000 Y5.0000"]),
    ],
)
def test_a_restart_keeps_what_the_skipped_lines_set(skipped: list[str], restart: list[str]) -> None:
    position = RestartPosition()
    for n, line in enumerate(skipped, start=1):
        position.skip(MotionStep(line, n, line))
    assert position.lines() == restart


def test_an_incremental_program_from_an_unknown_start_cannot_be_restarted() -> None:
    position = RestartPosition()
    position.skip(MotionStep("G91 G1 X10 F100", 3, "G91 G1 X10 F100"))
    with pytest.raises(BackendError, match="line 3 moves incrementally from an unknown start"):
        position.lines()


async def test_a_sender_stopping_on_its_own_ends_the_cut_too() -> None:
    """A line grbl refuses mid-cut: the motion is held and the daemon told to abort at once,
    so the torch does not burn at a standstill while the operator reads the error."""

    class Refusing(FakeBackend):
        async def queue(self, line: str, *, source_line: int | None = None) -> None:
            if "X50" in line:
                raise BackendError("grbl refused line 6: error:20", line_number=source_line)
            await super().queue(line, source_line=source_line)

    daemon = S1Daemon()
    sender = Sender(cast(DaemonClient, daemon), Refusing(), auto_cycle_start=True)
    report = await sender.run(S1_PROGRAM, dialect=Dialect.MASSO)
    assert report.error_line == 6
    assert ("abort", {}) in daemon.args
    assert report.restart_line == 5  # the start of the cut it happened in


async def test_a_failed_m3_restarts_from_itself_not_the_cut_before() -> None:
    class FailingSecondM3(S1Daemon):
        m3 = 0

        async def gcode(self, line: str, **kwargs: Any) -> dict[str, Any]:
            if line == "M3":
                self.m3 += 1
                if self.m3 == 2:
                    raise DaemonError("M3: arc not established")
            return await super().gcode(line, **kwargs)

    sender = Sender(cast(DaemonClient, FailingSecondM3()), FakeBackend(), auto_cycle_start=True)
    report = await sender.run(S1_PROGRAM, dialect=Dialect.MASSO)
    assert report.error_line == 9
    assert report.restart_line == 9


async def test_keys_from_a_terminal_reach_the_sender_in_order_and_the_terminal_is_restored(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The console on a real terminal (a pty): cbreak mode, each key handled in order (an
    arrow key's escape bytes do not swallow the next key), the modes restored after."""
    import os
    import pty
    import termios

    master, slave = pty.openpty()
    terminal = os.fdopen(slave, "r")
    monkeypatch.setattr("sys.stdin", terminal)
    before = termios.tcgetattr(slave)
    daemon = S1Daemon()
    sender = Sender(cast(DaemonClient, daemon), FakeBackend())
    console = OperatorConsole(sender, out=io.StringIO(), interactive=True)
    job = asyncio.ensure_future(console.run_job(S1_PROGRAM, dialect=Dialect.MASSO))
    try:
        for _ in range(2):
            await waiting(sender)
            os.write(master, b"\x1b[A+c")  # an arrow key, torch up, cycle start
            for _ in range(100):
                if not sender.progress.waiting_cycle_start:
                    break
                await asyncio.sleep(0.01)
        report = await asyncio.wait_for(job, 5)
        assert report.ok, report.error
        assert report.cycle_starts == [5, 9]
        assert [name for name, _ in daemon.args].count("torch_up") == 2
        assert termios.tcgetattr(slave) == before
    finally:
        job.cancel()
        terminal.close()
        os.close(master)


async def test_the_height_keys_step_the_cut_height_by_a_tenth() -> None:
    daemon = S1Daemon()
    console = OperatorConsole(
        Sender(cast(DaemonClient, daemon), FakeBackend()), out=io.StringIO(), interactive=False
    )
    await console.press("u")
    await console.press("d")
    assert [a for a in daemon.args if a[0] == "height_override"] == [
        ("height_override", {"mm": 0.1}), ("height_override", {"mm": -0.1}),
    ]  # fmt: skip
