"""Decode and encode errors. Each carries the data needed to diagnose it."""

from __future__ import annotations

__all__ = [
    "BadLength",
    "CobsError",
    "CrcMismatch",
    "DecodeError",
    "EncodeError",
    "FrameTooLong",
    "ProtocolError",
    "UnknownMessageType",
]


class ProtocolError(Exception):
    """Base of every error raised by :mod:`firmware_protocol`."""


class DecodeError(ProtocolError):
    """A received frame could not be turned into a message. ``raw`` holds its bytes."""

    def __init__(self, message: str, raw: bytes) -> None:
        super().__init__(f"{message} (raw={raw[:64].hex()}{'…' if len(raw) > 64 else ''})")
        self.raw = raw


class CobsError(DecodeError):
    """The bytes between two delimiters are not valid COBS."""


class FrameTooLong(DecodeError):
    """More than MAX_ENCODED_FRAME bytes arrived without a delimiter."""


class CrcMismatch(DecodeError):
    def __init__(self, expected: int, received: int, raw: bytes) -> None:
        super().__init__(
            f"CRC mismatch: computed 0x{expected:04X}, frame says 0x{received:04X}", raw
        )
        self.expected = expected
        self.received = received


class UnknownMessageType(DecodeError):
    def __init__(self, msg_type: int, raw: bytes) -> None:
        super().__init__(f"unknown message type 0x{msg_type:02X}", raw)
        self.msg_type = msg_type


class BadLength(DecodeError):
    def __init__(self, msg_type: int, expected: str, received: int, raw: bytes) -> None:
        super().__init__(
            f"message type 0x{msg_type:02X}: payload of {received} bytes, expected {expected}", raw
        )
        self.msg_type = msg_type
        self.expected = expected
        self.received = received


class EncodeError(ProtocolError):
    """A message field does not fit its wire type."""

    def __init__(self, message_name: str, detail: str) -> None:
        super().__init__(f"cannot encode {message_name}: {detail}")
        self.message_name = message_name
        self.detail = detail
