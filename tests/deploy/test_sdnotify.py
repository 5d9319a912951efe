"""sd_notify: readiness reaches systemd's socket, the watchdog pings from the event loop."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import os
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

from dthc_bridge.deploy.sdnotify import SdNotifier

from .notify_socket import FakeNotifySocket
from .watchdog_child import BLOCK_S

REPO_ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 5.0


def test_ready_reaches_a_socket_file(notify_socket: FakeNotifySocket) -> None:
    """READY=1 arrives on a path NOTIFY_SOCKET, sent by this process."""
    with SdNotifier.from_env(notify_socket.env()) as notifier:
        assert notifier.enabled
        assert notifier.ready()
        got = notify_socket.wait_for("READY=1", timeout_s=WAIT_S)
    assert got.message == "READY=1"
    assert got.pid == os.getpid()


def test_ready_reaches_an_abstract_socket(abstract_notify_socket: FakeNotifySocket) -> None:
    """A leading @ in NOTIFY_SOCKET means the abstract namespace."""
    assert abstract_notify_socket.address.startswith("@")
    with SdNotifier.from_env(abstract_notify_socket.env()) as notifier:
        assert notifier.ready(status="board offline")
        got = abstract_notify_socket.wait_for("READY=1", timeout_s=WAIT_S)
    assert got.assignments == {"READY": "1", "STATUS": "board offline"}


def test_status_and_stopping_are_single_datagrams(notify_socket: FakeNotifySocket) -> None:
    """STATUS= is folded onto one line; STOPPING=1 is sent as is."""
    with SdNotifier.from_env(notify_socket.env()) as notifier:
        notifier.status("link up\nmqtt up")
        notifier.stopping()
        notify_socket.wait_for("STOPPING=1", timeout_s=WAIT_S)
    assert notify_socket.messages() == ["STATUS=link up mqtt up", "STOPPING=1"]


async def test_without_notify_socket_everything_is_a_no_op() -> None:
    """Outside systemd nothing is sent, nothing fails, and the watchdog loop just returns."""
    notifier = SdNotifier.from_env({"WATCHDOG_USEC": "200000"})
    assert not notifier.enabled
    assert notifier.ready() is False
    assert notifier.watchdog() is False
    await asyncio.wait_for(notifier.watchdog_loop(), timeout=1)
    assert (notifier.sent, notifier.failed) == (0, 0)


async def test_watchdog_loop_returns_without_watchdog(notify_socket: FakeNotifySocket) -> None:
    """With a socket but no WATCHDOG_USEC there is nothing to feed."""
    with SdNotifier.from_env(notify_socket.env()) as notifier:
        assert notifier.watchdog_period_s() is None
        await asyncio.wait_for(notifier.watchdog_loop(), timeout=1)
        assert notifier.sent == 0


@pytest.mark.parametrize(
    ("env", "expected_s"),
    [
        ({"WATCHDOG_USEC": "200000"}, 0.1),
        ({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "4242"}, 5.0),
        ({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "4243"}, None),
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "ten"}, None),
        ({"WATCHDOG_USEC": "200000", "WATCHDOG_PID": "x"}, None),
        ({}, None),
    ],
)
def test_watchdog_period_is_half_the_timeout_for_our_pid(
    env: dict[str, str], expected_s: float | None
) -> None:
    """sd_watchdog_enabled(3): ping every half of WATCHDOG_USEC, only if WATCHDOG_PID is us."""
    notifier = SdNotifier.from_env({"NOTIFY_SOCKET": "/run/x", **env}, pid=4242)
    assert notifier.watchdog_period_s() == expected_s


def test_unreachable_socket_is_counted_not_raised(tmp_path: Path) -> None:
    """A notify socket that went away makes notify() return False; the daemon goes on."""
    with SdNotifier.from_env({"NOTIFY_SOCKET": str(tmp_path / "gone")}) as notifier:
        assert notifier.enabled
        assert notifier.ready() is False
        assert notifier.watchdog() is False
    assert (notifier.sent, notifier.failed) == (0, 2)


def test_non_unix_notify_socket_is_ignored() -> None:
    """vsock: addresses (VM managers) are not AF_UNIX: notification is off, not an error."""
    notifier = SdNotifier.from_env({"NOTIFY_SOCKET": "vsock:2:1234"})
    assert not notifier.enabled
    assert notifier.ready() is False


async def test_watchdog_loop_pings_every_half_timeout(notify_socket: FakeNotifySocket) -> None:
    """WATCHDOG_USEC=200000: WATCHDOG=1 about every 100 ms, the first one at once."""
    with SdNotifier.from_env(notify_socket.env(watchdog_usec=200_000)) as notifier:
        task = asyncio.create_task(notifier.watchdog_loop(), name="sd-watchdog")
        await asyncio.sleep(0.55)
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        sent = notifier.sent
    assert 5 <= sent <= 7
    notify_socket.wait_for("WATCHDOG=1", timeout_s=WAIT_S, count=sent)
    pings = notify_socket.times_of("WATCHDOG=1")
    intervals = [b - a for a, b in itertools.pairwise(pings)]
    assert 0.08 <= statistics.median(intervals) <= 0.15, intervals


def test_blocked_event_loop_stops_the_pings(notify_socket: FakeNotifySocket) -> None:
    """A daemon whose loop is blocked sends no WATCHDOG=1 until the loop runs again.

    The child marks the block with STATUS=blocking / STATUS=unblocked on the same socket.
    """
    env = {
        **os.environ,
        **notify_socket.env(watchdog_usec=200_000),
        "PYTHONPATH": str(REPO_ROOT),
    }
    with subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("watchdog_child.py"))],
        env=env, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    ) as proc:  # fmt: skip
        _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    notify_socket.wait_for("STOPPING=1", timeout_s=WAIT_S)

    ready = notify_socket.wait_for("READY=1", timeout_s=0)
    blocked_s = notify_socket.wait_for("STATUS=blocking", timeout_s=0).time_s
    unblocked_s = notify_socket.wait_for("STATUS=unblocked", timeout_s=0).time_s
    pings = notify_socket.times_of("WATCHDOG=1")
    before = [t for t in pings if t < blocked_s]
    during = [t for t in pings if blocked_s < t < unblocked_s]
    after = [t for t in pings if t > unblocked_s]

    assert notify_socket.messages()[0] == "READY=1"
    assert ready.pid == proc.pid
    assert {n.pid for n in notify_socket.notifications} == {proc.pid}  # NotifyAccess=main
    assert unblocked_s - blocked_s >= BLOCK_S - 0.05
    assert during == []
    assert len(before) >= 3
    assert 0.08 <= statistics.median(b - a for a, b in itertools.pairwise(before)) <= 0.2
    # The loop resumes pinging at once, then at the normal pace.
    assert len(after) >= 2
    assert after[0] - unblocked_s < 0.1
    assert after[0] - before[-1] >= BLOCK_S - 0.05
