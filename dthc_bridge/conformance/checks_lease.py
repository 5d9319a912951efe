"""Checks of the host lease (PROTOCOL.md §4-§5, §8): lease_expiry and lease_idle_lapse.

The lease ends one of two ways, decided by the board's state when it runs out. In use
(the torch relay or ohmic sensing on, or Z not at rest) it latches LEASE_EXPIRED and drops
the outputs until FAULT_RESET: ``lease_expiry`` switches ohmic sensing on (the torch relay
too with ``--allow-torch-relay``) and watches them drop. At rest (nothing lit, Z still,
protocol 1.1) it reports one FAULT LEASE_EXPIRED with detail 1 and latches nothing: the
next host frame renews it. ``lease_idle_lapse`` checks that with every output off.
"""

from __future__ import annotations

import asyncio

import firmware_protocol as fp
from firmware_protocol import Capability, FaultCode, StatusBit

from ..link import RequestTimeout, extend_u32
from .context import SuiteContext, batch_end_us
from .errors import ConformanceError
from .options import LEASE_TOLERANCE_US, LEASE_WAIT_EXTRA_S, SUITE_LEASE_MS
from .report import CheckResult, Value, failed, passed, skipped

__all__ = ["check_lease_expiry", "check_lease_idle_lapse"]

SAMPLES_AFTER_FAULT_S = 0.2  # wait this long for a batch showing the outputs off
# After an idle lapse's report the host stays silent this much longer than the FAULT
# re-report period, so a board that repeats it (as for a latched fault) is caught.
FAULT_REPEAT_S = 0.25  # PROTOCOL.md §8: a latched fault is re-reported every 250 ms
IDLE_REPEAT_WATCH_S = FAULT_REPEAT_S + 0.15
IN_USE = StatusBit.TORCH_ON | StatusBit.OHMIC_SENSE | StatusBit.Z_BUSY
IDLE_LAPSE_MINOR = 1  # the protocol minor that brought the idle lapse (1.1)


def _is_lease_fault(msg: fp.Fault) -> bool:
    return msg.code == FaultCode.LEASE_EXPIRED


# --- in use: latched ---------------------------------------------------------------------


