"""The mock board as a real-time process: firmware ticks paced by the monotonic clock.

The firmware and plant run in board time; each wake-up runs every tick that is due, then
flushes what the board sent to the link. Host bytes are handled the moment they arrive,
and their replies flushed at once, so acknowledgements do not wait for the next batch.

``parent_pid`` (set by ``python -m mock_device``): the run loop ends, as on SIGTERM, once the
process's parent is no longer that pid, checked every ``PARENT_CHECK_S``; a mock started
by anything, even a shell script that is then killed, does not outlive it.

``latency_log`` (``--latency-log PATH``) records, in real-clock board time, when each
Z_VELOCITY arrived and when each SAMPLES frame was handed to the link (latency_log.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path

import firmware_protocol as fp

from .faults import FaultPlan, check_rate
from .gantry_server import GantryServer
from .latency_log import LatencyLog
from .links import BoardLink
from .sim import SimulatedBoard

__all__ = ["MockBoardProcess", "ProcessOptions"]

MAX_TICKS_PER_WAKE = 200  # after a long stall, catch up in slices so the link is served
PARENT_CHECK_S = 0.25  # how often the run loop asks whether its parent is still there


@dataclass(frozen=True)
class ProcessOptions:
    duration_s: float | None = None
    truth_path: Path | None = None
    program: tuple[str, ...] = ()
    gantry: tuple[str, int] | None = None  # host, port of the gantry control port
    latency_log: Path | None = None  # JSON lines: Z_VELOCITY receipt, SAMPLES send times
    parent_pid: int | None = None  # stop once the parent is another process (None: never)
    parent_check_s: float = PARENT_CHECK_S


class MockBoardProcess:
    def __init__(
        self, board: SimulatedBoard, link: BoardLink, plan: FaultPlan, options: ProcessOptions
    ) -> None:
        self.board = board
        self.link = link
        self.plan = plan
        self.options = options
        self.stop = asyncio.Event()
        self.unplugs = 0
        self.reboots = 0
        self._unplug_task: asyncio.Task[None] | None = None
        self._stall_done = False
        self._gantry: GantryServer | None = None
        self.injected_bytes = 0
        self.latency: LatencyLog | None = None
        self._rx_loop_s = 0.0
        if options.latency_log is not None:
            self.latency = LatencyLog(options.latency_log)
            self._instrument()
        link.on_bytes = self._host_bytes

    def _instrument(self) -> None:
        """Hook the (current) firmware to the latency log."""
        assert self.latency is not None
        fw = self.board.firmware
        fw.on_zvelocity = self._zvel_received
        fw.on_samples = self.latency.samples_built

    def _host_bytes(self, data: bytes) -> None:
        if self.latency is not None:
            self._rx_loop_s = asyncio.get_running_loop().time()
        self.board.host_write(data)
        self._flush()

    def _zvel_received(self, msg: fp.ZVelocity) -> None:
        assert self.latency is not None
        fw = self.board.firmware
        current = fw.zvel_applied and fw.zvel_seq == msg.stream_seq
        self.latency.zvel_received(msg.stream_seq, self._rx_loop_s, fw.t_us, current)

    def _flush(self) -> None:
        data = self.board.read()
        if not data:
            return
        log = self.latency
        if self.plan.delay_ms:
            sent = None if log is None else log.take_pending()
            asyncio.get_running_loop().call_later(
                self.plan.delay_ms / 1000, self._write_late, data, sent
            )
        else:
            self.link.write(data)
            if log is not None:
                log.samples_sent(log.take_pending(), asyncio.get_running_loop().time())

    def inject(self, data: bytes) -> int:
        """Raw bytes into the host-bound stream, as if from the board's UART (a fuzzer's
        frames, through the real pty): how many were written."""
        self.injected_bytes += len(data)
        self.link.write(data)
        return len(data)

    def drop_frames(self, rate: float, for_s: float) -> None:
        """Lose ``rate`` of the board's frames for ``for_s`` seconds, then the plan's own."""
        check_rate("rate", rate)
        injector = self.board.faults
        normal = injector.plan
        injector.plan = dataclasses.replace(normal, drop_frame_rate=rate)
        self._log("drop_frames", rate=rate, for_s=for_s)

        def restore() -> None:
            injector.plan = normal

        asyncio.get_running_loop().call_later(for_s, restore)

    def _write_late(self, data: bytes, sent: list[fp.Samples] | None) -> None:
        self.link.write(data)
        if self.latency is not None and sent:
            self.latency.samples_sent(sent, asyncio.get_running_loop().time())

    async def unplug(self, for_s: float) -> None:
        """Close the pty master (the host sees EIO), wait, recreate it behind the same path."""
        if not self.link.is_open:
            return
        self.unplugs += 1
        self._log("unplug", for_s=for_s)
        await self.link.close()
        await asyncio.sleep(for_s)
        self.board.read()  # what the board sent meanwhile went nowhere
        if self.latency is not None:
            self.latency.take_pending()
        await self.link.open()
        self._log("replug")

    def reboot(self) -> None:
        self.reboots += 1
        self.board.reboot()
        if self.latency is not None:
            self.latency.reboot(self.board.firmware.boot_id)
            self._instrument()
        self._log("reboot", boot_id=f"{self.board.firmware.boot_id:08x}")

    def _log(self, event: str, **fields: object) -> None:
        line = {"event": event, "t_s": round(self.board.t_s, 4), **fields}
        print(json.dumps(line), file=sys.stderr, flush=True)

    def _scheduled_faults(self) -> None:
        t = self.board.t_s
        plan = self.plan
        if plan.unplug_at_s is not None and t >= plan.unplug_at_s and self.unplugs == 0:
            self._spawn_unplug(plan.unplug_for_s)
        if plan.reboot_at_s is not None and t >= plan.reboot_at_s and self.reboots == 0:
            self.reboot()
        if plan.stall_acks_at_s is not None and t >= plan.stall_acks_at_s and not self._stall_done:
            self._stall_done = True
            fw = self.board.firmware
            fw.stall_replies_until_us = fw.t_us + round(plan.stall_for_s * 1e6)
            self._log("stall_acks", for_s=plan.stall_for_s)

    def _spawn_unplug(self, for_s: float) -> None:
        if self._unplug_task is None or self._unplug_task.done():
            self._unplug_task = asyncio.create_task(self.unplug(for_s), name="unplug")

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        with contextlib.suppress(NotImplementedError):
            loop.add_signal_handler(signal.SIGTERM, self.stop.set)
            loop.add_signal_handler(signal.SIGINT, self.stop.set)
            loop.add_signal_handler(signal.SIGUSR1, self._spawn_unplug, self.plan.unplug_for_s)
            loop.add_signal_handler(signal.SIGUSR2, self.reboot)
        for line in self.options.program:
            self.board.plant.gantry.feed_line(line)
        await self.link.open()
        ready = f"READY {self.boot_hex}"
        if self.options.gantry is not None:
            self._gantry = GantryServer(
                self.board.plant, *self.options.gantry, inject=self.inject,
                drop_frames=self.drop_frames,
            )  # fmt: skip
            await self._gantry.start()
            ready += f" gantry={self._gantry.bound_port}"
        self._log("ready", link=str(getattr(self.link, "path", "")), boot_id=self.boot_hex)
        print(ready, flush=True)
        t0 = loop.time()
        self.board.tick_due(t0)  # anchors board time to the loop clock (a reboot re-anchors)
        if self.latency is not None:
            fw = self.board.firmware
            self.latency.start(t0, fw.t_us, fw.boot_id)
        parent_check_at = t0
        try:
            while not self.stop.is_set():
                self.board.tick_due(loop.time(), MAX_TICKS_PER_WAKE)
                self._flush()
                self._scheduled_faults()
                if (
                    self.options.duration_s is not None
                    and self.board.t_s >= self.options.duration_s
                ):
                    break
                if loop.time() >= parent_check_at:
                    parent_check_at = loop.time() + self.options.parent_check_s
                    if self._parent_gone():
                        break
                fw = self.board.firmware
                wake = self.board.due_at_s(fw.t_us + fw.period_us * fw.batch_size)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.stop.wait(), max(0.0, wake - loop.time()))
        finally:
            if self._gantry is not None:
                await self._gantry.close()
            await self.link.close()
            if self._unplug_task is not None:
                self._unplug_task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await self._unplug_task
            self._finish()
        return 0

    def _parent_gone(self) -> bool:
        expected = self.options.parent_pid
        if expected is None or os.getppid() == expected:
            return False
        self._log("parent_gone", parent_pid=expected)
        return True

    @property
    def boot_hex(self) -> str:
        return f"{self.board.firmware.boot_id:08x}"

    def _finish(self) -> None:
        if self.latency is not None:
            self.latency.write()
        truth = self.board.plant.truth
        if self.options.truth_path is not None:
            path = self.options.truth_path
            if path.suffix == ".csv":
                truth.write_csv(path)
            else:
                truth.write_jsonl(path)
        fw = self.board.firmware
        summary = truth.summary()
        self._log(
            "exit",
            cuts=[dataclasses.asdict(cut) for cut in summary.cuts],
            violations=truth.violations,
            unsafe_torch_ms=self.board.unsafe_torch_us / 1000,
            unplugs=self.unplugs,
            reboots=self.reboots,
            rx_crc_errors=fw.crc_errors,
            faults=f"0x{fw.faults:04x}",
            torch_on=fw.torch_on,
            executed=dict(sorted(fw.executed.items())),
            torch_on_commands=fw.torch_on_commands,
            injected_bytes=self.injected_bytes,
            proto=f"{fp.PROTOCOL_MAJOR}.{fp.PROTOCOL_MINOR}",
        )
