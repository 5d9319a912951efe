"""Failures of the conformance suite itself, each carrying what the report needs to say."""

from __future__ import annotations

import firmware_protocol as fp

__all__ = ["ConformanceError", "OutsideWindow", "UnexpectedReply"]


class ConformanceError(Exception):
    """Base of the suite's own errors; a check that raises one is reported as failed."""


class UnexpectedReply(ConformanceError):
    """The board answered a command, but not with what the protocol prescribes."""

    def __init__(self, command: str, reply: fp.Message, expected: str) -> None:
        super().__init__(f"{command}: expected {expected}, got {describe_reply(reply)}")
        self.command = command
        self.reply = reply
        self.expected = expected


class OutsideWindow(ConformanceError):
    """A Z target the suite was about to send lies outside the confirmed motion window."""

    def __init__(self, target_um: int, low_um: int, high_um: int) -> None:
        super().__init__(
            f"Z target {target_um / 1000:.3f} mm is outside the motion window "
            f"{low_um / 1000:.3f}..{high_um / 1000:.3f} mm; nothing was sent"
        )
        self.target_um = target_um
        self.low_um = low_um
        self.high_um = high_um


def describe_reply(reply: fp.Message) -> str:
    """``NAK FAULT_LATCHED (detail 0)``, ``ACK``, ``STATUS``: a reply as a report names it."""
    if isinstance(reply, fp.Nak):
        try:
            name = fp.NakCode(reply.code).name
        except ValueError:
            name = f"code {reply.code}"
        return f"NAK {name} (detail {reply.detail})"
    return fp.message_type(reply).name
