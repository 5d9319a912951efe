"""What the sender does with each line: plasma to the daemon, motion to the backend."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_tools.sender import DaemonClient, Sender


class FakeDaemon:
    """Records the lines the sender sends to the daemon; answers every one with ok (an
    ``M190`` with the material's cut feed, 2500)."""

    def __init__(self, started: dict[str, Any] | None = None) -> None:
        self.lines: list[str] = []
        self.requests: list[str] = []
        self.dialects: set[str | None] = set()
        # program_start: material 0 (the default) is in force, feed 3000; the daemon's
        # configured dialect and code table (controller.dialect, controller.codes).
        self.started = {"material": 0, "cut_feed_mm_min": 3000.0, "dialect": "masso",
                        "codes": {}, **(started or {})}  # fmt: skip

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        self.requests.append(name)
        return dict(self.started) if name == "program_start" else {}

    def on_event(self, handler: Callable[[dict[str, Any]], None]) -> None:
        pass

    def on_offline(self, handler: Callable[[], None]) -> None:
        pass

    def on_telemetry(self, handler: Callable[[dict[str, Any]], None]) -> None:
        pass

    async def notify(self, name: str, /, **args: Any) -> None:
        pass

    async def gcode(
        self,
        line: str,
        *,
        line_number: int | None = None,
        xy: tuple[float, float] | None = None,
        dialect: str | None = None,
    ) -> dict[str, Any]:
        self.lines.append(line)
        self.dialects.add(dialect)
        return {"cut_feed_mm_min": 2500.0} if line.startswith("M190") else {}


class FakeBackend:
    """Records the motion lines queued; always idle at the origin."""

    def __init__(self) -> None:
        self.queued: list[str] = []

    async def queue(self, line: str, *, source_line: int | None = None) -> None:
        self.queued.append(line)

    def add_motion_listener(self, listener: Callable[[float, str], None]) -> None:
        pass

    async def wait_idle(self) -> tuple[float, float]:
        return 0.0, 0.0

    async def hold(self) -> None:
        pass

    async def clear(self) -> None:
        pass

    async def resume(self) -> None:
        pass

    async def close(self) -> None:
        pass


async def _send(
    program: list[str],
    dialect: Dialect | None = Dialect.MASSO,
    started: dict[str, Any] | None = None,
    **codes: str,
) -> tuple[FakeDaemon, FakeBackend]:
    daemon, backend = FakeDaemon(started), FakeBackend()
    report = await Sender(cast(DaemonClient, daemon), backend).run(
        program, dialect=dialect, codes=codes
    )
    assert report.ok, report.error
    assert daemon.requests == ["program_start", "program_end"]  # the end resets the override
    return daemon, backend


@pytest.mark.parametrize("line", ["G21 G90", "N1 G21", "G17 (plane)", "g21g90", "G94 ; feed/min"])
async def test_modal_only_lines_reach_the_motion_backend(line: str) -> None:
    """Units, distance mode and plane are the backend's state: a G91 must not be dropped."""
    daemon, backend = await _send([line])
    assert len(backend.queued) == 1
    assert daemon.lines == []


async def test_modal_words_beside_a_board_z_word_still_reach_the_motion_backend() -> None:
    """A preamble with G92.1, a probe or origin line with G20/G91: the units must not be
    lost, or the machine runs an inch program in millimetres."""
    program = ["N10 G20 G40 G90 G92.1", "G21 G92 Z-1.5", "G38.2 Z-2 F12"]
    daemon, backend = await _send(program, Dialect.RELAY)
    assert backend.queued == ["G20 G40 G90", "G92.1", "G21"]
    assert daemon.lines == ["G92.1", "G92 Z-1.5", "G38.2 Z-2 F12"]


async def test_an_incremental_program_runs_incremental() -> None:
    _daemon, backend = await _send(["G91", "G0 X10", "G0 X10"])
    assert backend.queued == ["G91", "G0 X10", "G0 X10"]


@pytest.mark.parametrize(
    ("line", "motion", "to_daemon"),
    [
        ("G1 X10 F1500", "G1 X10 F1500", ["G1 F1500"]),
        ("N7 G01X10F1500 (compact)", "G01X10F1500", ["G1 F1500"]),
        ("G0 X10", "G0 X10", []),
    ],
)
async def test_motion_is_queued_and_a_new_cutting_feed_is_noted_to_the_daemon(
    line: str, motion: str, to_daemon: list[str]
) -> None:
    """The backend gets the motion text; the daemon a feed note when the cutting feed changes."""
    daemon, backend = await _send([line])
    assert backend.queued == [motion]
    assert daemon.lines == to_daemon


async def test_z_goes_to_the_daemon_up_first_and_down_last() -> None:
    """Z belongs to the board; a mixed line never drags the torch. What is left of a Z-only
    line (its modal G0) still reaches the backend."""
    daemon, backend = await _send(["G0 Z5", "G0 X10 Y10 Z20", "G0 X50 Y5 Z3", "G0 Z20 ; safe"])
    assert backend.queued == ["G0", "G0 X10 Y10", "G0 X50 Y5", "G0"]
    assert daemon.lines == ["G0 Z5", "G0 Z20", "G0 Z3", "G0 Z20"]


async def test_inch_programs_reach_the_daemon_in_millimetres() -> None:
    daemon, backend = await _send(["G20", "G0 Z0.5", "G1 X2 F100", "G38.2 Z-2 F10"], Dialect.RELAY)
    assert backend.queued == ["G20", "G0", "G1 X2 F100"]
    assert daemon.lines == ["G0 Z12.7", "G1 F2540", "G38.2 Z-50.8 F254"]


async def test_a_tool_change_passes_its_feed_to_motion() -> None:
    _daemon, backend = await _send(["M06 T1 F5840"])
    assert backend.queued == ["F5840"]


async def test_masso_hash_is_a_comment_and_g4_is_milliseconds() -> None:
    _daemon, backend = await _send(["G0 X1 # rapid to start", "G4 P250"])
    assert backend.queued == ["G0 X1"]


async def test_plasmac_program_with_material_feed_and_stripped_z() -> None:
    """The material's feed replaces the HAL read; Z moves are stripped as PlasmaC does."""
    program = [
        "G21 G90", "T0 M6", "G43 H0", "M190 P3", "M66 P3 L3 Q1",
        "F#<_hal[plasmac.cut-feed-rate]>", "G0 Z10", "G0 X5 Y5", "M3 $0 S1",
        "G1 X50", "M5 $0",
    ]  # fmt: skip
    daemon, backend = await _send(program, Dialect.PLASMAC)
    assert "F2500" in backend.queued
    assert daemon.lines == ["T0 M6", "M190 P3", "M3 $0 S1", "G1 F2500", "M5 $0"]
    assert daemon.dialects == {"plasmac"}


async def test_the_cut_feed_before_any_m190_is_the_material_in_force_at_start() -> None:
    """PlasmaC's pin always reads the material in force; in the program's units."""
    feed = "F#<_hal[plasmac.cut-feed-rate]>"
    _daemon, backend = await _send(["T0 M6", feed, "G20", feed], Dialect.PLASMAC)
    assert backend.queued[:2] == ["F3000", "G20"]
    assert float(backend.queued[2][1:]) == pytest.approx(3000 / 25.4)


async def test_pierce_only_pierces_and_skips_the_cut() -> None:
    program = ["#<pierce-only> = 1", "G0 X5 Y5", "M3 $0 S1", "G1 X50 F3000", "M5 $0", "G0 X0"]
    daemon, backend = await _send(program, Dialect.PLASMAC)
    assert daemon.lines == ["M3 $0 S1", "M5 $0"]
    assert backend.queued == ["G0 X5 Y5", "G0 X0"]


TOUCH_OFF = ["G38.2 Z-40 F300", "G92 Z0"]  # a relay program touches off before its M3


async def test_shop_codes_map_to_the_daemon_commands() -> None:
    """FireControl's H1/H0 in the relay dialect; a shop's own code from the table."""
    program = [*TOUCH_OFF, "M3", "H1", "H0", "M5", "M101"]
    daemon, _ = await _send(program, Dialect.RELAY, M101="M666")
    assert daemon.lines == [*TOUCH_OFF, "M3", "M667", "M666", "M5", "M666"]


async def test_the_daemons_code_table_applies_and_the_senders_own_codes_win() -> None:
    started = {"codes": {"M10": "M3", "M11": "M5", "H7": "M667"}}
    daemon, _ = await _send([*TOUCH_OFF, "M10", "H7", "M11"], Dialect.RELAY, started, H7="M666")
    assert daemon.lines == [*TOUCH_OFF, "M3", "M666", "M5"]


async def test_a_program_with_nothing_dialect_specific_takes_the_daemons_dialect() -> None:
    # A plain program (Z moves and motion, no touch-off: in the relay dialect its M3 is
    # refused): its daemon lines go in the daemon's own dialect.
    program = ["G21 G90", "G0 Z3", "G1 X10 F2000", "G0 Z10"]
    daemon, _ = await _send(program, None, {"dialect": "relay"})
    assert daemon.dialects == {"relay"}
    daemon, _ = await _send(program, None, {"dialect": "plasmac"})
    assert daemon.dialects == {"plasmac"}


async def test_a_velocity_reduction_scales_the_feed_the_machine_runs() -> None:
    """After M67 E3 Q50 the backend runs half the feed; the daemon still sees the program's."""
    daemon, backend = await _send(
        ["M67 E3 Q50", "G1 X10 F1500", "G1X20f3000Y5", "G1 X30", "M67 E3 Q0", "G1 X40 F1500"]
    )
    assert backend.queued == [
        "G1 X10 F750.0", "G1X20F1500.0Y5", "G1 X30", "G1 X40 F1500",
    ]  # fmt: skip
    assert daemon.lines == ["M67 E3 Q50", "G1 F1500", "G1 F3000", "M67 E3 Q0", "G1 F1500"]


async def test_a_program_reading_hal_pins_is_counted_and_drawn_to_its_end() -> None:
    """The cuts and the path are listed ahead of the run; a program that reads the cut
    feed from a HAL pin (a SheetCam PlasmaC post) is listed past that line, as it runs."""
    program = ["G21 G90", "M190 P1", "M66 P3 L3 Q1", "F#<_hal[plasmac.cut-feed-rate]>",
               "G0 X10 Y10", "M3 $0 S1", "G1 X20", "M5 $0",
               "G0 X30", "M3 $0 S1", "G1 X40", "M5 $0", "M2"]  # fmt: skip
    daemon, backend = FakeDaemon(), FakeBackend()
    sender = Sender(daemon, backend)
    report = await sender.run(program, dialect=Dialect.PLASMAC)
    assert report.ok, report.error
    assert sender.progress.total_cuts == 2
    assert sender.path is not None
    last = sender.path.document("pins.ngc")["moves"][-1]
    assert (last["cut"], last["points"][-1]) == (1, [40.0, 10.0])
