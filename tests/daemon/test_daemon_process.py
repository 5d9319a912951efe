"""The daemon process end to end: MQTT in, the mock board's torch and Z out, and its exits."""

from __future__ import annotations

import asyncio
import json
import signal
import time
import uuid
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from tests.mqtt.conftest import Broker
from tests.mqtt.helpers import Probe, open_probe, unique_base

from .conftest import STARTUP_S, Daemon, MockBoard, daemon_config, wait_until

pytestmark = pytest.mark.slow

SETUP = ["T112 M6", "G200 F300 P3.8 D300 C1.5 V125 A90 O1 S0", "M667 F600"]


class Stack:
    def __init__(self, daemon: Daemon, mock: MockBoard, probe: Probe, base: str) -> None:
        self.daemon = daemon
        self.mock = mock
        self.probe = probe
        self.base = base
        self.n = 0
        self.run_id = uuid.uuid4().hex[:6]  # transactions unique per sender run (exactly-once)

    def topic(self, leaf: str) -> str:
        return f"{self.base}/t1/{leaf}"

    async def gcode(self, line: str, timeout_s: float = 20.0) -> dict[str, Any]:
        self.n += 1
        transaction = f"{self.run_id}-tx{self.n}"
        start = len(self.probe.messages)
        await self.probe.publish_json(
            self.topic("request/gcode"), {"line": line, "transaction": transaction}
        )
        return await self.probe.wait_json(
            self.topic("response/gcode"), lambda d: d.get("transaction") == transaction,
            timeout_s, start,
        )  # fmt: skip

    async def online(self) -> None:
        await self.probe.wait_json(
            self.topic("board"), lambda d: d.get("state") == "online", STARTUP_S
        )
        await self.probe.wait_json(
            self.topic("availability"), lambda d: d.get("state") == "online", STARTUP_S
        )


@pytest.fixture
async def stack(tmp_path: Path, own_broker: Broker, mock_board: MockBoard) -> AsyncIterator[Stack]:
    base = unique_base()
    daemon = Daemon(tmp_path, daemon_config(mock_board.pty, own_broker, base))
    try:
        async with open_probe(own_broker, f"{base}/t1/#") as probe:
            stack = Stack(daemon, mock_board, probe, base)
            await stack.online()
            yield stack
    finally:
        daemon.close()


async def start_cut(stack: Stack) -> None:
    for line in SETUP:
        reply = await stack.gcode(line)
        assert reply["status"] == "ok", reply
    reply = await stack.gcode("M3")
    assert reply["status"] == "ok", (reply, stack.daemon.output()[-3000:])


async def test_gcode_over_mqtt_runs_a_cut_on_the_mock_board(stack: Stack) -> None:
    """T112 M6, G200, M3 answered at cut height (state 'cutting'), M5 back to idle."""
    await start_cut(stack)
    state = await stack.probe.wait_json(stack.topic("state"), lambda d: d.get("state") == "cutting")
    assert state["plasma_mode"] is True
    assert state["params"]["cut_height_mm"] == 1.5
    bad = await stack.gcode("G200 Q5")
    assert bad["status"] == "error"
    assert "G200 Q" in bad["error"]
    reply = await stack.gcode("M5")
    assert reply["status"] == "ok", reply
    await stack.probe.wait_json(stack.topic("state"), lambda d: d.get("state") == "idle")
    report = stack.mock.stop()
    assert report["torch_on"] is False
    assert report["violations"] == {}


async def test_sigterm_mid_cut_turns_the_torch_off_and_exits_within_a_second(
    stack: Stack,
) -> None:
    """SIGTERM with the arc on: torch off on the board, availability offline, exit < 1 s."""
    await start_cut(stack)
    start = len(stack.probe.messages)
    t0 = time.monotonic()
    stack.daemon.signal(signal.SIGTERM)
    code = await asyncio.to_thread(stack.daemon.wait, 5.0)
    elapsed = time.monotonic() - t0
    assert code == 0, stack.daemon.output()[-2000:]
    assert elapsed < 1.0
    await stack.probe.wait_json(
        stack.topic("availability"), lambda d: d.get("state") == "offline", 3.0, start
    )
    report = stack.mock.stop()
    assert report["torch_on"] is False
    assert report["violations"] == {}


async def test_kill_9_mid_cut_the_will_says_offline_and_the_lease_drops_the_torch(
    stack: Stack,
) -> None:
    """kill -9: the broker publishes the last will; the board's lease turns the torch off."""
    await start_cut(stack)
    start = len(stack.probe.messages)
    stack.daemon.signal(signal.SIGKILL)
    await asyncio.to_thread(stack.daemon.wait, 5.0)
    await stack.probe.wait_json(
        stack.topic("availability"), lambda d: d.get("state") == "offline", 5.0, start
    )
    await asyncio.sleep(0.5)  # well past the 200 ms lease
    report = stack.mock.stop()
    assert report["torch_on"] is False
    assert int(report["faults"], 16) & 0x0001  # LEASE_EXPIRED latched
    assert report["violations"] == {}


