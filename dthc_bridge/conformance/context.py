"""What the checks share: the raw link, the options, the board's HELLO_INFO, the window.

Also the few board actions every check needs (query STATUS, expect an ACK, clear faults,
move Z inside the window), each raising a :class:`ConformanceError` with the reason when
the board does not do what the protocol prescribes.
"""

from __future__ import annotations

import contextlib
import statistics
from dataclasses import dataclass
from typing import Protocol

import firmware_protocol as fp

from ..link import RequestTimeout, extend_u32
from .errors import ConformanceError, UnexpectedReply
from .options import SINGLE_ATTEMPT_TIMEOUT_S, ConformanceOptions
from .rawlink import RawBoardLink
from .window import MotionWindow

__all__ = ["InputRecord", "Operator", "SuiteContext", "batch_end_us", "mm", "percentile"]

MOTION_DONE_EXTRA_S = 3.0  # beyond distance / feed, for acceleration and reporting


class Operator(Protocol):
    """The person at the bench, in interactive mode: told what to do, never asked to type."""

    def tell(self, text: str) -> None: ...


@dataclass(frozen=True, slots=True)
class InputRecord:
    """A stretch of the run whose input edges the input-events check audits."""

    before: fp.Status
    after: fp.Status
    since: int  # history marks
    until: int
    how: str


@dataclass(slots=True)
class SuiteContext:
    link: RawBoardLink
    options: ConformanceOptions
    operator: Operator | None = None
    info: fp.HelloInfo | None = None
    window: MotionWindow | None = None
    session_open: bool = False
    velocity_seq: int = 0
    inputs: InputRecord | None = None

    def require_info(self) -> fp.HelloInfo:
        if self.info is None:
            raise ConformanceError("no HELLO_INFO from the board")
        return self.info

    def require_window(self) -> MotionWindow:
        if self.window is None:
            raise ConformanceError("no motion window (the reference position is unknown)")
        return self.window

    def capable(self, capability: fp.Capability) -> bool:
        return bool(self.require_info().capabilities & capability)

    @property
    def feed_um_s(self) -> int:
        return round(self.options.feed_mm_s * 1000)

    # --- board actions ---------------------------------------------------------------------

    async def status(self) -> fp.Status:
        reply = await self.link.request(fp.Query(0, fp.QueryWhat.STATUS))
        if not isinstance(reply, fp.Status):
            raise UnexpectedReply("QUERY(STATUS)", reply, "STATUS")
        return reply

    async def expect_ack(self, command: fp.Message, *, once: bool = False) -> fp.Ack:
        """Send ``command`` (``once``: a single attempt, never retransmitted); its ACK."""
        if once:
            reply = await self.link.request(command, timeout_s=SINGLE_ATTEMPT_TIMEOUT_S, attempts=1)
        else:
            reply = await self.link.request(command)
        if not isinstance(reply, fp.Ack):
            raise UnexpectedReply(fp.message_type(command).name, reply, "ACK")
        return reply

    async def clear_faults(self) -> fp.Status:
        """Reset whatever faults are latched (their causes must be gone); the fresh STATUS."""
        status = await self.status()
        if status.faults:
            await self.expect_ack(fp.FaultReset(0, status.faults))
            status = await self.status()
        return status

    async def board_time_us(self) -> int:
        """The board clock now (64 bits), from a CLOCK_QUERY."""
        reply = await self.link.request(fp.ClockQuery(0))
        if not isinstance(reply, fp.Clock):
            raise UnexpectedReply("CLOCK_QUERY", reply, "CLOCK")
        return reply.t_us

    async def move_z(
        self, target_um: int, *, inside_window: bool = True, seq: int = 0
    ) -> fp.MotionDone:
        """Z_MOVE (with ``seq``, or the next one) and wait for its MOTION_DONE; the target
        must lie inside the window unless ``inside_window`` is False (the start move)."""
        if inside_window:
            self.require_window().check(target_um)
        start = await self.status()
        mark = self.link.mark()
        ack = await self.expect_ack(fp.ZMove(seq, target_um, self.feed_um_s), once=True)
        timeout_s = abs(target_um - start.z_um) / self.feed_um_s + MOTION_DONE_EXTRA_S
        found = await self.link.wait_for_type(
            fp.MotionDone, timeout_s, since=mark, where=lambda m: m.seq == ack.seq
        )
        if found is None:
            await self.link.request(fp.ZStop(0))
            raise ConformanceError(
                f"Z_MOVE to {mm(target_um)} mm: no MOTION_DONE within {timeout_s:.1f} s"
            )
        done = found[1]
        if done.result != fp.MotionResult.REACHED:
            raise ConformanceError(
                f"Z_MOVE to {mm(target_um)} mm ended {_name(fp.MotionResult, done.result)} "
                f"at {mm(done.z_um)} mm"
            )
        return done

    async def stop_z(self) -> None:
        with contextlib.suppress(RequestTimeout):
            await self.link.request(fp.ZStop(0))


def mm(um: float) -> str:
    """Micrometres as millimetres with three decimals, for figures."""
    return f"{um / 1000:.3f}"


def _name(table: type[fp.MotionResult] | type[fp.ProbeOutcome], value: int) -> str:
    try:
        return table(value).name
    except ValueError:
        return f"code {value}"


def batch_end_us(batch: fp.Samples, reference_us: int) -> int:
    """Board time (64 bits, near ``reference_us``) of a batch's last sample, where its
    ``z_um``, ``inputs`` and ``status`` were taken."""
    t0 = extend_u32(batch.t0_us, reference_us)
    return t0 + max(len(batch.samples_cv) - 1, 0) * batch.period_us


def percentile(values: list[float], pct: float) -> float:
    """The ``pct`` percentile (0..100), interpolated; the value itself for one sample."""
    if len(values) == 1:
        return values[0]
    cuts = statistics.quantiles(values, n=100, method="inclusive")
    return cuts[min(max(round(pct) - 1, 0), 98)]
