"""Board time: the board's 32-bit microsecond stamps as one continuous clock.

The cut sequence and the THC run on the board's sample timestamps (two batches read
together keep their true spacing), so the host needs no model of the board's clock, only
two steps: extend each 32-bit stamp to 64 bits near the latest board time of the session
(:class:`BoardClock`), and keep one timeline that never runs backwards across sessions,
although a rebooted board counts from zero again (:class:`BoardTimeline`).
"""

from __future__ import annotations

__all__ = ["BoardClock", "BoardTimeline", "extend_u32"]


def extend_u32(t32: int, reference: int) -> int:
    """The 64-bit value nearest ``reference`` whose low 32 bits are ``t32``."""
    delta = (t32 - reference) & 0xFFFFFFFF
    if delta >= 0x80000000:
        delta -= 0x1_0000_0000
    return reference + delta


class BoardClock:
    """One session's board time in 64 bits (the board sends the low 32 bits, 71 minutes)."""

    def __init__(self) -> None:
        self.last_board_us = 0

    def extend(self, t32: int) -> int:
        """A 32-bit board timestamp as a 64-bit one, near the latest board time seen."""
        t = extend_u32(t32, self.last_board_us)
        self.last_board_us = max(self.last_board_us, t)
        return t


class BoardTimeline:
    """Board time in seconds, continuous over every session of one supervisor.

    Within a session it is the board's own clock (plus a constant); when a new session
    starts (a reconnect, or a reboot whose clock starts again at zero) the first stamp of
    it is placed no earlier than the last stamp seen. It never runs backwards: a stamp
    older than the newest one seen (an input edge inside the batch just handled) reads as
    the newest, so the sequence's timers and the THC's dt never go negative.
    """

    def __init__(self) -> None:
        self._offset_us = 0
        self._last_us = 0
        self._anchor_pending = False

    def new_session(self) -> None:
        """The next stamp comes from a new session: anchor the timeline on it."""
        self._anchor_pending = True

    def seconds(self, board_us: int) -> float:
        """A session's 64-bit board stamp on the timeline, in seconds."""
        if self._anchor_pending:
            self._anchor_pending = False
            self._offset_us = max(self._offset_us, self._last_us - board_us)
        t_us = board_us + self._offset_us
        if t_us < self._last_us:
            return self._last_us * 1e-6  # an edge stamped before the newest batch: now
        self._last_us = t_us
        return t_us * 1e-6

    @property
    def now_s(self) -> float:
        """The latest board time seen: when a command from the host takes effect."""
        return self._last_us * 1e-6
