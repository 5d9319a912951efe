"""Boards with deliberate faults, for the conformance suite and safety tests.

Each breaks one rule of PROTOCOL.md the way a real firmware bug would. The board logic is
the reference firmware's (firmware/board/, C); each fault is made at the mock's link, by
what reaches the board or what leaves it, except protocol 1.0's lease, which is a build of
the same C (BOARD_LEASE_IDLE_LAPSE=0). The plant's ground truth still audits the lease, so
a variant that keeps the torch on is counted.
"""

from __future__ import annotations

import struct

from cobs import cobs

import firmware_protocol as fp
from firmware_protocol import MsgType

from .board_logic import UNKNOWN_TYPE, BoardLogic, frame_type

__all__ = [
    "VARIANTS",
    "DuplicatesActedTwice",
    "IdleLapseLatched",
    "IdleLapseUnreported",
    "LeaseIgnored",
    "WrongCrcVariant",
]

# A frame of a type the board's codec does not know, with a valid CRC and seq 0: the board
# takes it as a sign of life (the lease is renewed, PROTOCOL.md section 7) and answers
# nothing.
_SIGN_OF_LIFE = fp.encode_frame(bytes((UNKNOWN_TYPE, 0)))


class LeaseIgnored(BoardLogic):
    """Never notices that the host went quiet: the torch stays on. (Its link feeds the board
    a sign of life before every tick, as if the host never stopped.)"""

    def _before_tick(self) -> None:
        self.c.receive(_SIGN_OF_LIFE)


class IdleLapseLatched(BoardLogic):
    """Latches LEASE_EXPIRED whenever the lease runs out, at rest too (protocol 1.0's rule,
    while announcing 1.1 or later): an idle table must be re-armed."""

    build = "lease-1.0"


class IdleLapseUnreported(BoardLogic):
    """Latches nothing when the lease runs out at rest, and says nothing either."""

    def _outgoing(self, frame: bytes) -> bytes | None:
        if frame_type(frame) == MsgType.FAULT:
            fault = fp.decode_frame(frame)
            assert isinstance(fault, fp.Fault)
            idle_lapse = (
                fault.code == fp.FaultCode.LEASE_EXPIRED and fault.detail == fp.LEASE_DETAIL_IDLE
            )
            if idle_lapse:
                return None
        return super()._outgoing(frame)


class DuplicatesActedTwice(BoardLogic):
    """Executes every retransmission again instead of re-sending the remembered reply. (Its
    link gives each sequenced host frame a fresh seq, so the board never recognises a
    retransmission, and gives the replies their host seq back.)"""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._next_seq = 0
        self._host_seq: dict[int, int] = {}

    def _host_frame(self, enc: bytes) -> None:
        try:
            raw = cobs.decode(enc)
        except cobs.DecodeError:
            raw = b""
        crc_ok = len(raw) >= 4 and fp.crc16(raw[:-2]) == int.from_bytes(raw[-2:], "big")
        if crc_ok and raw[1]:  # any sequenced frame, of a known type or not
            self._next_seq = self._next_seq % 255 + 1
            self._host_seq[self._next_seq] = raw[1]
            enc = fp.encode_frame(raw[:1] + bytes((self._next_seq,)) + raw[2:-2])[:-1]
        super()._host_frame(enc)

    def _outgoing(self, frame: bytes) -> bytes | None:
        body = cobs.decode(frame[:-1])[:-2]
        if body[1]:
            host_seq = self._host_seq.get(body[1], body[1])
            frame = fp.encode_frame(body[:1] + bytes((host_seq,)) + body[2:])
        return super()._outgoing(frame)


def _crc16_mcrf4xx(data: bytes) -> int:
    # Klipper's "CCITT": reflected, init 0xFFFF; check value 0x6F91. Not the spec's CRC.
    crc = 0xFFFF
    for byte in data:
        mixed = byte ^ (crc & 0xFF)
        mixed ^= (mixed << 4) & 0xFF
        crc = (((mixed << 8) | (crc >> 8)) ^ (mixed >> 4) ^ (mixed << 3)) & 0xFFFF
    return crc


class WrongCrcVariant(BoardLogic):
    """Frames its messages with CRC-16/MCRF4XX instead of CRC-16/CCITT-FALSE."""

    def _outgoing(self, frame: bytes) -> bytes | None:
        out = super()._outgoing(frame)
        if out is None:
            return None
        body = cobs.decode(out[:-1])[:-2]
        encoded: bytes = cobs.encode(body + struct.pack(">H", _crc16_mcrf4xx(body)))
        return encoded + b"\x00"


VARIANTS: dict[str, type[BoardLogic]] = {
    "good": BoardLogic,
    "lease-ignored": LeaseIgnored,
    "idle-lapse-latched": IdleLapseLatched,
    "idle-lapse-unreported": IdleLapseUnreported,
    "duplicates-twice": DuplicatesActedTwice,
    "wrong-crc": WrongCrcVariant,
}
