"""Streaming frame decoder: bytes in any split, typed messages out, never raises.

It resynchronises at the next delimiter after any corruption, caps what it holds without a
delimiter, and counts every kind of loss so the link layer can publish it.
"""

from __future__ import annotations

from binascii import crc_hqx
from collections.abc import Callable
from dataclasses import dataclass, fields

from cobs.cobs import DecodeError as _CobsDecodeError
from cobs.cobs import decode as _cobs_decode

from .codec import _DECODERS
from .constants import CRC_INIT, MAX_ENCODED_FRAME, MAX_FRAME
from .errors import (
    BadLength,
    CobsError,
    CrcMismatch,
    DecodeError,
    FrameTooLong,
    UnknownMessageType,
)
from .messages import Message

__all__ = ["DecoderStats", "StreamDecoder"]


@dataclass(slots=True)
class DecoderStats:
    bytes_in: int = 0
    frames_ok: int = 0
    crc_errors: int = 0
    framing_errors: int = 0  # invalid COBS, too short, or over-long without a delimiter
    unknown_type: int = 0
    length_errors: int = 0  # right type, wrong payload length
    dropped_bytes: int = 0  # every byte that did not end up in a valid message

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class StreamDecoder:
    """Feed it received bytes; it returns the messages completed by them, in order.

    ``on_error`` (optional) receives a :class:`DecodeError` describing each bad frame; the
    counters in ``stats`` are kept either way, and ``last_error`` keeps the latest.
    """

    __slots__ = ("_discarding", "_pending", "last_error", "on_error", "stats")

    def __init__(self, on_error: Callable[[DecodeError], None] | None = None) -> None:
        self._pending = b""
        # True after an over-long run: the bytes up to the next delimiter are garbage.
        self._discarding = False
        self.on_error = on_error
        self.last_error: DecodeError | None = None
        self.stats = DecoderStats()

    @property
    def pending_bytes(self) -> int:
        return len(self._pending)

    def reset(self) -> None:
        """Forget a partial frame (after reopening the link)."""
        self._pending = b""
        self._discarding = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Message]:
        stats = self.stats
        stats.bytes_in += len(data)
        if self._pending:
            data = self._pending + data
        elif not isinstance(data, bytes):
            data = bytes(data)
        parts = data.split(b"\x00")
        tail = parts.pop()
        if len(tail) > MAX_ENCODED_FRAME:
            # No delimiter within the longest legal frame: drop it and resync at the next one.
            stats.dropped_bytes += len(tail)
            stats.framing_errors += 1
            self._report(FrameTooLong("no delimiter within the maximum frame length", tail[:64]))
            tail = b""
            self._discarding = True
        out: list[Message] = []
        if parts:
            if self._discarding:
                stats.dropped_bytes += len(parts[0]) + 1  # the delimiter ends the discard
                parts[0] = b""
                self._discarding = False
            append = out.append
            decoders = _DECODERS
            for enc in parts:
                if not enc:
                    continue  # idle delimiter, or the one that ended a discard
                try:
                    raw = _cobs_decode(enc)
                except _CobsDecodeError as exc:
                    self._bad(enc, CobsError(f"invalid COBS: {exc}", enc), framing=True)
                    continue
                if not 4 <= len(raw) <= MAX_FRAME:
                    length = BadLength(
                        raw[0] if raw else 0, f"0..{MAX_FRAME - 4}", len(raw) - 4, raw
                    )
                    self._bad(enc, length, framing=True)
                    continue
                if crc_hqx(raw, CRC_INIT):
                    stats.crc_errors += 1
                    stats.dropped_bytes += len(enc) + 1
                    self._report(
                        CrcMismatch(
                            crc_hqx(raw[:-2], CRC_INIT), int.from_bytes(raw[-2:], "big"), raw
                        )
                    )
                    continue
                decoder = decoders.get(raw[0])
                if decoder is None:
                    stats.unknown_type += 1
                    stats.dropped_bytes += len(enc) + 1
                    self._report(UnknownMessageType(raw[0], raw))
                    continue
                try:
                    append(decoder(raw))
                except DecodeError as exc:
                    stats.length_errors += 1
                    stats.dropped_bytes += len(enc) + 1
                    self._report(exc)
            stats.frames_ok += len(out)
        if self._discarding:
            stats.dropped_bytes += len(tail)
            tail = b""
        self._pending = tail
        return out

    def _bad(self, enc: bytes, exc: DecodeError, framing: bool) -> None:
        if framing:
            self.stats.framing_errors += 1
        self.stats.dropped_bytes += len(enc) + 1
        self._report(exc)

    def _report(self, exc: DecodeError) -> None:
        self.last_error = exc
        if self.on_error is not None:
            self.on_error(exc)
