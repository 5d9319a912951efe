"""What the cut sequence asks for: board actions and notices to the sender.

The sequence is pure; an async driver turns these into board requests and MQTT messages
and feeds the outcomes back as events.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "Action",
    "BoardAction",
    "CommandReply",
    "MoveZ",
    "Notice",
    "OhmicSense",
    "PauseProgram",
    "ProbeZ",
    "ResetFaults",
    "SetCurrent",
    "StopZ",
    "Torch",
    "ZVelocity",
]


@dataclass(frozen=True, slots=True)
class Torch:
    on: bool


@dataclass(frozen=True, slots=True)
class OhmicSense:
    on: bool


@dataclass(frozen=True, slots=True)
class MoveZ:
    """Move Z; ``token`` comes back with the completion so a superseded move is ignored."""

    target_mm: float
    feed_mm_s: float
    token: int = 0


@dataclass(frozen=True, slots=True)
class ProbeZ:
    feed_mm_s: float
    max_travel_mm: float
    ohmic: bool
    float_switch: bool


@dataclass(frozen=True, slots=True)
class ZVelocity:
    velocity_mm_s: float


@dataclass(frozen=True, slots=True)
class StopZ:
    pass


@dataclass(frozen=True, slots=True)
class SetCurrent:
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


@dataclass(frozen=True, slots=True)
class PauseProgram:
    """Ask the sender to pause (feed hold) the program, with the reason."""

    reason: str


BoardAction = Torch | OhmicSense | MoveZ | ProbeZ | ZVelocity | StopZ | SetCurrent | ResetFaults
Notice = CommandReply | PauseProgram
Action = BoardAction | Notice
