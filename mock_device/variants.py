"""Firmware variants with deliberate faults, for the conformance suite and safety tests.

Each breaks one rule of PROTOCOL.md the way a real firmware bug would. The plant's ground
truth still audits the lease, so a variant that keeps the torch on is counted.
"""

from __future__ import annotations

import struct

from cobs import cobs

import firmware_protocol as fp

from .firmware import BoardFirmware

__all__ = [
    "VARIANTS",
    "DuplicatesActedTwice",
    "IdleLapseLatched",
    "IdleLapseUnreported",
    "LeaseIgnored",
    "WrongCrcVariant",
]


class LeaseIgnored(BoardFirmware):
    """Never notices that the host went quiet: the torch stays on."""

    def _check_lease(self) -> None:
        return


class IdleLapseLatched(BoardFirmware):
    """Latches LEASE_EXPIRED whenever the lease runs out, at rest too (protocol 1.0's rule,
    while announcing 1.1): an idle table must be re-armed."""

    def at_rest(self) -> bool:
        return False


class IdleLapseUnreported(BoardFirmware):
    """Latches nothing when the lease runs out at rest, and says nothing either."""

    def _send(self, msg: fp.Message) -> bytes:
        idle_lapse = (
            isinstance(msg, fp.Fault)
            and msg.code == fp.FaultCode.LEASE_EXPIRED
            and msg.detail == fp.LEASE_DETAIL_IDLE
        )
        if idle_lapse:
            return b""
        return super()._send(msg)


class DuplicatesActedTwice(BoardFirmware):
    """Executes every retransmission again instead of re-sending the remembered reply."""

    def _handle(self, msg: fp.Message) -> None:
        self.replies.clear()
        super()._handle(msg)


def _crc16_mcrf4xx(data: bytes) -> int:
    # Klipper's "CCITT": reflected, init 0xFFFF; check value 0x6F91. Not the spec's CRC.
    crc = 0xFFFF
    for byte in data:
        mixed = byte ^ (crc & 0xFF)
        mixed ^= (mixed << 4) & 0xFF
        crc = (((mixed << 8) | (crc >> 8)) ^ (mixed >> 4) ^ (mixed << 3)) & 0xFFFF
    return crc


class WrongCrcVariant(BoardFirmware):
    """Frames its messages with CRC-16/MCRF4XX instead of CRC-16/CCITT-FALSE."""

    def _encode(self, msg: fp.Message) -> bytes:
        body = fp.encode_message(msg)
        encoded: bytes = cobs.encode(body + struct.pack(">H", _crc16_mcrf4xx(body)))
        return encoded + b"\x00"


VARIANTS: dict[str, type[BoardFirmware]] = {
    "good": BoardFirmware,
    "lease-ignored": LeaseIgnored,
    "idle-lapse-latched": IdleLapseLatched,
    "idle-lapse-unreported": IdleLapseUnreported,
    "duplicates-twice": DuplicatesActedTwice,
    "wrong-crc": WrongCrcVariant,
}
