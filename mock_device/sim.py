"""Simulated-time board: the board logic (firmware/board/, C) + plant stepped by a clock,
in-process, no I/O.

Tests and benchmarks drive it directly: write host bytes, advance time, read board bytes.
"""

from __future__ import annotations

import random

import firmware_protocol as fp

from .board_logic import BoardIdentity, BoardLogic
from .faults import FaultPlan, LinkFaultInjector
from .plant import Plant, load_scenario

__all__ = ["SimulatedBoard"]


class SimulatedBoard:
    def __init__(
        self,
        scenario: str = "flat_clean",
        seed: int = 1,
        *,
        identity: BoardIdentity | None = None,
        faults: FaultPlan | None = None,
        firmware_class: type[BoardLogic] = BoardLogic,
    ) -> None:
        self.seed = seed
        self.rng = random.Random(seed)
        self.scenario = load_scenario(scenario)
        self.plant = Plant(self.scenario, seed=seed)
        self.faults = LinkFaultInjector(faults or FaultPlan(), random.Random(seed + 1))
        self._out = bytearray()
        self.firmware_class = firmware_class
        self.unsafe_torch_us_before_reboots = 0
        self.identity = identity
        self.firmware = firmware_class(
            self.plant, self._board_write, rng=self.rng, identity=identity
        )
        # Real-time pacing (tick_due): the firmware it was anchored on, the real clock and
        # board time at the anchor. A reboot's new firmware is anchored again.
        self._anchor: tuple[BoardLogic, float, int] | None = None

    def _board_write(self, frame: bytes) -> None:
        self._out += self.faults.outgoing(frame)

    def host_write(self, data: bytes) -> None:
        """Bytes from the host arrive at the board now (between two sample ticks)."""
        self.firmware.receive(self.faults.incoming(data))

    def send(self, msg: fp.Message) -> None:
        self.host_write(fp.encode(msg))

    def read(self) -> bytes:
        """Everything the board sent since the last read."""
        data = bytes(self._out)
        self._out.clear()
        return data

    def tick_due(self, now_s: float, max_ticks: int | None = None) -> int:
        """Run every tick whose sample time has come by ``now_s`` on a real clock (at most
        ``max_ticks``); return how many ran. The first call, and the first after a reboot
        (whose firmware clock starts again at 0), anchor board time to ``now_s``."""
        fw = self.firmware
        if self._anchor is None or self._anchor[0] is not fw:
            self._anchor = (fw, now_s, fw.t_us)
        _, t0_s, fw_t0_us = self._anchor
        due_us = fw_t0_us + round((now_s - t0_s) * 1e6)
        period_us = fw.period_us
        ticks = 0
        # A tick's sample is taken at the tick's end: run it once its time has come, or
        # its batch leaves before the board time it carries.
        while fw.t_us + period_us <= due_us and (max_ticks is None or ticks < max_ticks):
            fw.tick()
            ticks += 1
        return ticks

    def due_at_s(self, board_us: int) -> float:
        """The real-clock time at which board time ``board_us`` is due (after tick_due)."""
        assert self._anchor is not None
        _, t0_s, fw_t0_us = self._anchor
        return t0_s + (board_us - fw_t0_us) / 1e6

    def advance_ms(self, ms: float) -> None:
        period_us = self.firmware.period_us
        for _ in range(max(1, round(ms * 1000 / period_us))):
            self.firmware.tick()

    def reboot(self) -> None:
        """Power-cycle the board: the board logic starts again (a new boot id, reset reason
        WATCHDOG), Z where it stands; the plant stays."""
        self.unsafe_torch_us_before_reboots += self.firmware.unsafe_torch_us
        self.plant.set_torch(False)
        self.firmware = self.firmware_class(
            self.plant, self._board_write, rng=self.rng, identity=self.identity,
            reset_reason=fp.ResetReason.WATCHDOG,
        )  # fmt: skip

    @property
    def unsafe_torch_us(self) -> int:
        """Torch-on time past the lease, over every firmware instance since the start."""
        return self.unsafe_torch_us_before_reboots + self.firmware.unsafe_torch_us

    @property
    def t_s(self) -> float:
        return self.firmware.t_us / 1e6
