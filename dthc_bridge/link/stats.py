"""Link counters, published on the MQTT diagnostics topic (Klipper's stats line, as data)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["LinkStats"]


@dataclass(slots=True)
class LinkStats:
    bytes_out: int = 0
    frames_out: int = 0
    requests: int = 0
    retransmits: int = 0
    timeouts: int = 0
    naks: int = 0
    duplicate_replies: int = 0
    telemetry_batches: int = 0
    telemetry_gaps: int = 0  # SAMPLES batches lost, from stream_seq
    event_gaps: int = 0  # EVENT/FAULT reports lost, from the event counter
    velocity_frames: int = 0
    rtt_last_ms: float = 0.0
    rtt_min_ms: float = 0.0
    rtt_avg_ms: float = 0.0  # exponentially weighted, 1/16
    reconnects: int = 0
    reboots: int = 0
    handshakes: int = 0
    unexpected_frames: int = 0  # decoded fine, but not a message a board sends here
    handler_errors: int = 0  # listeners above the link that raised (docs/DESIGN.md invariant 6)

    def observe_rtt(self, rtt_s: float) -> None:
        ms = rtt_s * 1e3
        self.rtt_last_ms = ms
        self.rtt_min_ms = ms if not self.rtt_min_ms else min(self.rtt_min_ms, ms)
        self.rtt_avg_ms = (
            ms if not self.rtt_avg_ms else self.rtt_avg_ms + (ms - self.rtt_avg_ms) / 16
        )

    def as_dict(self) -> dict[str, float]:
        return asdict(self)
