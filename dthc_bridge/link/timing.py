"""Timing constants of the link, named with their units and injectable (tests shrink them).

The defaults the wire protocol fixes (window, lease, velocity expiry) are read from
``firmware_protocol``; the daemon's ``[board]`` section reads its defaults from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import firmware_protocol as fp

__all__ = ["LinkTiming"]


@dataclass(frozen=True)
class LinkTiming:
    ack_timeout_s: float = 0.025  # >= 3x a USB full-speed round trip; raise it on slow UARTs
    max_attempts: int = 5  # first send + 4 retransmissions (PROTOCOL.md §3)
    window: int = fp.HOST_WINDOW  # sequenced commands in flight
    lease_ms: int = fp.DEFAULT_LEASE_MS
    handshake_timeout_s: float = 0.5
    # An Arduino resets when its port opens (DTR) and sits in its bootloader first (0.84 s
    # on a Mega 2560, 1.34 s on an old-bootloader Nano, measured on the emulated boards); a
    # byte sent then reaches the bootloader (the Mega's then waits 5 s more). The handshake
    # starts at the board's first frame (it streams SAMPLES from power-on), or after this
    # long without one.
    boot_window_s: float = 1.5
    max_consecutive_timeouts: int = 3  # then the link is declared down
    backoff_initial_s: float = 0.2
    backoff_max_s: float = 5.0
    velocity_expiry_ms: int = fp.DEFAULT_ZVEL_EXPIRY_MS

    @property
    def heartbeat_period_s(self) -> float:
        return self.lease_ms / 3000.0
