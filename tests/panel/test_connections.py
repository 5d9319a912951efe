"""The panel's connections on a real socket: a request's head has a deadline (a slow sender
is closed, an idle keep-alive too, a live stream is not), a body too; at the connection cap
the longest-waiting connection makes room, or the newcomer gets 503; running out of file
descriptors is one log line, not a traceback per retry."""

from __future__ import annotations

import asyncio
import errno
import os
import subprocess
import sys
import textwrap
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp import web
from structlog.testing import capture_logs

from dthc_tools.panel.connections import ConnectionPool, OutOfDescriptorsLog, start_guarded_site
from dthc_tools.panel.server import PanelLimits, build_app
from tests.panel.test_server import RecordingHub

ROOT = Path(__file__).parents[2]
HEAD_TIMEOUT_S = 0.4
GET_VIEW = b"GET /api/view HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"


class Panel:
    def __init__(self, server: asyncio.Server, pool: ConnectionPool) -> None:
        self.server = server
        self.pool = pool
        self.port: int = server.sockets[0].getsockname()[1]

    async def connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        return await asyncio.open_connection("127.0.0.1", self.port)


async def _serve(**limits: Any) -> AsyncIterator[Panel]:
    values = {"header_timeout_s": HEAD_TIMEOUT_S, "body_timeout_s": HEAD_TIMEOUT_S, **limits}
    panel_limits = PanelLimits(**values)
    app = build_app(RecordingHub(), token=None, limits=panel_limits)
    runner = web.AppRunner(app, access_log=None, shutdown_timeout=0.5)
    await runner.setup()
    server, pool = await start_guarded_site(runner, "127.0.0.1", 0, panel_limits.connections)
    try:
        yield Panel(server, pool)
    finally:
        server.close()
        await runner.cleanup()
        await server.wait_closed()


@pytest.fixture
async def panel() -> AsyncIterator[Panel]:
    async for served in _serve():
        yield served


async def _closed_after_s(reader: asyncio.StreamReader, timeout_s: float) -> float:
    """Seconds until the panel closes the connection (everything it sent is discarded)."""
    start = time.monotonic()
    async with asyncio.timeout(timeout_s):
        try:
            while await reader.read(4096):
                pass
        except ConnectionResetError:
            pass
    return time.monotonic() - start


async def test_a_slow_header_sender_is_closed_within_the_timeout(panel: Panel) -> None:
    """A request line then a header byte every 50 ms, never the blank line: closed once
    HEADER_TIMEOUT_S has passed since the connection opened, however busy it keeps."""
    reader, writer = await panel.connect()
    writer.write(b"GET /api/view HTTP/1.1\r\nHost: 127.0.0.1\r\n")

    async def trickle() -> None:
        while True:
            writer.write(b"X")
            await asyncio.sleep(0.05)

    dripping = asyncio.create_task(trickle())
    try:
        closed_s = await _closed_after_s(reader, 5 * HEAD_TIMEOUT_S)
    finally:
        dripping.cancel()
        writer.close()
    assert 0.8 * HEAD_TIMEOUT_S <= closed_s <= HEAD_TIMEOUT_S + 0.3
    assert panel.pool.head_timeouts == 1