async def check_lease_expiry(ctx: SuiteContext) -> list[CheckResult]:
    """Host silent with an output on: within lease + one sample period the board latches
    LEASE_EXPIRED (detail 0) and drops its outputs; later frames do not revive them;
    FAULT_RESET re-arms."""
    link = ctx.link
    opts = ctx.options
    await ctx.clear_faults()
    outputs = 0
    if ctx.capable(Capability.OHMIC):
        outputs |= StatusBit.OHMIC_SENSE
    if opts.allow_torch_relay:
        outputs |= StatusBit.TORCH_ON
    if not outputs:
        return [
            skipped(
                "lease_expiry",
                "no output to switch on (no ohmic sensing, no --allow-torch-relay): with "
                "nothing lit the lease lapses without latching (see lease_idle_lapse)",
                hint="--allow-torch-relay (cutter off) lets the check click the relay",
            )
        ]
    names = "+".join(n for n, b in (("ohmic sense", 2), ("torch", 1)) if outputs & b)
    await ctx.expect_ack(fp.SetLease(0, opts.lease_ms))
    values: dict[str, Value] = {"lease_ms": opts.lease_ms, "outputs": names}
    try:
        if outputs & StatusBit.OHMIC_SENSE:
            await ctx.expect_ack(fp.OhmicSense(0, True))
        if outputs & StatusBit.TORCH_ON:
            await ctx.expect_ack(fp.Torch(0, True))
        on = await ctx.status()
        if on.status & outputs != outputs:
            raise ConformanceError(f"could not switch on {names} (status 0x{on.status:02x})")
        async with link.silent():
            measured = await _fall_silent(ctx, outputs)
        after = await ctx.status()  # a frame after expiry: it must not revive anything
    finally:
        await _rearm(ctx)
    t_last, fault, period_us, last_on_us, first_off_us = measured
    limit_us = opts.lease_ms * 1000 + period_us
    values.update(limit_ms=limit_us / 1e3, sample_period_us=period_us)
    problems = []
    if fault is None:
        problems.append(
            f"no LEASE_EXPIRED fault within {opts.lease_ms + LEASE_WAIT_EXTRA_S * 1e3:.0f} ms "
            "of the last host frame"
        )
    else:
        fault_us, late = _late(fault, t_last, limit_us, "LEASE_EXPIRED", opts.lease_ms)
        values.update(fault_after_ms=fault_us / 1e3, detail=fault.detail)
        problems += late
        if fault.detail != fp.LEASE_DETAIL_LATCHED:
            problems.append(
                f"LEASE_EXPIRED with {names} on reported detail {fault.detail} (an idle lapse), "
                f"not {fp.LEASE_DETAIL_LATCHED} (latched)"
            )
    if last_on_us is not None:
        values["last_on_ms"] = last_on_us / 1e3
        if last_on_us > limit_us + LEASE_TOLERANCE_US:
            problems.append(f"{names} still on {last_on_us / 1e3:.1f} ms after the last frame")
    if fault is not None and first_off_us is None:
        problems.append(f"no SAMPLES showed {names} off after the fault")
    if fault is not None and not after.faults & (1 << FaultCode.LEASE_EXPIRED):
        problems.append("LEASE_EXPIRED no longer latched after later host frames")
    if fault is not None and after.status & (StatusBit.TORCH_ON | StatusBit.OHMIC_SENSE):
        problems.append(f"outputs on again after later host frames (status 0x{after.status:02x})")
    if problems:
        hint = "the board must time the lease in its sample interrupt (PROTOCOL.md §4, §10.4)"
        return [failed("lease_expiry", "; ".join(problems), hint=hint, values=values)]
    if last_on_us is not None and first_off_us is not None:
        values["first_off_ms"] = first_off_us / 1e3
        watched = (
            f"{names} last reported on at {last_on_us / 1e3:.1f} ms, off at "
            f"{first_off_us / 1e3:.1f} ms"
        )
    else:
        watched = f"{names} never reported on in the silent period"
    figure = (
        f"LEASE_EXPIRED {values['fault_after_ms']:.1f} ms after the last host frame (limit "
        f"{opts.lease_ms} + {period_us / 1e3:g} ms); {watched}; latched until FAULT_RESET"
    )
    return [passed("lease_expiry", figure, values=values)]


async def _last_heard_us(ctx: SuiteContext) -> tuple[int, int]:
    """Send a CLOCK_QUERY, the last frame before a silence. Its reply stamps, in board time,
    when the board last heard the host: the lease runs from there. (That time, the mark
    from which to look for what the silence brings.)"""
    link = ctx.link
    for _ in range(3):
        mark = link.mark()
        try:
            reply = await link.request(fp.ClockQuery(0), attempts=1)
        except RequestTimeout:
            continue  # a lost reply: ask again (a query renews the lease, that is fine)
        if isinstance(reply, fp.Clock):
            return reply.t_us, mark
    raise ConformanceError("CLOCK_QUERY unanswered before the silent period")


async def _fall_silent(
    ctx: SuiteContext, outputs: int
) -> tuple[int, fp.Fault | None, int, int | None, int | None]:
    """Fall silent after a last CLOCK_QUERY. Returns when the board last heard the host,
    the FAULT, the sample period, and (relative to that time) the last batch that showed an
    output on and the first that showed them off after the fault."""
    link = ctx.link
    opts = ctx.options
    t_last, mark = await _last_heard_us(ctx)
    wait_s = opts.lease_ms / 1000 + LEASE_WAIT_EXTRA_S
    found = await link.wait_for_type(fp.Fault, wait_s, since=mark, where=_is_lease_fault)
    fault = found[1] if found is not None else None
    first_off_us = None
    if fault is not None:
        fault_us = extend_u32(fault.t_us, t_last)
        off = await link.wait_for(
            lambda m: (
                isinstance(m, fp.Samples)
                and not m.status & outputs
                and batch_end_us(m, t_last) >= fault_us
            ),
            SAMPLES_AFTER_FAULT_S,
            since=mark,
        )
        if off is not None:
            assert isinstance(off.msg, fp.Samples)
            first_off_us = batch_end_us(off.msg, t_last) - t_last
    batches = link.messages(fp.Samples, since=mark)
    period_us = _period_us(ctx, batches)
    on_times = [batch_end_us(b, t_last) - t_last for b in batches if b.status & outputs]
    last_on_us = max(on_times) if on_times else None
    return t_last, fault, period_us, last_on_us, first_off_us


