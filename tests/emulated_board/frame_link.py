"""A host for tests that talk frames to a board on a pty, without the daemon: encode,
write, decode what comes back; requests retransmitted as the daemon does."""

from __future__ import annotations

import os
import select
import time
import tty
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import firmware_protocol as fp

__all__ = ["FrameLink"]

ReplyT = TypeVar("ReplyT", bound=fp.Message)
_UNSOLICITED = (fp.Samples, fp.Event, fp.Fault, fp.MotionDone, fp.ProbeResult)


class FrameLink:
    """Frames over the board's pty; every message received is kept in ``received``."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.decoder = fp.StreamDecoder()
        self.received: list[fp.Message] = []
        self._seq = 0
        os.write(self.fd, b"\x00")  # end whatever partial frame the board holds

    def close(self) -> None:
        os.close(self.fd)

    def next_seq(self) -> int:
        self._seq = self._seq % 255 + 1
        return self._seq

    def pump(self, wait_s: float) -> None:
        """Read what has arrived, waiting up to ``wait_s`` for the first bytes."""
        ready, _, _ = select.select([self.fd], [], [], wait_s)
        if ready:
            self.received.extend(self.decoder.feed(os.read(self.fd, 65536)))

    def run_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            self.pump(min(left, 0.01))

    def send(self, msg: fp.Message) -> None:
        os.write(self.fd, fp.encode(msg))

    def request(
        self, make: Callable[[int], fp.Message], attempts: int = 5, timeout_s: float = 0.1
    ) -> fp.Message:
        """Send ``make(seq)``; its reply (any non-report message with that seq). Sent again
        after ``timeout_s``, ``attempts`` times in all (a board whose receive buffer is
        full drops what does not fit; a retransmission is answered from its memory)."""
        msg = make(self.next_seq())
        mark = len(self.received)
        for _ in range(attempts):
            self.send(msg)
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                self.pump(0.01)
                for reply in self.received[mark:]:
                    if not isinstance(reply, _UNSOLICITED) and reply.seq == msg.seq:
                        return reply
        raise TimeoutError(f"no reply to {msg!r} in {attempts} attempts")

    def expect(self, make: Callable[[int], fp.Message], kind: type[ReplyT]) -> ReplyT:
        reply = self.request(make)
        assert isinstance(reply, kind), f"{make(0)!r}: {reply!r}, expected {kind.__name__}"
        return reply

    def hello(self) -> fp.HelloInfo:
        return self.expect(
            lambda s: fp.Hello(s, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 0x5EED), fp.HelloInfo
        )

    def status(self) -> fp.Status:
        return self.expect(lambda s: fp.Query(s, fp.QueryWhat.STATUS), fp.Status)

    def reports(self, kind: type[ReplyT], since: int = 0) -> list[ReplyT]:
        return [m for m in self.received[since:] if isinstance(m, kind)]
