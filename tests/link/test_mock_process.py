"""The link layer against the mock board as its own process on a real pty (pyserial)."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

import firmware_protocol as fp
from dthc_bridge.board import BoardClient
from dthc_bridge.link import LinkState, LinkSupervisor, LinkTiming
from dthc_tools.procs import die_with_parent

pytestmark = pytest.mark.slow

TIMING = LinkTiming(ack_timeout_s=0.05, lease_ms=150, backoff_initial_s=0.05, backoff_max_s=0.2)


class ProcessRig:
    def __init__(self, proc: subprocess.Popen[str], pty: Path) -> None:
        self.proc = proc
        self.pty = pty
        self.states: list[tuple[str, str]] = []
        self.supervisor = LinkSupervisor(str(pty), TIMING)
        self.supervisor.add_state_listener(lambda c: self.states.append((str(c.state), c.reason)))
        self.client = BoardClient(self.supervisor)

    async def wait_state(self, state: LinkState, within_s: float) -> None:
        for _ in range(round(within_s / 0.01)):
            if self.supervisor.state is state:
                return
            await asyncio.sleep(0.01)
        raise AssertionError(f"state {self.supervisor.state}, wanted {state}: {self.states}")


@pytest.fixture
async def rig(tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[ProcessRig]:
    pty = tmp_path / "dthc0"
    extra: list[str] = getattr(request, "param", [])
    proc = subprocess.Popen(  # noqa: ASYNC220 - the test needs the Popen handle for signals
        [sys.executable, "-m", "mock_device", "--pty", str(pty), "--seed", "4",
         "--unplug-for", "0.4", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        preexec_fn=die_with_parent(),
    )  # fmt: skip
    assert proc.stdout is not None
    assert (await asyncio.to_thread(proc.stdout.readline)).startswith("READY")
    rig = ProcessRig(proc, pty)
    task = asyncio.create_task(rig.supervisor.run(), name="supervisor")
    try:
        yield rig
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        proc.send_signal(signal.SIGTERM)
        await asyncio.to_thread(proc.wait, 5)
        proc.stdout.close()


async def test_unplug_and_replug_mid_stream(rig: ProcessRig) -> None:
    """The pty master closes mid-stream: offline, every waiter fails, then back online."""
    await rig.supervisor.wait_online(5.0)
    await rig.client.torch(True)
    batches_before = rig.supervisor.stats.telemetry_batches
    rig.proc.send_signal(signal.SIGUSR1)
    await rig.wait_state(LinkState.OFFLINE, 2.0)
    await rig.supervisor.wait_online(5.0)
    assert rig.supervisor.stats.reconnects >= 1
    # While unplugged the board's lease ran out: torch off, fault latched, reported on return.
    status = await rig.client.status()
    assert status.faults & (1 << fp.FaultCode.LEASE_EXPIRED)
    assert not status.status & fp.StatusBit.TORCH_ON
    await asyncio.sleep(0.1)
    assert rig.supervisor.stats.telemetry_batches > batches_before


async def test_board_reboot_is_detected_and_resynced(rig: ProcessRig) -> None:
    """SIGUSR2 reboots the board: a new boot id, a board_rebooted state change, a new session."""
    first = await rig.supervisor.wait_online(5.0)
    old_boot = first.boot_id
    rig.proc.send_signal(signal.SIGUSR2)
    for _ in range(300):
        session = rig.supervisor.session
        if session is not first and rig.supervisor.state is LinkState.ONLINE:
            break
        await asyncio.sleep(0.01)
    again = await rig.supervisor.wait_online(3.0)
    assert again is not first
    assert again.boot_id != old_boot
    assert ("offline", "board_rebooted") in rig.states
    status = await rig.client.status()
    assert status.boot_id == again.boot_id


@pytest.mark.parametrize("rig", [["--stall-acks-at", "0.6", "--stall-for", "0.12"]], indirect=True)
async def test_stalled_acks_are_survived(rig: ProcessRig) -> None:
    """The board withholds replies for 120 ms: requests retransmit and still complete."""
    await rig.supervisor.wait_online(5.0)
    for _ in range(40):
        await rig.client.status()
        await asyncio.sleep(0.02)
    assert rig.supervisor.stats.retransmits >= 1
    assert rig.supervisor.state is LinkState.ONLINE


async def test_device_that_appears_later_is_picked_up(tmp_path: Path) -> None:
    """Started before the board exists (cable not plugged), the link comes up when it does."""
    pty = tmp_path / "late0"
    supervisor = LinkSupervisor(str(pty), TIMING)
    task = asyncio.create_task(supervisor.run(), name="supervisor")
    proc: subprocess.Popen[bytes] | None = None
    try:
        await asyncio.sleep(0.4)
        assert supervisor.state is not LinkState.ONLINE
        assert "No such file" in supervisor.last_error or "could not open" in supervisor.last_error
        proc = subprocess.Popen(  # noqa: ASYNC220 - the test needs the Popen handle
            [sys.executable, "-m", "mock_device", "--pty", str(pty)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=die_with_parent(),
        )  # fmt: skip
        session = await supervisor.wait_online(8.0)
        assert session.info is not None
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        if proc is not None:
            proc.send_signal(signal.SIGTERM)
            await asyncio.to_thread(proc.wait, 5)