async def test_a_silent_connection_and_an_idle_keepalive_are_closed(panel: Panel) -> None:
    """Nothing sent at all; or one request answered, then nothing: each closed by the same
    deadline, counted from the connection or from the answer."""
    silent_reader, silent = await panel.connect()
    reader, writer = await panel.connect()
    writer.write(GET_VIEW)
    head = await reader.readuntil(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 200")
    assert await _closed_after_s(silent_reader, 5 * HEAD_TIMEOUT_S) <= HEAD_TIMEOUT_S + 0.3
    assert await _closed_after_s(reader, 5 * HEAD_TIMEOUT_S) <= HEAD_TIMEOUT_S + 0.3
    silent.close()
    writer.close()


async def test_a_live_stream_outlasts_the_head_deadline(panel: Panel) -> None:
    """The deadline is the head's: a stream whose head came at once stays open."""
    reader, writer = await panel.connect()
    writer.write(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    assert (await reader.readuntil(b"\r\n\r\n")).startswith(b"HTTP/1.1 200")
    await asyncio.sleep(3 * HEAD_TIMEOUT_S)
    assert not reader.at_eof()
    assert panel.pool.head_timeouts == 0
    writer.close()


async def test_a_slow_body_gets_408_within_the_body_timeout(panel: Panel) -> None:
    reader, writer = await panel.connect()
    writer.write(
        b"POST /api/control/torch_up HTTP/1.1\r\nHost: 127.0.0.1\r\nX-DTHC-Panel: 1\r\n"
        b"Content-Type: application/json\r\nContent-Length: 10\r\n\r\n{}"
    )
    start = time.monotonic()
    answer = await asyncio.wait_for(reader.read(4096), 5 * HEAD_TIMEOUT_S)
    assert answer.startswith(b"HTTP/1.1 408")
    assert b"BODY_TIMEOUT_S" in answer
    assert time.monotonic() - start <= HEAD_TIMEOUT_S + 0.3
    writer.close()


async def test_at_the_cap_the_longest_waiting_connection_makes_room() -> None:
    """Three connections allowed: a fourth closes the one that waited longest for a head and
    is served; when all three are busy streams, a newcomer is answered 503."""
    async for panel in _serve(max_connections=3, header_timeout_s=30.0):
        idle = [await panel.connect() for _ in range(3)]
        await asyncio.sleep(0.05)
        reader, writer = await panel.connect()
        writer.write(GET_VIEW)
        assert (await reader.readuntil(b"\r\n\r\n")).startswith(b"HTTP/1.1 200")
        assert await _closed_after_s(idle[0][0], 1.0) < 1.0  # the oldest made room
        assert panel.pool.evicted == 1
        for _, w in (*idle, (reader, writer)):
            w.close()
        await asyncio.sleep(0.05)

        streams = []
        for _ in range(3):
            r, w = await panel.connect()
            w.write(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            assert (await r.readuntil(b"\r\n\r\n")).startswith(b"HTTP/1.1 200")
            streams.append(w)
        late_reader, late = await panel.connect()
        answer = await asyncio.wait_for(late_reader.read(4096), 1.0)
        assert answer.startswith(b"HTTP/1.1 503")
        assert panel.pool.refused == 1
        for w in (*streams, late):
            w.close()


def test_out_of_descriptors_is_one_line_per_period() -> None:
    """A thousand EMFILE reports from the accept loop: one warning with their count; any
    other exception still reaches the handler that was there before."""
    passed: list[dict[str, Any]] = []
    handler = OutOfDescriptorsLog(lambda _loop, context: passed.append(context), period_s=60.0)
    loop = asyncio.new_event_loop()
    try:
        with capture_logs() as logs:
            for _ in range(1000):
                handler(loop, {"message": "accept", "exception": OSError(errno.EMFILE, "x")})
            handler(loop, {"message": "other", "exception": RuntimeError("a bug")})
    finally:
        loop.close()
    assert [entry["event"] for entry in logs] == ["panel_out_of_file_descriptors"]
    assert logs[0]["error"] == "EMFILE"
    assert handler.total == 1000
    assert [context["message"] for context in passed] == ["other"]


PANEL_WITH_FEW_FDS = textwrap.dedent(
    """
    import asyncio, resource, sys
    from aiohttp import web
    from dthc_bridge.logs import configure_logging
    from dthc_tools.panel.connections import start_guarded_site
    from dthc_tools.panel.server import PanelLimits, build_app
    from tests.panel.test_server import RecordingHub

    async def main():
        configure_logging("info", json=True)
        hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
        resource.setrlimit(resource.RLIMIT_NOFILE, (48, hard))
        limits = PanelLimits(max_connections=500)  # above the descriptors: accept() fails
        runner = web.AppRunner(build_app(RecordingHub(), token=None, limits=limits))
        await runner.setup()
        server, _ = await start_guarded_site(runner, "127.0.0.1", 0, limits.connections)
        print(server.sockets[0].getsockname()[1], flush=True)
        await asyncio.sleep(3.0)
        server.close()
        await runner.cleanup()

    asyncio.run(main())
    """
)


async def test_running_out_of_descriptors_logs_one_line_not_tracebacks() -> None:
    """A panel process with 48 descriptors and 120 connections held open for three seconds:
    accept() fails with EMFILE at every retry; stderr has one warning and no traceback."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", PANEL_WITH_FEW_FDS, cwd=ROOT, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert proc.stdout is not None
    held = []
    try:
        port = int(await proc.stdout.readline())
        for _ in range(120):
            held.append((await asyncio.open_connection("127.0.0.1", port))[1])
        _out, raw_err = await asyncio.wait_for(proc.communicate(), 20)
        err = raw_err.decode()
    finally:
        for writer in held:
            writer.close()
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    warnings = [line for line in err.splitlines() if "panel_out_of_file_descriptors" in line]
    assert len(warnings) == 1, err
    assert '"error": "EMFILE"' in warnings[0]
