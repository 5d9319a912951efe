"""The gantry's control port: how a sender's ``sim`` motion backend drives the mock's XY.

JSON lines over TCP, one request per line, one reply per request:

    {"op": "line", "gcode": "G1 X10 Y5 F3000"}  -> {"ok": true, "queued": 3}
    {"op": "wait_idle"}                          -> {"ok": true, "x": .., "y": ..} when idle
    {"op": "hold"} / {"op": "resume"} / {"op": "clear"}
    {"op": "status"}     -> {"ok": true, "x", "y", "speed_mm_s", "idle", "queued"}
    {"op": "inject", "hex": "00a1..."}  -> {"ok": true, "bytes": n}: raw bytes to the host,
                            as if from the board's UART (the fuzz bench's frames)
    {"op": "drop_frames", "rate": 0.01, "for_s": 10}  -> {"ok": true}: lose that share of the
                            board's frames for a while (the fault bench)
    {"op": "input", "name": "estop", "on": true}  -> {"ok": true}: hold a board input active
                            (true) or inactive (false) whatever the plant's physics says;
                            "on": null hands it back to the physics. Names: arc_ok, ohmic,
                            float, breakaway, thc_up, thc_down, estop, z_limit_min,
                            z_limit_max. The board sees it at its pin, as a real switch: it
                            shows in SAMPLES, EVENT and STATUS input bits, a forced E-stop or
                            breakaway latches its fault (and FAULT_RESET is refused while it
                            is held), a forced float or ohmic contact stops a probe, a forced
                            arc OK counts for ARC_LOST. Ohmic contact shows only while ohmic
                            sensing is on, as on a real board. A forced Z limit switch acts
                            as on the reference firmware (the mock runs its board logic): it
                            stops motion towards it at once, and latches Z_LIMIT when Z was
                            driven into it.

A bad line or op gets {"ok": false, "error": "..."} and changes nothing.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable
from typing import Any

from .plant.gantry import GcodeError
from .plant.inputs import InputBit
from .plant.plant import Plant

__all__ = ["INPUT_NAMES", "GantryServer"]

MAX_LINE = 4096
#: The inputs the ``input`` op can hold, by their names on the wire (PROTOCOL.md §7).
INPUT_NAMES: dict[str, int] = {str(bit.name).lower(): int(bit) for bit in InputBit}


class GantryServer:
    def __init__(
        self,
        plant: Plant,
        host: str,
        port: int,
        *,
        inject: Callable[[bytes], int] | None = None,
        drop_frames: Callable[[float, float], None] | None = None,
    ) -> None:
        self.plant = plant
        self.inject = inject  # raw bytes to the host, as the board's UART would send them
        self.drop_frames = drop_frames  # (rate, seconds): a flaky cable for a while
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.Task[None]] = set()

    @property
    def bound_port(self) -> int:
        assert self._server is not None
        port: int = self._server.sockets[0].getsockname()[1]
        return port

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._client, self.host, self.port)

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            for task in list(self._clients):
                task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.gather(*self._clients, return_exceptions=True)
            await self._server.wait_closed()
            self._server = None

    def _force_input(self, request: dict[str, Any]) -> dict[str, Any]:
        name = request.get("name")
        if not isinstance(name, str) or name not in INPUT_NAMES:
            return {
                "ok": False,
                "error": f"input: unknown name {json.dumps(name)} "
                f"(one of {', '.join(INPUT_NAMES)})",
            }
        if "on" not in request:
            return {"ok": False, "error": "input: 'on' is missing (true, false or null)"}
        on = request["on"]
        if on is not None and not isinstance(on, bool):
            return {
                "ok": False,
                "error": f"input: 'on' must be true, false or null, not {json.dumps(on)}",
            }
        self.plant.force_input(INPUT_NAMES[name], on)
        return {"ok": True}

    def _status(self) -> dict[str, Any]:
        g = self.plant.gantry
        return {
            "ok": True,
            "x": round(g.x_mm, 4),
            "y": round(g.y_mm, 4),
            "speed_mm_s": round(g.speed_mm_s, 3),
            "idle": g.idle,
            "queued": g.queue_len,
        }

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._clients.add(task)
        try:
            while line := await reader.readline():
                reply = await self._handle(line[:MAX_LINE])
                writer.write(json.dumps(reply).encode() + b"\n")
                await writer.drain()
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self._clients.discard(task)
            writer.close()

    async def _handle(self, raw: bytes) -> dict[str, Any]:
        try:
            request = json.loads(raw)
            op = request["op"]
        except (ValueError, KeyError, TypeError):
            return {"ok": False, "error": "expected a JSON object with an 'op'"}
        gantry = self.plant.gantry
        if op == "inject" and self.inject is not None:
            try:
                data = bytes.fromhex(str(request.get("hex", "")))
            except ValueError:
                return {"ok": False, "error": "inject: 'hex' is not hexadecimal"}
            return {"ok": True, "bytes": self.inject(data)}
        if op == "drop_frames" and self.drop_frames is not None:
            try:
                rate, for_s = float(request["rate"]), float(request["for_s"])
                self.drop_frames(rate, for_s)
            except (KeyError, TypeError, ValueError) as exc:
                return {"ok": False, "error": f"drop_frames: {exc}"}
            return {"ok": True}
        if op == "input":
            return self._force_input(request)
        if op == "line":
            try:
                queued = gantry.feed_line(str(request.get("gcode", "")))
            except GcodeError as exc:
                return {"ok": False, "error": str(exc)}
            return {"ok": True, "queued": queued}
        if op == "wait_idle":
            # The gantry is stepped by the board's sample ticks; poll it at 200 Hz.
            while not gantry.idle:  # noqa: ASYNC110 - no event to wait on in the plant
                await asyncio.sleep(0.005)
            return self._status()
        if op == "hold":
            gantry.hold()
        elif op == "resume":
            gantry.resume()
        elif op == "clear":
            gantry.clear()
        elif op != "status":
            return {"ok": False, "error": f"unknown op {op!r}"}
        return self._status()
