"""What the cut sequence asks for: board actions and notices to the sender.

The sequence is pure; an async driver turns these into board requests and MQTT messages
and feeds the outcomes back as events.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

__all__ = [
    "Action",
    "ApplyCurrent",
    "BoardAction",
    "CommandReply",
    "MoveZ",
    "Notice",
    "PauseCause",
    "PauseProgram",
    "ProbeZ",
    "ResetFaults",
    "SetZVelocity",
    "SwitchOhmicSense",
    "SwitchTorch",
]


@dataclass(frozen=True, slots=True)
class SwitchTorch:
    on: bool


@dataclass(frozen=True, slots=True)
class SwitchOhmicSense:
    on: bool


@dataclass(frozen=True, slots=True)
class MoveZ:
    """Move Z; ``token`` comes back with the completion so a superseded move is ignored."""

    target_mm: float
    feed_mm_s: float
    token: int = 0


@dataclass(frozen=True, slots=True)
class ProbeZ:
    """Probe down until a sensor closes; ``away``: up until every one is released (G38.4/
    G38.5 on Z; a board of protocol 1.2 or later). The float switch always stops a probe;
    ``ohmic`` adds ohmic contact."""

    feed_mm_s: float
    max_travel_mm: float
    ohmic: bool
    away: bool = False


@dataclass(frozen=True, slots=True)
class SetZVelocity:
    """The THC's output: Z velocity now (streamed, expires on the board)."""

    velocity_mm_s: float


@dataclass(frozen=True, slots=True)
class ApplyCurrent:
    """Set the plasma cutter's current (where the board drives it)."""

    current_a: float


@dataclass(frozen=True, slots=True)
class ResetFaults:
    pass


@dataclass(frozen=True, slots=True)
class CommandReply:
    """The answer to the sender's pending M3/M5/...: done, or an error with a reason."""

    command: str
    ok: bool
    error: str = ""


class PauseCause(StrEnum):
    FAULT = "fault"  # docs/DESIGN.md invariant 3: the cut ended through the fault path
    ARC_LOST = "arc_lost"  # the same, because the arc went out
    STOP_AFTER_PIERCE = "stop_after_pierce"  # G200 S1: waits for cycle start
    # docs/DESIGN.md invariant 7: the operator paused a lit cut; the torch is out and raised,
    # and the program resumes through the start sequence where the torch stands.
    OPERATOR = "operator_pause"


@dataclass(frozen=True, slots=True)
class PauseProgram:
    """Ask the sender to pause (feed hold) the program, with the reason."""

    reason: str
    cause: PauseCause = PauseCause.FAULT


BoardAction = (
    SwitchTorch | SwitchOhmicSense | MoveZ | ProbeZ | SetZVelocity | ApplyCurrent | ResetFaults
)
Notice = CommandReply | PauseProgram
Action = BoardAction | Notice
