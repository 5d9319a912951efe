"""Invariant 6: a bug while handling board data is a fault, never the end of the link.

The daemon's controller service, built as ``dthc-bridge run`` builds it, cuts against the
mock board as its own process, over a real pty and over TCP. Mid-cut the THC raises: the
link layer catches it at its boundary, logs it with its traceback, counts it, and the
service ends the cut through the fault path (torch off, pause, safe height), while the
link stays up on the same session.
"""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest
import structlog

import firmware_protocol as fp
from dthc_bridge.board import BoardClient
from dthc_bridge.config import ControllerSettings, default_controller_configs
from dthc_bridge.controller.sequence import State
from dthc_bridge.controller.thc import ThcController
from dthc_bridge.daemon import build_controller
from dthc_bridge.events import ControllerEvent, ProgramPaused
from dthc_bridge.link import LinkState, LinkSupervisor, LinkTiming
from dthc_bridge.service import ControllerService
from dthc_tools.procs import die_with_parent

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]

TIMING = LinkTiming(ack_timeout_s=0.05, lease_ms=250, backoff_initial_s=0.05, backoff_max_s=0.2)
PROGRAM = ("T112 M6", "G200 F300 P3.8 D300 C1.5 V125 A90 O1 S0", "M667 F3000", "M3")


class BuggyThc(ThcController):
    """The daemon's THC, with a bug that fires once, when armed mid-cut."""

    armed = False

    def filter(self, volts: Sequence[float], period_s: float, now: float) -> float:
        if self.armed:
            self.armed = False
            raise ZeroDivisionError("injected THC bug")
        return super().filter(volts, period_s, now)


@dataclass
class Rig:
    proc: subprocess.Popen[str]
    url: str


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@pytest.fixture(params=["pty", "tcp"])
async def board(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Rig]:
    if request.param == "pty":
        url = str(tmp_path / "dthc0")
        where = ["--pty", url]
    else:
        url = f"socket://127.0.0.1:{_free_port()}"
        where = ["--listen", url]
    proc = subprocess.Popen(  # noqa: ASYNC220 - the test owns the process for its lifetime
        [sys.executable, "-m", "mock_device", *where, "--scenario", "flat_clean", "--seed", "5"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        preexec_fn=die_with_parent(),
    )  # fmt: skip
    assert proc.stdout is not None
    assert (await asyncio.to_thread(proc.stdout.readline)).startswith("READY")
    try:
        yield Rig(proc, url)
    finally:
        proc.terminate()
        await asyncio.to_thread(proc.wait, 5)
        proc.stdout.close()


async def test_a_controller_that_raises_mid_cut_faults_the_cut_and_keeps_the_link(
    board: Rig,
) -> None:
    """The THC raises while cutting: one logged traceback, one counted error, the cut ends
    through the fault path within a batch or two, the board's torch is off, and the link
    is still up on its first session."""
    configs = default_controller_configs()
    controller, _ = build_controller(ControllerSettings())
    thc = BuggyThc(configs.thc)
    controller.sequence.thc = thc
    supervisor = LinkSupervisor(board.url, TIMING)
    client = BoardClient(supervisor)
    service = ControllerService(controller, supervisor, client)
    events: list[ControllerEvent] = []
    service.add_event_listener(events.append)
    tasks = [asyncio.create_task(supervisor.run()), asyncio.create_task(service.run())]
    try:
        await supervisor.wait_online(5.0)
        for line in PROGRAM:
            result = await service.execute_gcode(line)
            assert result.ok, (line, result.error)
        assert str(service.sequence.state) == State.CUTTING
        assert (await client.status()).status & fp.StatusBit.TORCH_ON
        with structlog.testing.capture_logs() as logs:
            thc.armed = True
            for _ in range(100):
                if service.sequence.state is State.FAULTED:
                    break
                await asyncio.sleep(0.005)
        assert service.sequence.state is State.FAULTED
        assert "internal error: ZeroDivisionError: injected THC bug" in service.sequence.error
        assert any(isinstance(e, ProgramPaused) and "internal error" in e.reason for e in events)
        failures = [entry for entry in logs if entry["event"] == "board_data_handler_failed"]
        assert len(failures) == 1
        assert failures[0]["exc_info"] is True  # rendered as a traceback by the pipeline
        assert service.diagnostics()["handler_errors"] == 1
        assert supervisor.stats.handler_errors == 1
        await asyncio.sleep(0.3)  # more batches arrive and are handled without a bug
        status = await client.status()
        assert not status.status & fp.StatusBit.TORCH_ON
        assert supervisor.state is LinkState.ONLINE
        assert supervisor.stats.handshakes == 1
        assert supervisor.stats.reconnects == 0
        assert supervisor.stats.telemetry_batches > 0
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
