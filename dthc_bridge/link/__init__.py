"""The board link: sessions over a transport, reliability, lease, reconnect."""

from __future__ import annotations

from .clock import BoardClock, BoardTimeline, extend_u32
from .errors import (
    BoardRebooted,
    BoardTooOld,
    LinkDown,
    LinkError,
    NegativeAck,
    ProtocolVersionMismatch,
    RequestTimeout,
)
from .session import BoardSession, SessionTrace
from .stats import LinkStats
from .supervisor import LinkState, LinkStateChange, LinkSupervisor
from .timing import LinkTiming

__all__ = [
    "BoardClock",
    "BoardRebooted",
    "BoardSession",
    "BoardTimeline",
    "BoardTooOld",
    "LinkDown",
    "LinkError",
    "LinkState",
    "LinkStateChange",
    "LinkStats",
    "LinkSupervisor",
    "LinkTiming",
    "NegativeAck",
    "ProtocolVersionMismatch",
    "RequestTimeout",
    "SessionTrace",
    "extend_u32",
]
