"""Board time to host time: 32-bit extension and a drift-tracking linear fit.

Each CLOCK reply is paired with the host times the query left and the reply arrived. The
fit uses only samples whose round trip is close to the best seen, so a late reply (the
event loop was busy) does not bend the mapping.
"""

from __future__ import annotations

from collections import deque

__all__ = ["BoardClock", "extend_u32"]


def extend_u32(t32: int, reference: int) -> int:
    """The 64-bit value nearest ``reference`` whose low 32 bits are ``t32``."""
    delta = (t32 - reference) & 0xFFFFFFFF
    if delta >= 0x80000000:
        delta -= 0x1_0000_0000
    return reference + delta


class BoardClock:
    def __init__(self, window: int = 16) -> None:
        self._samples: deque[tuple[float, int, float]] = deque(maxlen=window)
        self.last_board_us = 0
        self.offset_s = 0.0  # host_time = board_us * 1e-6 * rate + offset_s
        self.rate = 1.0
        self.min_rtt_s = float("inf")
        self.synced = False

    def observe(self, host_sent_s: float, host_received_s: float, board_us: int) -> None:
        rtt = host_received_s - host_sent_s
        self.last_board_us = max(self.last_board_us, board_us)
        self.min_rtt_s = min(self.min_rtt_s, rtt)
        self._samples.append(((host_sent_s + host_received_s) / 2, board_us, rtt))
        good = [s for s in self._samples if s[2] <= self.min_rtt_s * 1.5 + 200e-6]
        if len(good) >= 3:
            n = len(good)
            mb = sum(b for _, b, _ in good) / n
            mh = sum(h for h, _, _ in good) / n
            var = sum((b - mb) ** 2 for _, b, _ in good)
            if var > 0:
                cov = sum((b - mb) * (h - mh) for h, b, _ in good)
                rate = cov / var * 1e6
                if 0.999 < rate < 1.001:  # crystals are within hundreds of ppm
                    self.rate = rate
            self.offset_s = mh - mb * 1e-6 * self.rate
        else:
            h, b, _ = min(good or self._samples, key=lambda s: s[2])
            self.offset_s = h - b * 1e-6 * self.rate
        self.synced = True

    def extend(self, t32: int) -> int:
        """A 32-bit board timestamp as a 64-bit one, near the latest board time seen."""
        t = extend_u32(t32, self.last_board_us)
        self.last_board_us = max(self.last_board_us, t)
        return t

    def to_host(self, board_us: int) -> float:
        return board_us * 1e-6 * self.rate + self.offset_s
