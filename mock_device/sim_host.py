"""A minimal host for driving a SimulatedBoard in tests: sequence numbers and replies."""

from __future__ import annotations

from typing import TypeVar

import firmware_protocol as fp
from mock_device.sim import SimulatedBoard

M = TypeVar("M", bound=fp.Message)


class SimHost:
    def __init__(self, board: SimulatedBoard) -> None:
        self.board = board
        self.decoder = fp.StreamDecoder()
        self.received: list[fp.Message] = []
        self.seq = 0

    def next_seq(self) -> int:
        self.seq = self.seq % 255 + 1
        return self.seq

    def collect(self) -> list[fp.Message]:
        new = self.decoder.feed(self.board.read())
        self.received.extend(new)
        return new

    def pump(self, ms: float) -> list[fp.Message]:
        self.board.advance_ms(ms)
        return self.collect()

    def send(self, msg: fp.Message, seq: int | None = None) -> int:
        seq = self.next_seq() if seq is None else seq
        self.board.send(msg._replace(seq=seq))
        return seq

    def request(self, msg: fp.Message, seq: int | None = None) -> fp.Message:
        """Send and return the reply carrying the command's seq (the board answers at once)."""
        seq = self.send(msg, seq)
        for reply in self.collect():
            if reply.seq == seq and not isinstance(reply, fp.Samples | fp.Event | fp.Fault):
                return reply
        raise AssertionError(f"no reply to {msg!r}")

    def open_session(self, lease_ms: int = 250) -> fp.HelloInfo:
        info = self.request(fp.Hello(0, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 1))
        assert isinstance(info, fp.HelloInfo)
        assert isinstance(self.request(fp.SetLease(0, lease_ms)), fp.Ack)
        return info

    def of_type(self, cls: type[M]) -> list[M]:
        return [m for m in self.received if isinstance(m, cls)]

    def keep_alive_for(self, ms: int, step_ms: int = 50) -> None:
        for _ in range(ms // step_ms):
            self.pump(step_ms)
            self.request(fp.Heartbeat(0))
