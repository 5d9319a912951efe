"""The grbl backend against the emulated grbl as its own process on a pty: identification,
character counting, ok/error/ALARM, hold/resume/clear, and what never reaches grbl."""

from __future__ import annotations

import asyncio
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from dthc_tools.sender.backend import BackendError
from dthc_tools.sender.grbl_backend import GrblBackend
from tests.grbl_emu.processes import exit_line, start_ready, stop

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]


class Grbl:
    """One emulator process; ``stats()`` stops it and returns its exit figures."""

    def __init__(self, tmp_path: Path, *args: str) -> None:
        self.pty = tmp_path / "grbl0"
        self.log = tmp_path / "grbl.log"
        self.proc, _ = start_ready(
            [sys.executable, "-m", "dthc_tools.grbl_emu", "--pty", str(self.pty), *args],
            self.log,
        )

    async def stats(self) -> dict[str, Any]:
        await asyncio.to_thread(stop, self.proc)
        return exit_line(self.log)

    def kill(self) -> None:
        stop(self.proc)


@pytest.fixture
async def grbl(tmp_path: Path) -> AsyncIterator[Callable[..., Grbl]]:
    started: list[Grbl] = []

    def start(*args: str) -> Grbl:
        started.append(Grbl(tmp_path, *args))
        return started[-1]

    yield start
    for emulator in started:
        emulator.kill()


async def connected(emulator: Grbl, **kwargs: Any) -> GrblBackend:
    backend = GrblBackend(str(emulator.pty), **kwargs)
    await backend.connect()
    return backend


SQUARES = [f"G1 X{x + 10:.3f} Y{y + 10:.3f} F6000" for x in range(0, 100, 10) for y in (0, 10)]


async def test_classic_grbl_is_identified_and_streamed_by_counting(grbl: Any) -> None:
    emulator = grbl()
    backend = await connected(emulator)
    assert backend.info.banner.startswith("Grbl 1.1f")
    assert (backend.info.planner_blocks, backend.info.rx_buffer) == (15, 128)
    speeds: list[tuple[float, str]] = []
    backend.add_motion_listener(lambda speed, state: speeds.append((speed, state)))
    for n, line in enumerate(["G21 G90 (metric)", *SQUARES], start=1):
        await backend.queue(line, source_line=n)
    assert await backend.wait_idle() == pytest.approx((100.0, 20.0))
    await backend.close()
    figures = backend.figures
    stats = await emulator.stats()
    assert stats["rx_overflow"] == 0
    # $I, the program, and wait_idle's G4P0 (its ok: the planner has emptied)
    assert stats["ok"] == stats["lines"] == 3 + len(SQUARES)
    assert stats["z_words_received"] == stats["spindle_words_received"] == 0
    assert 80 < figures.max_in_flight_bytes < 128  # lines really were streamed ahead
    assert any(state == "Run" and speed > 50.0 for speed, state in speeds)


async def test_grblhal_reports_its_larger_buffer_and_sync_mode_sends_one_at_a_time(
    grbl: Any,
) -> None:
    emulator = grbl("--flavor", "grblhal")
    backend = await connected(emulator, streaming="sync")
    assert backend.info.is_grblhal
    assert (backend.info.planner_blocks, backend.info.rx_buffer) == (35, 1024)
    for line in SQUARES[:6]:
        await backend.queue(line)
    await backend.wait_idle()
    longest = max(len(line.replace(" ", "")) + 1 for line in SQUARES[:6])
    assert backend.figures.max_in_flight_bytes == longest
    await backend.close()
    assert (await emulator.stats())["rx_overflow"] == 0


async def test_a_refused_line_holds_the_motion_and_names_the_line_and_the_reason(
    grbl: Any,
) -> None:
    emulator = grbl()
    backend = await connected(emulator)
    await backend.queue("G21 G90 G1 X50 Y0 F3000", source_line=1)
    await backend.queue("G38.9 X60", source_line=2)  # not a grbl command: error:20
    await backend.queue("G1 X200 Y0", source_line=3)  # streamed behind it: must not run on
    with pytest.raises(BackendError) as info:
        await backend.wait_idle()
    assert info.value.line_number == 2
    assert "error:20" in str(info.value)
    assert "G38.9X60" in str(info.value)
    assert "an unsupported or invalid G-code command" in str(info.value)
    await asyncio.sleep(0.3)
    assert backend.status is not None
    assert backend.status.state == "Hold"  # held at once, not run to X200
    await backend.clear()  # hold complete: no ALARM:3
    assert backend.status.state == "Idle"
    await backend.close()
    stats = await emulator.stats()
    assert stats["alarms"] == {}
    assert stats["x_mm"] < 200.0


