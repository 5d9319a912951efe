"""What the operator chose for a conformance run, and the suite's timing constants.

Every Z motion of the suite stays inside a window of ``z_window_mm`` either side of the
reference position: where Z stood when the suite started, or ``start_z_mm`` if given (the
one absolute move, made first, for benches and the mock whose plate height is known).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import firmware_protocol as fp

__all__ = [
    "BOOT_WINDOW_S",
    "CHECK_TIMEOUT_S",
    "HANDSHAKE_ATTEMPTS",
    "HANDSHAKE_TIMEOUT_S",
    "LEASE_TOLERANCE_US",
    "LEASE_WAIT_EXTRA_S",
    "LISTEN_BEFORE_HELLO_S",
    "PROBE_DECEL_ALLOWANCE_MM",
    "REPLY_SETTLE_S",
    "RESET_SETTLE_S",
    "RESET_WAIT_S",
    "SINGLE_ATTEMPT_TIMEOUT_S",
    "SUITE_LEASE_MS",
    "WINDOW_GUARD_MARGIN_MM",
    "ZVEL_EXPIRY_MS",
    "ZVEL_GIVE_UP_S",
    "ZVEL_RENEWALS",
    "ZVEL_RENEW_PERIOD_S",
    "ZVEL_STOP_MARGIN_MS",
    "ZVEL_VELOCITY_UM_S",
    "ConformanceOptions",
]

# The lease the suite runs under between checks: long enough that a busy host never trips
# it by accident; the lease check sets its own (``lease_ms``) and restores this one.
SUITE_LEASE_MS: Final = 1000
# Boards send SAMPLES from power-on: listen this long before HELLO and count what arrives.
LISTEN_BEFORE_HELLO_S: Final = 0.3
# An Arduino resets when its port is opened (DTR) and sits in its bootloader first (measured
# on the emulated boards with Arduino's bootloaders: 0.84 s on the Mega 2560, 1.34 s on the
# old-bootloader Nano); a byte sent then reaches the bootloader, and the Mega's stk500v2
# then waits 5 s more for the rest of a programming message. The suite speaks only once the
# board has (its first frame), or after this long without one.
BOOT_WINDOW_S: Final = 1.5
# After signalling a reset: frames the board sent before it drain meanwhile.
RESET_SETTLE_S: Final = 0.1
HANDSHAKE_ATTEMPTS: Final = 3
HANDSHAKE_TIMEOUT_S: Final = 0.3
# A check that has not finished after this long is failed (bounded time everywhere).
CHECK_TIMEOUT_S: Final = 30.0
# Where a check counts replies or duplicates, it sends each command once and waits this long
# (a retransmission would itself be a duplicate and skew the count).
SINGLE_ATTEMPT_TIMEOUT_S: Final = 0.5
# After a batch of commands, wait this long for stray second replies before counting them.
REPLY_SETTLE_S: Final = 0.05
# How long past the lease the lease check waits for FAULT(LEASE_EXPIRED) before failing.
LEASE_WAIT_EXTRA_S: Final = 1.0
# Board timestamps are taken at interrupt granularity; this covers their quantisation only.
# The measurement itself does not depend on link latency: it subtracts two board times.
LEASE_TOLERANCE_US: Final = 250
# Z velocity check: a slow upward stream renewed a few times, then left to expire.
ZVEL_VELOCITY_UM_S: Final = 3000
ZVEL_EXPIRY_MS: Final = 40
ZVEL_RENEWALS: Final = 4
ZVEL_RENEW_PERIOD_S: Final = 0.02
# Expiry plus this covers the board's deceleration and one batch of reporting delay.
ZVEL_STOP_MARGIN_MS: Final = 100
# Still moving this long after the last frame: the host sends Z_STOP and fails the check.
ZVEL_GIVE_UP_S: Final = 0.5
# The probe's max travel ends this far inside the window, so its deceleration stays inside.
PROBE_DECEL_ALLOWANCE_MM: Final = 0.5
# Z seen this far beyond the window (a board ignoring a limit): the host sends Z_STOP.
WINDOW_GUARD_MARGIN_MM: Final = 1.0
# How long to wait for the boot id to change after asking for (or signalling) a reset.
RESET_WAIT_S: Final = 5.0


@dataclass(frozen=True, slots=True)
class ConformanceOptions:
    link: str
    z_window_mm: float = 10.0
    probe_travel_mm: float | None = None  # None: the whole window
    start_z_mm: float | None = None
    feed_mm_s: float = 20.0
    probe_feed_mm_s: float = 5.0
    lease_ms: int = 100
    allow_torch_relay: bool = False
    reset_signal_pid: int | None = None
    interactive: bool = False
    telemetry_s: float = 2.0
    rtt_queries: int = 200
    rtt_limit_ms: float = 20.0
    ack_timeout_ms: float = 50.0
    input_timeout_s: float = 15.0
    baudrate: int = 921_600
    # Run only the steps holding these checks (with the handshake and the set-up every
    # step needs); empty: every check. The others are reported skipped.
    only: tuple[str, ...] = ()
    home: bool = False  # run the homing cycle: Z up to its home switch, beyond the window

    def __post_init__(self) -> None:
        _within("--z-window-mm", self.z_window_mm, 1.0, 50.0)
        if self.probe_travel_mm is not None:
            _within("--probe-travel-mm", self.probe_travel_mm, 0.1, self.z_window_mm)
        if self.start_z_mm is not None:
            _within("--start-z-mm", self.start_z_mm, -10_000.0, 10_000.0)
        _within("--feed-mm-s", self.feed_mm_s, 0.1, 200.0)
        _within("--probe-feed-mm-s", self.probe_feed_mm_s, 0.1, 50.0)
        _within("--lease-ms", self.lease_ms, fp.LEASE_MIN_MS, fp.LEASE_MAX_MS)
        _within("--telemetry-s", self.telemetry_s, 0.5, 60.0)
        _within("--rtt-queries", self.rtt_queries, 10, 10_000)
        _within("--rtt-limit-ms", self.rtt_limit_ms, 0.1, 10_000.0)
        _within("--ack-timeout-ms", self.ack_timeout_ms, 1.0, 5000.0)
        _within("--input-timeout-s", self.input_timeout_s, 1.0, 600.0)

    @property
    def probe_max_travel_mm(self) -> float:
        """The probe's max travel: as asked, and never so far its deceleration leaves the
        window."""
        travel = self.z_window_mm if self.probe_travel_mm is None else self.probe_travel_mm
        return min(travel, self.z_window_mm - PROBE_DECEL_ALLOWANCE_MM)

    @property
    def ack_timeout_s(self) -> float:
        return self.ack_timeout_ms / 1000.0

    def describe_motion(self) -> str:
        """What will move, for the confirmation prompt."""
        where = (
            f"first to the absolute position Z = {self.start_z_mm:g} mm, then"
            if self.start_z_mm is not None
            else "relative to where Z stands now:"
        )
        torch = (
            "The torch relay WILL be switched on briefly (--allow-torch-relay)."
            if self.allow_torch_relay
            else "The torch relay is only ever switched off."
        )
        return (
            f"The suite moves Z {where} within ±{self.z_window_mm:g} mm "
            f"(probe down at most {self.probe_max_travel_mm:g} mm at "
            f"{self.probe_feed_mm_s:g} mm/s; other moves at {self.feed_mm_s:g} mm/s). "
            f"Ohmic sensing is switched on and off. {torch}"
        )


def _within(option: str, value: float, low: float, high: float) -> None:
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{option} {value:g} is out of range {low:g}..{high:g}")
