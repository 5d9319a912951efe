"""Fault injection on a link: what a noisy, flaky USB cable does to the bytes.

The one place bytes are corrupted for tests and the mock. :class:`LinkFaultInjector` sits
between a writer and the wire: the mock board's firmware (one frame per ``outgoing`` call,
bytes in any split per ``incoming`` call) and the tests' in-memory transport (one write
per ``outgoing`` call). Scheduled faults (unplug, reboot, stalled acks) are read by the
process that owns the link; everything here is seeded and deterministic.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

__all__ = ["FaultPlan", "LinkFaultInjector", "check_rate"]


def check_rate(name: str, rate: float) -> None:
    """A probability named ``name`` must be within 0..1 (ValueError naming it otherwise)."""
    if not 0.0 <= rate <= 1.0:
        raise ValueError(f"{name} must be within 0..1, got {rate}")


@dataclass(frozen=True)
class FaultPlan:
    """Every fault the mock can inject; all off by default."""

    bit_flip_rate: float = 0.0  # probability per byte, both directions
    drop_frame_rate: float = 0.0  # probability per board frame
    delay_ms: float = 0.0  # extra latency on every board frame
    garbage_rate: float = 0.0  # probability per board frame of a garbage burst before it
    garbage_max_bytes: int = 32
    unplug_at_s: float | None = None  # close the pty master, recreate it after unplug_for_s
    unplug_for_s: float = 1.0
    reboot_at_s: float | None = None  # restart the firmware with a new boot id
    stall_acks_at_s: float | None = None  # stop answering commands for stall_for_s
    stall_for_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("bit_flip_rate", "drop_frame_rate", "garbage_rate"):
            check_rate(name, getattr(self, name))
        if self.delay_ms < 0:
            raise ValueError(f"delay_ms must not be negative, got {self.delay_ms}")
        if self.garbage_max_bytes < 1:
            raise ValueError(f"garbage_max_bytes must be at least 1, got {self.garbage_max_bytes}")


class LinkFaultInjector:
    """Applies a plan's drops, garbage and bit flips; counts each."""

    def __init__(self, plan: FaultPlan, rng: random.Random) -> None:
        self.plan = plan
        self.rng = rng
        self.flipped_bits = 0
        self.dropped_frames = 0
        self.garbage_bytes = 0
        self.garbage_bursts = 0

    def _flip(self, data: bytes) -> bytes:
        rate = self.plan.bit_flip_rate
        if not rate:
            return data
        rng = self.rng
        out: bytearray | None = None
        # Geometric skipping, cost proportional to flips rather than bytes: the clean bytes
        # before the next flip are floor(Exp(lam)), geometric with P(flip) = 1 - e^-lam = rate.
        lam = -math.log1p(-rate) if rate < 1.0 else None
        pos = -1
        while True:
            pos += 1 if lam is None else 1 + int(rng.expovariate(lam))
            if pos >= len(data):
                break
            if out is None:
                out = bytearray(data)
            out[pos] ^= 1 << rng.randrange(8)
            self.flipped_bits += 1
        return data if out is None else bytes(out)

    def outgoing(self, frame: bytes) -> bytes:
        """Board to host: maybe drop the frame, add garbage before it, flip bits in it."""
        plan = self.plan
        rng = self.rng
        if plan.drop_frame_rate and rng.random() < plan.drop_frame_rate:
            self.dropped_frames += 1
            return b""
        prefix = b""
        if plan.garbage_rate and rng.random() < plan.garbage_rate:
            n = rng.randint(1, plan.garbage_max_bytes)
            prefix = bytes(rng.randrange(256) for _ in range(n))
            self.garbage_bytes += n
            self.garbage_bursts += 1
        return prefix + self._flip(frame)

    def incoming(self, data: bytes) -> bytes:
        """Host to board: bit flips only (the host's own retransmissions cover loss)."""
        return self._flip(data)
