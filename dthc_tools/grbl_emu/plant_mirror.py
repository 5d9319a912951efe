"""Mirror the emulator's motion onto the mock board's gantry (its JSON-lines port).

The mock board simulates the arc from where its gantry is; when a grbl emulator moves the
table, the mock's gantry must move the same way. Every line the emulator plans, and every
hold, resume and clear, is sent to ``mock_device``'s gantry port (``--gantry-listen``) as
``{"op": "line", "gcode": ...}`` and friends, in order.

Never blocks the emulator: operations go into a queue that a writer task drains, and a
reader task consumes the replies (counting refusals). A queue that stays full (the mock is
gone) drops operations and counts them.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
from types import TracebackType

__all__ = ["PlantMirror", "PlantMirrorError"]

QUEUE_MAX_OPS = 100_000
CONNECT_TIMEOUT_S = 5.0
DRAIN_TIMEOUT_S = 2.0


class PlantMirrorError(ConnectionError):
    """The plant's gantry port could not be reached."""


class PlantMirror:
    """``async with PlantMirror(host, port) as mirror: mirror.submit({...})``."""

    def __init__(self, host: str, port: int) -> None:
        self.host = host
        self.port = port
        self.sent = 0
        self.refused = 0
        self.dropped = 0
        self._queue: asyncio.Queue[dict[str, str]] = asyncio.Queue(QUEUE_MAX_OPS)
        self._writer: asyncio.StreamWriter | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._unanswered = 0
        self._answered = asyncio.Event()

    async def __aenter__(self) -> PlantMirror:
        try:
            reader, writer = await asyncio.wait_for(
                asyncio.open_connection(self.host, self.port), CONNECT_TIMEOUT_S
            )
        except (OSError, TimeoutError) as exc:
            raise PlantMirrorError(f"plant {self.host}:{self.port}: {exc}") from exc
        self._writer = writer
        self._tasks = [
            asyncio.create_task(self._write_loop(writer), name="plant-mirror-writer"),
            asyncio.create_task(self._read_loop(reader), name="plant-mirror-reader"),
        ]
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        # Let what is queued reach the plant (the last moves of a program matter).
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._drain(), DRAIN_TIMEOUT_S)
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, ConnectionError):
                await task
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(ConnectionError):
                await self._writer.wait_closed()

    async def _drain(self) -> None:
        await self._queue.join()
        reader = self._tasks[1]
        while self._unanswered > 0 and not reader.done():
            self._answered.clear()
            await self._answered.wait()

    def submit(self, op: dict[str, str]) -> None:
        """Queue one operation; never waits."""
        try:
            self._queue.put_nowait(op)
        except asyncio.QueueFull:
            self.dropped += 1

    async def _write_loop(self, writer: asyncio.StreamWriter) -> None:
        while True:
            op = await self._queue.get()
            try:
                writer.write(json.dumps(op).encode() + b"\n")
                self._unanswered += 1
                self.sent += 1
                await writer.drain()
            finally:
                self._queue.task_done()

    async def _read_loop(self, reader: asyncio.StreamReader) -> None:
        while line := await reader.readline():
            self._unanswered -= 1
            self._answered.set()
            try:
                ok = bool(json.loads(line).get("ok"))
            except (ValueError, AttributeError):
                ok = False
            if not ok:
                self.refused += 1
                print(
                    json.dumps({"event": "plant_refused", "reply": line.decode(errors="replace")}),
                    file=sys.stderr,
                    flush=True,
                )
        self._answered.set()

    def stats(self) -> dict[str, int]:
        """Counts for the exit line."""
        return {"sent": self.sent, "refused": self.refused, "dropped": self.dropped}
