"""What the sender does with each line: plasma to the daemon, motion to the backend."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import pytest

from dthc_tools.sender import DaemonClient, Sender


class FakeDaemon:
    """Records the lines the sender sends to the daemon; answers every one with ok."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def on_event(self, handler: Callable[[dict[str, Any]], None]) -> None:
        pass

    def on_offline(self, handler: Callable[[], None]) -> None:
        pass

    async def gcode(
        self, line: str, *, line_number: int | None = None, xy: tuple[float, float] | None = None
    ) -> dict[str, Any]:
        self.lines.append(line)
        return {}


class FakeBackend:
    """Records the motion lines queued; always idle at the origin."""

    def __init__(self) -> None:
        self.queued: list[str] = []

    async def queue(self, line: str) -> None:
        self.queued.append(line)

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


async def _send(program: list[str]) -> tuple[FakeDaemon, FakeBackend]:
    daemon, backend = FakeDaemon(), FakeBackend()
    report = await Sender(cast(DaemonClient, daemon), backend).run(program)
    assert report.ok, report.error
    return daemon, backend


@pytest.mark.parametrize("line", ["G21 G90", "N1 G21", "G17 (plane)", "g21g90", "G94 ; feed/min"])
async def test_modal_only_lines_go_nowhere(line: str) -> None:
    """Lines of only plane, unit, distance and feed-mode codes are neither queued nor sent."""
    daemon, backend = await _send([line])
    assert backend.queued == []
    assert daemon.lines == []


@pytest.mark.parametrize(
    ("line", "motion", "to_daemon"),
    [
        ("G1 X10 F1500", "G1 X10 F1500", True),
        ("N7 G01X10F1500 (compact)", "G01X10F1500", True),
        ("G1 X10", "G1 X10", False),
        ("G0 Z20 ; safe", "G0 Z20", False),
    ],
)
async def test_motion_is_queued_and_lines_with_a_feed_also_go_to_the_daemon(
    line: str, motion: str, to_daemon: bool
) -> None:
    """The backend gets the motion text; the daemon gets it too when it carries an F word."""
    daemon, backend = await _send([line])
    assert backend.queued == [motion]
    assert daemon.lines == ([motion] if to_daemon else [])


async def test_a_velocity_reduction_scales_the_feed_the_machine_runs() -> None:
    """After M67 E3 Q50 the backend runs half the feed; the daemon still sees the program's."""
    daemon, backend = await _send(
        ["M67 E3 Q50", "G1 X10 F1500", "G1X20f3000Y5", "G1 X30", "M67 E3 Q0", "G1 X40 F1500"]
    )
    assert backend.queued == [
        "G1 X10 F750.0", "G1X20F1500.0Y5", "G1 X30", "G1 X40 F1500",
    ]  # fmt: skip
    assert daemon.lines == [
        "M67 E3 Q50",
        "G1 X10 F1500",
        "G1X20f3000Y5",
        "M67 E3 Q0",
        "G1 X40 F1500",
    ]