async def test_broker_restart_mid_cut_the_cut_goes_on_and_state_is_republished(
    tmp_path: Path, own_broker: Broker, mock_board: MockBoard
) -> None:
    """The broker goes away mid-cut: the arc stays on (THC is local); state comes back."""
    base = unique_base()
    daemon = Daemon(tmp_path, daemon_config(mock_board.pty, own_broker, base))
    try:
        async with open_probe(own_broker, f"{base}/t1/#") as probe:
            stack = Stack(daemon, mock_board, probe, base)
            await stack.online()
            await start_cut(stack)
        own_broker.stop()
        await asyncio.sleep(1.0)
        assert daemon.proc.poll() is None
        own_broker.start()
        async with open_probe(own_broker, f"{base}/t1/#") as probe:
            stack = Stack(daemon, mock_board, probe, base)
            state = await probe.wait_json(stack.topic("state"), timeout_s=STARTUP_S)
            assert state["state"] == "cutting"  # the cut went on without the broker
            reply = await stack.gcode("M5")
            assert reply["status"] == "ok", reply
        report = mock_board.stop()
        assert report["violations"] == {}
    finally:
        daemon.close()


async def test_malformed_requests_get_errors_and_change_nothing(stack: Stack) -> None:
    """Garbage and unknown words are answered with errors; the state stays idle."""
    start = len(stack.probe.messages)
    await stack.probe.client.publish(stack.topic("request/gcode"), b"{not json", qos=1)
    reply = await stack.probe.wait_json(stack.topic("response/gcode"), timeout_s=5.0, start=start)
    assert reply["status"] == "error"
    bad = await stack.gcode("G100 P2 A1 B100")
    assert "not a plasma function" in bad["error"]
    state = await stack.probe.wait_json(stack.topic("state"))
    assert state["state"] == "idle"


async def test_daemon_notifies_systemd_ready_and_watchdog(
    tmp_path: Path, own_broker: Broker, mock_board: MockBoard
) -> None:
    """Under a fake NOTIFY_SOCKET: READY=1 once set up, then WATCHDOG=1 about every 100 ms."""
    from tests.deploy.notify_socket import FakeNotifySocket

    with FakeNotifySocket() as notify:
        daemon = Daemon(
            tmp_path, daemon_config(mock_board.pty, own_broker, unique_base()),
            env=notify.env(watchdog_usec=200_000),
        )  # fmt: skip
        try:
            await asyncio.to_thread(lambda: notify.wait_for("READY=1", timeout_s=10.0))
            await asyncio.sleep(0.6)
            pings = notify.times_of("WATCHDOG=1")
            assert len(pings) >= 4
        finally:
            daemon.signal(signal.SIGTERM)
            await asyncio.to_thread(daemon.wait, 5.0)
            daemon.close()


async def test_a_daemon_stalled_while_idle_is_not_a_fault_to_rearm(stack: Stack) -> None:
    """SIGSTOP past the 200 ms lease with nothing lit (a CPU spike as a browser starts):
    the board reports the lapse and latches nothing, the daemon logs it, and the next cut
    runs with no re-arm. Stalled mid-cut instead, the lease latches as it always did."""
    for line in SETUP:
        assert (await stack.gcode(line))["status"] == "ok"
    stack.daemon.signal(signal.SIGSTOP)
    await asyncio.sleep(0.6)
    stack.daemon.signal(signal.SIGCONT)
    deadline = time.monotonic() + 5.0
    while "lease_lapsed_idle" not in stack.daemon.output():
        assert time.monotonic() < deadline, stack.daemon.output()[-3000:]
        await asyncio.sleep(0.05)
    reply = await stack.gcode("M3")
    assert reply["status"] == "ok", reply  # no "re-arm required"
    stack.daemon.signal(signal.SIGSTOP)  # now mid-cut: the lease latches
    await asyncio.sleep(0.6)
    stack.daemon.signal(signal.SIGCONT)
    await asyncio.sleep(0.5)
    refused = await stack.gcode("M3")
    assert "re-arm required after: board fault: LEASE_EXPIRED" in refused["error"], refused


async def test_a_daemon_told_to_home_homes_a_board_that_booted_wrong_then_cuts(
    tmp_path: Path, own_broker: Broker
) -> None:
    """[board.homing] mode = "required", a board whose firmware took Z as 45 mm at power-on
    with the carriage at 60: the daemon homes it once online (its log says how far homing
    moved Z: +15 mm) and the cut that follows starts."""
    mock = MockBoard(tmp_path, "--boot-z-mm", "45")
    base = unique_base()
    config = daemon_config(mock.pty, own_broker, base) + (
        '\n[board.homing]\nmode = "required"\nseek_mm_s = 40.0\nlocate_mm_s = 4.0\n'
    )
    daemon = Daemon(tmp_path, config)
    try:
        async with open_probe(own_broker, f"{base}/t1/#") as probe:
            stack = Stack(daemon, mock, probe, base)
            await stack.online()
            homed = await asyncio.to_thread(
                wait_until, lambda: '"event": "homed"' in daemon.output(), 20.0
            )
            assert homed, daemon.output()[-3000:]
            line = next(x for x in daemon.output().splitlines() if '"event": "homed"' in x)
            assert json.loads(line)["shift_mm"] == pytest.approx(15.0, abs=0.01)
            await start_cut(stack)
            await stack.gcode("M5")
    finally:
        daemon.close()
        mock.proc.kill()
        mock.proc.communicate(timeout=5)
