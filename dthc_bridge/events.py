"""What the controller service tells the world: typed events, one class per kind.

The MQTT gateway publishes each on the ``event`` topic as ``as_payload()``; the ``type``
string there is the wire contract senders match on (``arc_lost``, ``pause``, ...). Inside
the daemon nothing matches on strings: a consumer tests the event's class.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import ClassVar

__all__ = [
    "ArcLost",
    "BoardFaulted",
    "BoardRestarted",
    "ControllerEvent",
    "LinkChanged",
    "ProgramPaused",
    "ResumePointMarked",
    "SequenceChanged",
]


@dataclass(frozen=True, slots=True)
class ControllerEvent:
    """Base of every event: ``t`` is the board time it happened at, in seconds."""

    type: ClassVar[str] = ""
    t: float

    def as_payload(self) -> dict[str, object]:
        fields = asdict(self)
        return {"t": round(fields.pop("t"), 3), "type": self.type, **fields}


@dataclass(frozen=True, slots=True)
class ArcLost(ControllerEvent):
    """The arc went out mid-cut: the cut faulted and the sender must pause."""

    type: ClassVar[str] = "arc_lost"
    reason: str


@dataclass(frozen=True, slots=True)
class ProgramPaused(ControllerEvent):
    """The sender must hold motion: a fault other than arc loss, or a stop after pierce."""

    type: ClassVar[str] = "pause"
    reason: str
    # "fault", or "stop_after_pierce" (G200 S1): the M3 is still pending, cycle start
    # answers it, so a sender waits instead of stopping the program.
    cause: str = "fault"


@dataclass(frozen=True, slots=True)
class BoardFaulted(ControllerEvent):
    """The board reported a fault (it has turned the torch off by itself)."""

    type: ClassVar[str] = "fault"
    code: str
    faults: int  # every fault latched now, as a mask of FaultCode bits


@dataclass(frozen=True, slots=True)
class ResumePointMarked(ControllerEvent):
    """A RosettaCNC ``G100 P0``: where a program may restart after an error."""

    type: ClassVar[str] = "resume_point"
    resume_line: int | None
    index: int  # the how-many-th resume point of the program


@dataclass(frozen=True, slots=True)
class LinkChanged(ControllerEvent):
    type: ClassVar[str] = "link"
    state: str
    reason: str


@dataclass(frozen=True, slots=True)
class SequenceChanged(ControllerEvent):
    """The cut sequence entered another state, at the board time it did: what a cut record
    (an operator panel's history) is built from, exact where the 10 Hz telemetry is not."""

    type: ClassVar[str] = "sequence"
    state: str
    previous: str
    error: str  # the fault's reason when ``state`` is ``faulted``, else ""


@dataclass(frozen=True, slots=True)
class BoardRestarted(ControllerEvent):
    """The board rebooted (a new boot id): whatever it was doing has stopped."""

    type: ClassVar[str] = "board_rebooted"
