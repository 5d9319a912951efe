"""The trace switch: a session keeps its last frames and logs them on a protocol error.

Off by default. :func:`enable` (called by ``configure_logging(trace_frames=True)``) turns it
on for the sessions opened afterwards; :func:`new_frame_trace` hands a session a
:class:`FrameTrace`, or ``None`` when the switch is off, and the session only touches the
trace when it has one. Recording keeps raw bytes and a monotonic time; hex and the decoded
message type are worked out only when the trace is dumped.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any, Literal, Protocol

import firmware_protocol as fp

__all__ = ["DEFAULT_CAPACITY", "FrameTrace", "WarningLogger", "enable", "new_frame_trace"]

DEFAULT_CAPACITY = 32

Direction = Literal["in", "out"]


class WarningLogger(Protocol):
    """What :meth:`FrameTrace.dump` needs: a structlog logger's ``warning``."""

    def warning(self, event: str, *args: Any, **kw: Any) -> Any: ...


_capacity = 0  # frames each new session keeps; 0: the switch is off


def enable(capacity: int = DEFAULT_CAPACITY) -> None:
    """Sessions opened from now on keep their last ``capacity`` frames; 0 turns tracing off."""
    global _capacity  # noqa: PLW0603 - the switch is process-wide, like the log level
    if capacity < 0:
        raise ValueError(f"capacity must not be negative, got {capacity}")
    _capacity = capacity


def new_frame_trace() -> FrameTrace | None:
    """A trace for a new session, or ``None`` when the switch is off."""
    return FrameTrace(_capacity) if _capacity else None


class FrameTrace:
    """The last ``capacity`` frames in both directions, oldest first."""

    __slots__ = ("_frames", "_partial")

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self._frames: deque[tuple[Direction, float, bytes]] = deque(maxlen=capacity)
        self._partial = b""  # received bytes of a frame whose delimiter has not arrived

    def __len__(self) -> int:
        return len(self._frames)

    def record_out(self, data: bytes) -> None:
        """One write: an encoded frame with its delimiter (a lone delimiter is not kept)."""
        if data.strip(b"\x00"):
            self._frames.append(("out", time.monotonic(), bytes(data)))

    def record_in(self, data: bytes) -> None:
        """Received bytes in any split; each delimited frame is kept once it is complete."""
        now = time.monotonic()
        *frames, partial = (self._partial + data).split(b"\x00")
        for frame in frames:
            if frame:
                self._frames.append(("in", now, frame + b"\x00"))
        if len(partial) > fp.MAX_ENCODED_FRAME:  # garbage without a delimiter: keep its start
            self._frames.append(("in", now, partial[: fp.MAX_ENCODED_FRAME]))
            partial = b""
        self._partial = partial

    def frames(self) -> list[dict[str, Any]]:
        """The kept frames, oldest first, as log-friendly fields."""
        now = time.monotonic()
        return [_describe(direction, t_s, now, data) for direction, t_s, data in self._frames]

    def dump(self, logger: WarningLogger, reason: str, **fields: Any) -> None:
        """Log the kept frames as one ``frame_trace`` warning, then forget them.

        Forgetting them means each frame appears in one dump only, however many errors follow.
        """
        logger.warning("frame_trace", reason=reason, frames=self.frames(), **fields)
        self._frames.clear()


def _describe(direction: Direction, t_s: float, now_s: float, data: bytes) -> dict[str, Any]:
    try:
        kind = type(fp.decode_frame(data)).__name__
    except fp.DecodeError as exc:
        kind = f"!{type(exc).__name__}"
    return {
        "dir": direction,
        "t_s": round(t_s, 6),
        "age_ms": round((now_s - t_s) * 1000.0, 3),
        "type": kind,
        "hex": data.hex(),
    }
