"""A board device that cannot be opened (unplugged at start, a wrong path, a folder): the
log says so once per distinct OS error with the path, and the board's state carries the
OS's words, while the retries go on quietly until the device is there."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, MutableMapping, Sequence
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
import structlog

from dthc_bridge.link import LinkState, LinkSupervisor, LinkTiming
from dthc_bridge.transport import (
    BytesCallback,
    LinkUnavailable,
    LostCallback,
    Transport,
    TransportOpener,
    open_transport,
)
from mock_device.sim import SimulatedBoard

from .board_harness import RealtimeSimBoard

FAST = LinkTiming(
    ack_timeout_s=0.03, lease_ms=200, backoff_initial_s=0.005, backoff_max_s=0.01,
    handshake_timeout_s=0.1,
)  # fmt: skip


class Counting:
    """An opener that counts its attempts before handing over to ``inner``."""

    def __init__(self, inner: TransportOpener) -> None:
        self.inner = inner
        self.attempts = 0
        self._attempted = asyncio.Event()

    async def __call__(self, on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
        self.attempts += 1
        self._attempted.set()
        return await self.inner(on_bytes, on_lost)

    async def wait_attempts(self, count: int, timeout_s: float = 5.0) -> None:
        async with asyncio.timeout(timeout_s):
            while self.attempts < count:
                self._attempted.clear()
                await self._attempted.wait()


def serial_opener(path: Path) -> TransportOpener:
    async def opener(on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
        return await open_transport(str(path), on_bytes, on_lost)

    return opener


@asynccontextmanager
async def supervising(
    opener: Counting, url: str
) -> AsyncIterator[tuple[LinkSupervisor, list[tuple[LinkState, str]]]]:
    supervisor = LinkSupervisor(url, FAST, opener=opener)
    states: list[tuple[LinkState, str]] = []
    supervisor.add_state_listener(lambda change: states.append((change.state, change.reason)))
    task = asyncio.create_task(supervisor.run(), name="supervisor")
    try:
        yield supervisor, states
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task


def events(logs: Sequence[MutableMapping[str, Any]], name: str) -> list[dict[str, Any]]:
    return [dict(entry) for entry in logs if entry["event"] == name]


async def test_a_missing_device_is_logged_once_with_path_and_os_error(tmp_path: Path) -> None:
    """The tester's probe: a missing /dev/dthc0 was only reported as "closed by the host"
    at every retry. Now: one warning naming the path and the OS error however many
    retries, the state offline with the OS's words, and no flicker through connecting."""
    device = tmp_path / "dthc0"
    opener = Counting(serial_opener(device))
    with structlog.testing.capture_logs() as logs:
        async with supervising(opener, str(device)) as (supervisor, states):
            await opener.wait_attempts(6)
    [warning] = events(logs, "board_link_unavailable")
    assert warning == {
        "event": "board_link_unavailable",
        "log_level": "warning",
        "path": str(device),
        "error": "[Errno 2] No such file or directory",
    }
    reason = f"cannot open {device}: No such file or directory"
    assert states[:2] == [(LinkState.CONNECTING, "connecting"), (LinkState.OFFLINE, reason)]
    assert (LinkState.CONNECTING, "connecting") not in states[2:]  # not at every retry
    assert supervisor.last_error == reason
    assert events(logs, "link_lost") == []  # nothing was "closed by the host"
    assert all("closed by the host" not in str(entry) for entry in logs)


async def test_each_distinct_error_is_logged_and_published_once(tmp_path: Path) -> None:
    """The path missing, then a folder in its place, then missing again: three warnings,
    one per change of what the OS says, and the state's reason follows each."""
    device = tmp_path / "dthc0"
    opener = Counting(serial_opener(device))
    with structlog.testing.capture_logs() as logs:
        async with supervising(opener, str(device)) as (_, states):
            await opener.wait_attempts(3)
            device.mkdir()
            await opener.wait_attempts(opener.attempts + 3)
            device.rmdir()
            await opener.wait_attempts(opener.attempts + 3)
    errors = [entry["error"] for entry in events(logs, "board_link_unavailable")]
    assert errors == [
        "[Errno 2] No such file or directory",
        "[Errno 21] Is a directory",
        "[Errno 2] No such file or directory",
    ]
    offline = [reason for state, reason in states if state is LinkState.OFFLINE]
    assert offline == [
        f"cannot open {device}: No such file or directory",
        f"cannot open {device}: Is a directory",
        f"cannot open {device}: No such file or directory",
    ]


async def test_a_device_that_appears_brings_the_link_online() -> None:
    """Unavailable twice, then the board is there: online, as before."""
    sim = RealtimeSimBoard(SimulatedBoard("flat_clean", seed=7))

    async def plugged_late(on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
        if opener.attempts <= 2:
            raise LinkUnavailable("/dev/dthc0", "No such file or directory", 2)
        return await sim.opener(on_bytes, on_lost)

    opener = Counting(plugged_late)
    async with sim.running(), supervising(opener, "/dev/dthc0") as (supervisor, states):
        await supervisor.wait_online(5.0)
    assert [state for state, _ in states[:3]] == [
        LinkState.CONNECTING,
        LinkState.OFFLINE,
        LinkState.ONLINE,
    ]