def _period_us(ctx: SuiteContext, batches: list[fp.Samples]) -> int:
    return batches[-1].period_us if batches else 1_000_000 // ctx.require_info().sample_rate_hz


async def _rearm(ctx: SuiteContext) -> None:
    """Outputs off, the lease fault reset, the suite's lease back."""
    await ctx.expect_ack(fp.Torch(0, False))
    if ctx.capable(Capability.OHMIC):
        await ctx.expect_ack(fp.OhmicSense(0, False))
    await ctx.clear_faults()
    await ctx.expect_ack(fp.SetLease(0, SUITE_LEASE_MS))


# --- at rest: reported, not latched ------------------------------------------------------


async def check_lease_idle_lapse(ctx: SuiteContext) -> list[CheckResult]:
    """Host silent with nothing lit and Z still: within lease + one sample period one FAULT
    LEASE_EXPIRED detail 1 with no fault bit, not repeated while the host stays silent;
    nothing latched afterwards; the next frame renews the lease, so a second silence is
    reported again (protocol 1.1, PROTOCOL.md §4)."""
    opts = ctx.options
    info = ctx.require_info()
    if info.proto_minor < IDLE_LAPSE_MINOR:
        return [
            skipped(
                "lease_idle_lapse",
                f"the board speaks protocol {info.proto_major}.{info.proto_minor}: the idle "
                f"lapse came with {fp.PROTOCOL_MAJOR}.{IDLE_LAPSE_MINOR} (a lease running out "
                "at rest latches LEASE_EXPIRED there, which lease_expiry covers)",
            )
        ]
    await _come_to_rest(ctx)
    await ctx.expect_ack(fp.SetLease(0, opts.lease_ms))
    try:
        async with ctx.link.silent():
            first = await _idle_silence(ctx, IDLE_REPEAT_WATCH_S)
            after = await ctx.status()  # the host is back: this renews the lease
            second = None
            if not after.faults & (1 << FaultCode.LEASE_EXPIRED):
                # Once per lapse: renewed by that frame, the lease lapses again.
                second = await _idle_silence(ctx, 0.0)
        final = await ctx.status()
    finally:
        await _rearm(ctx)
    t_last, lapse, reports, period_us = first
    limit_us = opts.lease_ms * 1000 + period_us
    values: dict[str, Value] = {
        "lease_ms": opts.lease_ms,
        "limit_ms": limit_us / 1e3,
        "sample_period_us": period_us,
        "reports": reports,
        "watched_ms": round((opts.lease_ms / 1000 + IDLE_REPEAT_WATCH_S) * 1e3),
    }
    problems = []
    if lapse is None:
        problems.append(
            f"no FAULT LEASE_EXPIRED within {opts.lease_ms + LEASE_WAIT_EXTRA_S * 1e3:.0f} ms "
            "of the last host frame with nothing lit and Z at rest"
        )
    else:
        lapse_us, late = _late(lapse, t_last, limit_us, "idle lapse reported", opts.lease_ms)
        values.update(
            lapse_after_ms=lapse_us / 1e3, detail=lapse.detail, faults=f"0x{lapse.faults:04x}"
        )
        problems += late
    latched = lapse is not None and (
        lapse.detail != fp.LEASE_DETAIL_IDLE or lapse.faults & (1 << FaultCode.LEASE_EXPIRED)
    )
    if lapse is not None and latched:
        problems.append(
            f"the lease latched LEASE_EXPIRED at rest (detail {lapse.detail}, fault set "
            f"0x{lapse.faults:04x}): an idle lapse is reported with detail "
            f"{fp.LEASE_DETAIL_IDLE} and latches nothing, so an idle table needs no re-arm"
        )
    elif reports > 1:
        problems.append(
            f"the idle lapse was reported {reports} times in one silence (once per lapse)"
        )
    if not latched and after.status & StatusBit.FAULT_LATCHED:
        problems.append(
            f"a fault latched after an idle lapse (faults 0x{after.faults:04x}, status "
            f"0x{after.status:02x}): the next frame must find nothing to re-arm"
        )
    if lapse is not None and second is not None and second[1] is None:
        problems.append(
            "no report of a second lapse after the host came back and fell silent again: "
            "the host's frames did not renew the lease"
        )
    elif second is not None and second[1] is not None:
        values["second_detail"] = second[1].detail
        if second[1].detail != fp.LEASE_DETAIL_IDLE:
            problems.append(f"the second lapse reported detail {second[1].detail}, not idle")
    if not latched and final.faults & (1 << FaultCode.LEASE_EXPIRED):
        problems.append("LEASE_EXPIRED latched after the second idle lapse")
    if problems:
        hint = (
            "at rest (torch, ohmic sensing off, Z still) a lapse is one FAULT LEASE_EXPIRED "
            "detail 1, nothing latched, renewed by the next valid frame (PROTOCOL.md §4)"
        )
        return [failed("lease_idle_lapse", "; ".join(problems), hint=hint, values=values)]
    figure = (
        f"reported {values['lapse_after_ms']:.1f} ms after the last host frame (limit "
        f"{opts.lease_ms} + {period_us / 1e3:g} ms), detail 1, nothing latched; once in "
        f"{values['watched_ms']} ms of silence; renewed by the next frame (a second lapse "
        "reported again)"
    )
    return [passed("lease_idle_lapse", figure, values=values)]


