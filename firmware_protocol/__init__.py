"""The DTHC wire protocol: spec (PROTOCOL.md), sans-io Python codec, golden vectors.

Imports no asyncio, serial or USB library: the daemon, the mock board and the tests all
speak through this package, so the two ends cannot drift apart.
"""

from __future__ import annotations

from .codec import (
    LAYOUTS,
    crc16,
    decode_frame,
    decode_message,
    encode,
    encode_frame,
    encode_message,
    message_type,
)
from .constants import *  # noqa: F403 - the code tables are the public surface
from .constants import __all__ as _constants_all
from .errors import (
    BadLength,
    CobsError,
    CrcMismatch,
    DecodeError,
    EncodeError,
    FrameTooLong,
    ProtocolError,
    UnknownMessageType,
)
from .messages import *  # noqa: F403 - every message class is public
from .messages import __all__ as _messages_all
from .stream import DecoderStats, StreamDecoder

__all__ = [  # noqa: PLE0604 - built from the submodules' own __all__
    *_constants_all,
    *_messages_all,
    "LAYOUTS",
    "BadLength",
    "CobsError",
    "CrcMismatch",
    "DecodeError",
    "DecoderStats",
    "EncodeError",
    "FrameTooLong",
    "ProtocolError",
    "StreamDecoder",
    "UnknownMessageType",
    "crc16",
    "decode_frame",
    "decode_message",
    "encode",
    "encode_frame",
    "encode_message",
    "message_type",
]
