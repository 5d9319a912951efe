"""What a grbl sender writes, split as grbl 1.1's serial receiver splits it. Sans I/O.

grbl picks its real-time commands out of the byte stream as they arrive, wherever they
fall, even inside a line, and never buffers or answers them: ``?`` (status), ``!`` (feed
hold), ``~`` (cycle start), 0x18 (soft reset) and every byte from 0x80 (overrides, jog
cancel, safety door). Everything else is line text: a line ends at LF or CR, each end is
one line (an empty one too: grbl answers it ``ok``, which is why senders end lines with LF
alone), other control characters are dropped, and a line longer than the receiver's buffer
is answered ``error:11`` without being run. A sender counts the bytes of the lines it has
not yet seen answered against that buffer (character counting), so the receiver may hold
many lines at once; their answers must come back in order.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["MAX_LINE_BYTES", "Line", "RealTime", "Receiver", "is_realtime"]

MAX_LINE_BYTES = 256  # grblHAL's line buffer; grbl 1.1 on an AVR has 80
_REALTIME_ASCII = frozenset(b"?!~\x18")


def is_realtime(byte: int) -> bool:
    return byte in _REALTIME_ASCII or byte >= 0x80


@dataclass(frozen=True, slots=True)
class RealTime:
    """A real-time command byte: to be acted on now, never answered."""

    byte: int


@dataclass(frozen=True, slots=True)
class Line:
    """One line, as written (its end removed); ``overflow``: longer than the receiver
    holds, to be answered ``error:11`` and not run."""

    text: str
    overflow: bool = False


class Receiver:
    def __init__(self, max_line_bytes: int = MAX_LINE_BYTES) -> None:
        self.max_line_bytes = max_line_bytes
        self._line = bytearray()
        self._overflow = False

    def feed(self, data: bytes) -> list[RealTime | Line]:
        """What ``data`` completes, in the order it arrived."""
        out: list[RealTime | Line] = []
        for byte in data:
            if is_realtime(byte):
                out.append(RealTime(byte))
            elif byte in (0x0A, 0x0D):
                out.append(Line(self._line.decode("ascii", "replace"), self._overflow))
                self._line.clear()
                self._overflow = False
            elif byte < 0x20 and byte != 0x09:
                continue  # a control character: grbl drops it
            elif len(self._line) >= self.max_line_bytes:
                self._overflow = True  # the rest of the line is lost; it will not run
            else:
                self._line.append(byte)
        return out

    def reset(self) -> None:
        """After a soft reset: a partly received line is gone."""
        self._line.clear()
        self._overflow = False
