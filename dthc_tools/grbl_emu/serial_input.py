"""grbl's serial receive buffer and the main loop's line assembly, sans I/O.

The buffer is a ring of ``size_bytes`` in which one slot stays empty, so it holds one byte
less than its size (grbl reports the size, ``[OPT:...,128]``, and ``Bf:`` counts free bytes
against it). The main loop takes bytes out one by one into its line buffer, the way grbl's
``protocol_main_loop`` does: blanks and control characters, ``/``, ``(...)`` and ``;``
comments are dropped, letters are upper-cased, and a line longer than the line buffer is
flagged (``error:11``) and its excess thrown away. CR and LF both end a line; grblHAL takes a
CR LF (or LF CR) pair as one end, classic grbl answers the empty line between them.
"""

from __future__ import annotations

__all__ = ["SerialInput"]

_CR, _LF = 0x0D, 0x0A


class SerialInput:
    """Bytes in (``put``), complete prepared lines out (``next_line``)."""

    def __init__(self, size_bytes: int, line_chars: int, *, merge_crlf: bool) -> None:
        self.size_bytes = size_bytes
        self._capacity = size_bytes - 1
        self._line_chars = line_chars
        self._merge_crlf = merge_crlf
        self._rx = bytearray()
        self._line = bytearray()
        self._skip = ""  # "(", ";" or "overflow": drop characters until ")" or the line end
        self._last_eol = 0

    def __len__(self) -> int:
        """Bytes waiting in the receive buffer."""
        return len(self._rx)

    @property
    def full(self) -> bool:
        """No room for another byte."""
        return len(self._rx) >= self._capacity

    @property
    def free_bytes(self) -> int:
        """What grbl reports as free (``Bf:`` second value): size minus bytes waiting."""
        return self.size_bytes - len(self._rx)

    def put(self, byte: int) -> bool:
        """Store one received byte; False (the byte is lost) if the buffer is full."""
        if self.full:
            return False
        self._rx.append(byte)
        return True

    def clear(self) -> None:
        """Soft reset: the buffer and the half-read line are gone."""
        self._rx.clear()
        self._line.clear()
        self._skip = ""
        self._last_eol = 0

    def next_line(self) -> tuple[str, bool] | None:
        """Read bytes up to the next line end: ``(line, too_long)``, or None once the buffer
        is empty (a partial line stays in the line buffer)."""
        rx = self._rx
        for i, c in enumerate(rx):
            if c in (_CR, _LF):
                pair = self._last_eol and self._last_eol != c
                if self._merge_crlf and pair and not self._line and not self._skip:
                    self._last_eol = 0
                    continue
                self._last_eol = c
                del rx[: i + 1]
                too_long = self._skip == "overflow"
                line = self._line.decode("ascii", "replace")
                self._line.clear()
                self._skip = ""
                return line, too_long
            self._take(c)
        rx.clear()
        return None

    def _take(self, c: int) -> None:
        self._last_eol = 0
        if self._skip:
            if self._skip == "(" and c == 0x29:  # ')'
                self._skip = ""
        elif c <= 0x20 or c == 0x2F:  # blanks, control characters, '/' (block delete: ignored)
            pass
        elif c == 0x28:  # '('
            self._skip = "("
        elif c == 0x3B:  # ';'
            self._skip = ";"
        elif len(self._line) >= self._line_chars:
            self._skip = "overflow"
        elif 0x61 <= c <= 0x7A:  # lower case
            self._line.append(c - 0x20)
        else:
            self._line.append(c)
