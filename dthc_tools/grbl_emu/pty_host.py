"""The emulator as a real-time process on a pseudo-terminal.

The pty comes from the mock board's :class:`mock_device.links.PtyLink` (raw mode on both
ends, symlinked atomically at the requested path). Received bytes reach the firmware the
moment they arrive and its answers are written at once, so ``?`` is answered within a
millisecond; a timer wakes the firmware every ``TICK_S`` to run the planner on the measured
time. Events are JSON lines on stderr; the exit line carries the statistics tests assert on.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import sys
from pathlib import Path

from mock_device.links import PtyLink

from .firmware import GrblFirmware
from .plant_mirror import PlantMirror

__all__ = ["EmulatorHost", "log_event"]

TICK_S = 0.003  # wake-up period of the real-time loop
PARENT_CHECK_S = 0.25  # how often the loop asks whether its parent is still there


def log_event(event: str, **fields: object) -> None:
    """One JSON line on stderr."""
    print(json.dumps({"event": event, **fields}), file=sys.stderr, flush=True)


class EmulatorHost:
    """Runs one :class:`GrblFirmware` behind a pty until SIGTERM/SIGINT (or its parent dies)."""

    def __init__(
        self,
        firmware: GrblFirmware,
        pty_path: Path,
        *,
        plant: tuple[str, int] | None = None,
        parent_pid: int | None = None,
        tick_s: float = TICK_S,
    ) -> None:
        self.firmware = firmware
        self.pty_path = pty_path
        self.plant = plant
        self.parent_pid = parent_pid
        self.tick_s = tick_s
        self._link = PtyLink(pty_path, self._received)
        self._mirror: PlantMirror | None = None
        self._stop = asyncio.Event()
        self._overflow_logged = 0
        self._t0 = 0.0

    def _now(self) -> float:
        return asyncio.get_running_loop().time()

    def _received(self, data: bytes) -> None:
        try:
            self.firmware.receive(data, self._now())
        except Exception as exc:  # a firmware bug must not kill the link
            log_event("firmware_error", error=repr(exc))
        self._flush()

    def _flush(self) -> None:
        fw = self.firmware
        out = fw.read()
        if out:
            self._link.write(out)
        ops = fw.take_plant_ops()
        if self._mirror is not None:
            for op in ops:
                self._mirror.submit(op)
        if fw.stats.rx_overflow != self._overflow_logged:
            log_event("rx_overflow", dropped_total=fw.stats.rx_overflow, t_s=self._uptime())
            self._overflow_logged = fw.stats.rx_overflow

    def _uptime(self) -> float:
        return round(self._now() - self._t0, 4)

    def _stats_line(self, event: str) -> None:
        fw = self.firmware
        x, y, z = fw.motion.position_mm
        fields: dict[str, object] = {
            "flavor": fw.config.flavor.value,
            "rx_buffer_bytes": fw.config.rx_buffer_bytes,
            "planner_blocks": fw.config.planner_blocks,
            "uptime_s": self._uptime(),
            **fw.stats.as_dict(),
            "tx_dropped_writes": self._link.dropped_writes,
            "state": fw.state.value,
            "x_mm": round(x, 4),
            "y_mm": round(y, 4),
            "z_mm": round(z, 4),
        }
        if self._mirror is not None:
            fields["plant"] = self._mirror.stats()
        log_event(event, **fields)

    async def run(self) -> int:
        """Serve until stopped; 0 on a clean stop, 1 if the plant port cannot be reached."""
        loop = asyncio.get_running_loop()
        with contextlib.suppress(NotImplementedError):
            loop.add_signal_handler(signal.SIGTERM, self._stop.set)
            loop.add_signal_handler(signal.SIGINT, self._stop.set)
            loop.add_signal_handler(signal.SIGUSR1, self._stats_line, "stats")
        async with contextlib.AsyncExitStack() as stack:
            if self.plant is not None:
                try:
                    self._mirror = await stack.enter_async_context(PlantMirror(*self.plant))
                except ConnectionError as exc:
                    log_event("plant_unreachable", error=str(exc))
                    return 1
            self._t0 = loop.time()
            self.firmware.set_clock(self._t0)
            await self._link.open()
            try:
                log_event("ready", pty=str(self.pty_path), flavor=self.firmware.config.flavor.value)
                print(f"READY pty={self.pty_path}", flush=True)
                self._flush()
                await self._loop()
            finally:
                await self._link.close()
                self._flush()  # the last plant operations go to the mirror before it closes
                self._stats_line("exit")
        return 0

    async def _loop(self) -> None:
        loop = asyncio.get_running_loop()
        parent_check_at = loop.time()
        while not self._stop.is_set():
            now = loop.time()
            try:
                self.firmware.advance(now)
            except Exception as exc:  # logged; the emulator keeps serving
                log_event("firmware_error", error=repr(exc))
            self._flush()
            if now >= parent_check_at:
                parent_check_at = now + PARENT_CHECK_S
                if self.parent_pid is not None and os.getppid() != self.parent_pid:
                    log_event("parent_gone", parent_pid=self.parent_pid)
                    return
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), self.tick_s)