async def _come_to_rest(ctx: SuiteContext) -> None:
    """Faults cleared, torch relay and ohmic sensing off, Z still (stopped if it moves)."""
    await ctx.clear_faults()
    await ctx.expect_ack(fp.Torch(0, False))
    if ctx.capable(Capability.OHMIC):
        await ctx.expect_ack(fp.OhmicSense(0, False))
    status = await ctx.status()
    for _ in range(20):
        if not status.status & IN_USE:
            return
        if status.status & StatusBit.Z_BUSY:
            await ctx.stop_z()
        await asyncio.sleep(0.05)
        status = await ctx.status()
    raise ConformanceError(f"the board does not come to rest (status 0x{status.status:02x})")


async def _idle_silence(ctx: SuiteContext, watch_s: float) -> tuple[int, fp.Fault | None, int, int]:
    """Fall silent after a last CLOCK_QUERY, wait for the lease's FAULT, then stay silent
    ``watch_s`` longer. Returns when the board last heard the host, the first lease FAULT,
    how many lease FAULTs came in the whole silence, and the sample period."""
    link = ctx.link
    opts = ctx.options
    t_last, mark = await _last_heard_us(ctx)
    wait_s = opts.lease_ms / 1000 + LEASE_WAIT_EXTRA_S
    found = await link.wait_for_type(fp.Fault, wait_s, since=mark, where=_is_lease_fault)
    if found is not None and watch_s:
        await asyncio.sleep(watch_s)
    reports = [m for m in link.messages(fp.Fault, since=mark) if _is_lease_fault(m)]
    period_us = _period_us(ctx, link.messages(fp.Samples, since=mark))
    return t_last, (found[1] if found is not None else None), len(reports), period_us


def _late(
    fault: fp.Fault, t_last: int, limit_us: int, what: str, lease_ms: int
) -> tuple[int, list[str]]:
    """How long after the host's last frame (board µs) the lease's FAULT came, and the
    problem when that is past lease + one sample period (``limit_us``, with tolerance)."""
    after_us = extend_u32(fault.t_us, t_last) - t_last
    if after_us <= limit_us + LEASE_TOLERANCE_US:
        return after_us, []
    period_ms = (limit_us - lease_ms * 1000) / 1e3
    return after_us, [
        f"{what} {after_us / 1e3:.1f} ms after the last host frame, limit {lease_ms} + "
        f"{period_ms:g} ms"
    ]