async def test_z_and_spindle_words_never_reach_grbl(grbl: Any) -> None:
    emulator = grbl()
    backend = await connected(emulator)
    for line, word in (("G0 X1 Z5", "Z words"), ("M3 S1000", "M3"), ("G1 X2 S300 F100", "S300")):
        with pytest.raises(BackendError, match=word):
            await backend.queue(line, source_line=7)
    await backend.close()
    stats = await emulator.stats()
    assert stats["z_words_received"] == stats["spindle_words_received"] == 0


async def test_hold_stops_within_the_next_status_report_and_resume_goes_on(grbl: Any) -> None:
    """A daemon pause holds the motion within one status period: the ``!`` goes out at
    once, so the first report after it already shows the hold."""
    emulator = grbl()
    backend = await connected(emulator)
    await backend.queue("G21 G90 G1 X300 Y0 F3000")
    for _ in range(100):  # the status poll sees it running
        if backend.status is not None and backend.status.state == "Run":
            break
        await asyncio.sleep(0.01)
    seq = backend.figures.status_reports
    states: list[str] = []
    backend.add_motion_listener(lambda _speed, state: states.append(state))
    await backend.hold()
    assert states[0] == "Hold", states
    assert backend.figures.status_reports > seq
    held_at = backend.position
    await asyncio.sleep(0.3)
    assert backend.position == held_at
    await backend.resume()
    assert await backend.wait_idle() == pytest.approx((300.0, 0.0))
    await backend.close()


async def test_a_soft_limit_alarm_stops_the_program_and_a_clear_reports_it(grbl: Any) -> None:
    emulator = grbl("--max-travel", "500,500")
    backend = await connected(emulator)
    await backend.queue("G21 G90 G0 X900 Y10", source_line=4)
    with pytest.raises(BackendError, match="ALARM:2"):
        await backend.wait_idle()
    with pytest.raises(BackendError, match=r"ALARM:2|alarm"):
        await backend.queue("G0 X1")
    with pytest.raises(BackendError, match=r"still in alarm.*\$X"):
        await backend.clear()  # a restart must not begin on a locked machine
    await backend.close()


async def test_an_unexpected_reset_stops_the_program(grbl: Any) -> None:
    """A brownout or DTR reset loses G91, the feed and the queued motion: never carry on."""
    emulator = grbl()
    backend = await connected(emulator)
    await backend.queue("G21 G91 G1 X10 Y10 F3000")
    await backend.wait_idle()
    backend._write(b"\x18")  # as if the controller had rebooted by itself
    await asyncio.sleep(0.3)
    with pytest.raises(BackendError, match="reset unexpectedly"):
        await backend.queue("G1 X10 Y10")
    await backend.clear()  # the operator's re-arm: a reset we asked for is fine
    await backend.queue("G90 G0 X0 Y0")
    assert await backend.wait_idle() == pytest.approx((0.0, 0.0))
    await backend.close()


async def test_a_controller_in_alarm_is_refused_at_connect(grbl: Any) -> None:
    emulator = grbl()
    first = await connected(emulator)
    await first.queue("G21 G90 G1 X300 Y0 F3000")
    await asyncio.sleep(0.3)
    first._write(b"\x18")  # a reset in motion: ALARM:3, locked until $X
    await asyncio.sleep(0.3)
    await first.close()
    with pytest.raises(BackendError, match=r"alarm.*\$X"):
        await connected(emulator)


async def test_the_feed_override_keys_reach_grbl_as_real_time_bytes(grbl: Any) -> None:
    emulator = grbl()
    backend = await connected(emulator)
    for step in ("+10", "+10", "-1"):
        backend.feed_override(step)
    for _ in range(50):
        await asyncio.sleep(0.05)
        if backend.status is not None and backend.status.overrides == (119, 100, 100):
            break
    assert backend.status is not None
    assert backend.status.overrides == (119, 100, 100)
    backend.feed_override("reset")
    await asyncio.sleep(0.3)
    report = backend.status
    assert report.overrides is not None
    assert report.overrides[0] == 100
    await backend.close()
