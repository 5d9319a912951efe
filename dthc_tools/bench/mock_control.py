"""The mock board's control port (``dthc-mock --gantry-listen``) as the benches use it:
its fault ops, one JSON line per request and per reply (``mock_device/gantry_server.py``).

The sender's ``SimGantryBackend`` speaks the same port for motion; this client is for the
ops a motion backend has no business with (bytes injected into the host link, frame loss)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

__all__ = ["MockControl", "mock_control"]


class MockControl:
    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._reader = reader
        self._writer = writer

    async def request(self, op: str, **args: Any) -> dict[str, Any]:
        """The reply to ``op``; RuntimeError with the mock's reason when it refuses."""
        self._writer.write(json.dumps({"op": op, **args}).encode() + b"\n")
        await self._writer.drain()
        reply: dict[str, Any] = json.loads(await self._reader.readline())
        if not reply.get("ok"):
            raise RuntimeError(f"the mock refused {op}: {reply.get('error')}")
        return reply


@asynccontextmanager
async def mock_control(port: int) -> AsyncIterator[MockControl]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        yield MockControl(reader, writer)
    finally:
        writer.close()
