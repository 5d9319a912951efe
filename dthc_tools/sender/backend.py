"""The motion backend seam: where a sender's XY motion lines go.

``sim`` drives the mock board's gantry over its control port. A real motion controller
(a grblHAL board, LinuxCNC over its Python API, a MASSO) plugs in by implementing the
same five verbs.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

__all__ = [
    "BackendError", "MotionBackend", "MotionListener", "Positioned", "SimGantryBackend", "Where",
]  # fmt: skip

MotionListener = Callable[[float, str], None]
"""Called with the measured XY speed (mm/s) and the controller's state, per status report."""


class BackendError(Exception):
    """The motion backend refused a line or is unreachable; ``line_number`` is the program
    line it refused, when the refusal names one."""

    def __init__(self, message: str, *, line_number: int | None = None) -> None:
        super().__init__(message)
        self.line_number = line_number


class MotionBackend(Protocol):
    async def queue(self, line: str, *, source_line: int | None = None) -> None:
        """Queue one motion line (G0/G1/G2/G3 ...); returns once accepted."""
        ...

    def add_motion_listener(self, listener: MotionListener) -> None:
        """Measured XY speed reports, for a board without an XY speed input."""
        ...

    async def wait_idle(self) -> tuple[float, float]:
        """Wait until every queued move is done; returns the XY position."""
        ...

    async def hold(self) -> None:
        """Feed hold: decelerate to a stop, keep the queue."""
        ...

    async def clear(self) -> None:
        """Drop queued motion (after an error, before a resume)."""
        ...

    async def resume(self) -> None:
        """Release a feed hold."""
        ...

    async def close(self) -> None: ...


@dataclass(frozen=True, slots=True)
class Where:
    """Where the motion controller says the torch is: XY in mm (work coordinates), its
    measured speed, and whether it holds (a feed hold: the operator's, or one of its own)."""

    x_mm: float
    y_mm: float
    speed_mm_s: float
    held: bool


@runtime_checkable
class Positioned(Protocol):
    """A backend that reports the torch's position (the console's line, the panel's
    marker) and can release a hold an earlier sender left behind."""

    async def where(self) -> Where | None:
        """The latest position (None before the controller reported one)."""
        ...

    async def release_stale_hold(self) -> None:
        """Before a program starts: a hold (and its queue) left by a sender that died is
        dropped, so the new program does not sit waiting for a cycle start."""
        ...


class SimGantryBackend:
    """JSON lines to the mock's gantry port (``dthc-mock --gantry-listen``)."""

    def __init__(self, host: str, port: int) -> None:
        self.host = host
        self.port = port
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lock = asyncio.Lock()

    async def connect(self) -> None:
        try:
            self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        except OSError as exc:
            raise BackendError(f"gantry {self.host}:{self.port}: {exc}") from None

    async def _call(self, **request: Any) -> dict[str, Any]:
        if self._writer is None or self._reader is None:
            await self.connect()
        assert self._writer is not None
        assert self._reader is not None
        async with self._lock:
            self._writer.write(json.dumps(request).encode() + b"\n")
            await self._writer.drain()
            line = await self._reader.readline()
        if not line:
            raise BackendError("gantry closed the connection")
        reply: dict[str, Any] = json.loads(line)
        if not reply.get("ok"):
            raise BackendError(str(reply.get("error", "refused")))
        return reply

    async def queue(self, line: str, *, source_line: int | None = None) -> None:
        try:
            await self._call(op="line", gcode=line)
        except BackendError as exc:
            raise BackendError(str(exc), line_number=source_line) from None

    def add_motion_listener(self, listener: MotionListener) -> None:
        """Nothing to report: the mock board measures the gantry's XY speed itself."""

    async def wait_idle(self) -> tuple[float, float]:
        # Its own connection: the wait may be cancelled (a pause), and a hold must not queue
        # behind it on the control connection.
        try:
            reader, writer = await asyncio.open_connection(self.host, self.port)
        except OSError as exc:
            raise BackendError(f"gantry {self.host}:{self.port}: {exc}") from None
        try:
            writer.write(b'{"op": "wait_idle"}\n')
            await writer.drain()
            line = await reader.readline()
        finally:
            writer.close()
        if not line:
            raise BackendError("gantry closed the connection")
        reply = json.loads(line)
        return float(reply["x"]), float(reply["y"])

    async def hold(self) -> None:
        await self._call(op="hold")

    async def where(self) -> Where | None:
        reply = await self._call(op="status")
        return Where(float(reply["x"]), float(reply["y"]), float(reply["speed_mm_s"]),
                     bool(reply.get("held", False)))  # fmt: skip

    async def release_stale_hold(self) -> None:
        await self.clear()
        await self.resume()

    async def clear(self) -> None:
        await self._call(op="clear")

    async def resume(self) -> None:
        await self._call(op="resume")

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            await self._writer.wait_closed()
            self._writer = None
