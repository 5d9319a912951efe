"""Checks of the safety rules that need motion and inputs (PROTOCOL.md §3, §5-§8).

z_velocity_expiry, probe_contact and input_events. Z moves only inside the confirmed
window. The host lease has its own checks (checks_lease.py).
"""

from __future__ import annotations

import asyncio
import itertools
from collections import Counter
from collections.abc import Callable, Iterable

import firmware_protocol as fp
from firmware_protocol import Capability, InputBit, InputMask, StatusBit

from ..link import extend_u32
from .context import InputRecord, SuiteContext, batch_end_us, mm
from .errors import ConformanceError
from .options import (
    ZVEL_EXPIRY_MS,
    ZVEL_GIVE_UP_S,
    ZVEL_RENEW_PERIOD_S,
    ZVEL_RENEWALS,
    ZVEL_STOP_MARGIN_MS,
    ZVEL_VELOCITY_UM_S,
)
from .report import CheckResult, Value, failed, passed, skipped

__all__ = [
    "audit_input_events",
    "check_input_events",
    "check_probe_contact",
    "check_z_velocity_expiry",
]

PROBE_EXTRA_S = 3.0  # beyond travel / feed, for the deceleration and the report
STALE_FRAME_WAIT_S = 0.08
# An input an operator can toggle on a bench, by the capability that says the board has it.
_INPUTS: tuple[tuple[InputBit, Capability | None, str], ...] = (
    (InputBit.ARC_OK, None, "close the arc OK input (a jumper), then open it"),
    (InputBit.OHMIC, Capability.OHMIC, "touch the torch tip to the plate, then lift it"),
    (InputBit.FLOAT, Capability.FLOAT, "push the floating head up to close the switch, release"),
    (InputBit.BREAKAWAY, Capability.BREAKAWAY, "trip the breakaway, then re-seat the torch"),
    (InputBit.THC_UP, Capability.THC_UPDOWN, "activate the THC box's UP output, then release"),
    (InputBit.THC_DOWN, Capability.THC_UPDOWN, "activate the THC box's DOWN output, release"),
    (InputBit.ESTOP, Capability.ESTOP, "press the E-stop, then release it"),
    (InputBit.Z_LIMIT_MIN, Capability.Z_LIMITS, "close the Z min limit switch, then release"),
    (InputBit.Z_LIMIT_MAX, Capability.Z_LIMITS, "close the Z max limit switch, then release"),
)


def _sensor_names(bits: int) -> str:
    return "+".join(b.name for b in InputBit if bits & (1 << b)) or "none"


# --- Z velocity --------------------------------------------------------------------------


async def check_z_velocity_expiry(ctx: SuiteContext) -> list[CheckResult]:
    """A Z_VELOCITY stream moves Z while renewed and stops by itself once it is not."""
    link = ctx.link
    start = await ctx.clear_faults()
    z0 = start.z_um
    # The whole run, give-up time included, must stay well inside the window.
    window = ctx.require_window()
    span_s = ZVEL_RENEWALS * ZVEL_RENEW_PERIOD_S + ZVEL_GIVE_UP_S
    window.check(z0 + round(ZVEL_VELOCITY_UM_S * span_s))
    mark = link.mark()
    sent_s: list[float] = []
    for i in range(ZVEL_RENEWALS):
        if i:
            await asyncio.sleep(ZVEL_RENEW_PERIOD_S)
        ctx.velocity_seq = (ctx.velocity_seq + 1) & 0xFFFF
        sent_s.append(
            link.send(fp.ZVelocity(0, ctx.velocity_seq, ZVEL_VELOCITY_UM_S, ZVEL_EXPIRY_MS))
        )
    last_seq = ctx.velocity_seq
    # A CLOCK_QUERY right behind the last frame stamps when the board received it.
    t_last = await ctx.board_time_us()
    found = await link.wait_for(
        lambda m: (
            isinstance(m, fp.Samples)
            and not m.status & StatusBit.Z_BUSY
            and batch_end_us(m, t_last) > t_last
        ),
        ZVEL_GIVE_UP_S,
        since=mark,
    )
    values: dict[str, Value] = {"expiry_ms": ZVEL_EXPIRY_MS, "velocity_um_s": ZVEL_VELOCITY_UM_S}
    if found is None:
        await ctx.stop_z()
        await ctx.move_z(z0)
        return [
            failed(
                "z_velocity_expiry",
                f"Z still moving {ZVEL_GIVE_UP_S * 1e3:.0f} ms after the last Z_VELOCITY "
                f"(expiry {ZVEL_EXPIRY_MS} ms); stopped by the host",
                hint="a board must stop Z by itself expiry_ms after the last Z_VELOCITY",
                values=values,
            )
        ]
    stop = found.msg
    assert isinstance(stop, fp.Samples)
    stop_after_ms = (batch_end_us(stop, t_last) - t_last) / 1e3
    moved_um = stop.z_um - z0
    batches = [b for b in link.messages(fp.Samples, since=mark) if b is not stop]
    moving = [b for b in batches if b.status & StatusBit.Z_BUSY]
    first_moving = next((b for b in batches if b.status & StatusBit.Z_BUSY), None)
    # While renewed (every ZVEL_RENEW_PERIOD_S < expiry), Z must not have stopped.
    pauses = 0
    if first_moving is not None:
        ref = extend_u32(first_moving.t0_us, t_last)
        pauses = sum(
            1
            for b in batches
            if not b.status & StatusBit.Z_BUSY and ref < batch_end_us(b, t_last) < t_last
        )
    host_gap_ms = max(b - a for a, b in itertools.pairwise(sent_s)) * 1e3
    # A frame that is not newer than the last applied one must be ignored.
    link.send(fp.ZVelocity(0, (last_seq - 1) & 0xFFFF, ZVEL_VELOCITY_UM_S, ZVEL_EXPIRY_MS))
    await asyncio.sleep(STALE_FRAME_WAIT_S)
    after_stale = await ctx.status()
    stale_moved_um = after_stale.z_um - stop.z_um
    values.update(
        stop_after_ms=round(stop_after_ms, 2),
        moved_um=moved_um,
        limit_ms=ZVEL_EXPIRY_MS + ZVEL_STOP_MARGIN_MS,
        zvel_seq_echoed=stop.zvel_seq,
        stale_moved_um=stale_moved_um,
    )
    await ctx.move_z(z0)
    problems = []
    if not moving or moved_um <= 0:
        problems.append(f"Z did not move up (moved {mm(moved_um)} mm): velocity not applied")
    if stop.zvel_seq != last_seq:
        problems.append(f"SAMPLES echo zvel_seq {stop.zvel_seq}, last applied was {last_seq}")
    if stop_after_ms > ZVEL_EXPIRY_MS + ZVEL_STOP_MARGIN_MS:
        problems.append(
            f"stopped {stop_after_ms:.1f} ms after the last frame, "
            f"limit {ZVEL_EXPIRY_MS} + {ZVEL_STOP_MARGIN_MS} ms"
        )
    if pauses and host_gap_ms < ZVEL_EXPIRY_MS * 0.75:
        problems.append(f"Z stopped between renewals ({pauses} idle batches)")
    if abs(stale_moved_um) > 20 or after_stale.status & StatusBit.Z_BUSY:
        problems.append("a stale Z_VELOCITY (older stream_seq) was applied")
    if after_stale.zvel_seq != last_seq:
        problems.append(f"STATUS zvel_seq {after_stale.zvel_seq} after a stale frame")
    if problems:
        return [failed("z_velocity_expiry", "; ".join(problems), values=values)]
    figure = (
        f"moved +{mm(moved_um)} mm while renewed, stopped {stop_after_ms:.1f} ms after the "
        f"last frame (expiry {ZVEL_EXPIRY_MS} ms, limit {ZVEL_EXPIRY_MS + ZVEL_STOP_MARGIN_MS} "
        "ms); stale frame ignored"
    )
    return [passed("z_velocity_expiry", figure, values=values)]


# --- probe and input events --------------------------------------------------------------


async def check_probe_contact(ctx: SuiteContext) -> list[CheckResult]:
    """Z_PROBE stops on a contact input by itself and reports where."""
    link = ctx.link
    opts = ctx.options
    sensors = (InputMask.OHMIC if ctx.capable(Capability.OHMIC) else 0) | (
        InputMask.FLOAT if ctx.capable(Capability.FLOAT) else 0
    )
    if not sensors:
        return [skipped("probe_contact", "skipped: the board has no ohmic or float input")]
    window = ctx.require_window()
    start = await ctx.clear_faults()
    travel_um = round(opts.probe_max_travel_mm * 1000)
    window.check(start.z_um - travel_um)
    feed_um_s = round(opts.probe_feed_mm_s * 1000)
    if sensors & InputMask.OHMIC:
        await ctx.expect_ack(fp.OhmicSense(0, True))
    before = await ctx.status()
    mark = link.mark()
    excursions = window.excursions
    ack = await ctx.expect_ack(fp.ZProbe(0, feed_um_s, travel_um, sensors))
    timeout_s = travel_um / feed_um_s + PROBE_EXTRA_S
    found = await link.wait_for_type(
        fp.ProbeResult, timeout_s, since=mark, where=lambda m: m.seq == ack.seq
    )
    if found is None:
        await ctx.stop_z()
    if sensors & InputMask.OHMIC:
        await ctx.expect_ack(fp.OhmicSense(0, False))
    await ctx.move_z(start.z_um)
    after = await ctx.status()
    ctx.inputs = InputRecord(before, after, mark, link.mark(), "provoked by the probe")
    values: dict[str, Value] = {
        "start_z_mm": start.z_um / 1000,
        "max_travel_mm": travel_um / 1000,
        "feed_mm_s": opts.probe_feed_mm_s,
    }
    if found is None:
        return [failed("probe_contact", f"no PROBE_RESULT within {timeout_s:.1f} s", values=values)]
    result = found[1]
    try:
        outcome = fp.ProbeOutcome(result.result).name
    except ValueError:
        outcome = f"code {result.result}"
    values.update(
        outcome=outcome,
        sensor=_sensor_names(result.sensor),
        contact_z_mm=result.contact_z_um / 1000,
        stop_z_mm=result.stop_z_um / 1000,
        overrun_mm=(result.contact_z_um - result.stop_z_um) / 1000,
    )
    if result.result == fp.ProbeOutcome.NO_CONTACT:
        return [
            failed(
                "probe_contact",
                f"no contact within {mm(travel_um)} mm of travel (stopped at "
                f"{mm(result.stop_z_um)} mm); the stop on contact could not be verified",
                hint="put a jumper or a plate on the ohmic/float input within reach, or start "
                "closer to it (--start-z-mm) or allow more travel (--probe-travel-mm, "
                "--z-window-mm)",
                values=values,
            )
        ]
    problems = []
    if result.result != fp.ProbeOutcome.CONTACT:
        problems.append(f"probe ended {outcome}")
    if not result.sensor & sensors:
        problems.append(f"PROBE_RESULT names sensor bits 0x{result.sensor:04x}")
    if result.stop_z_um > result.contact_z_um:
        problems.append("stop position above the contact position")
    if not start.z_um - travel_um - 1000 <= result.contact_z_um <= start.z_um:
        problems.append(f"contact at {mm(result.contact_z_um)} mm, outside the probed range")
    if window.excursions != excursions:
        problems.append("Z ran beyond the window: the host had to stop it")
    rising = [
        e for e in link.messages(fp.Event, since=mark) if e.level and (1 << e.input) & result.sensor
    ]
    if not rising:
        problems.append("no EVENT reported the contact input")
    if problems:
        return [failed("probe_contact", "; ".join(problems), values=values)]
    figure = (
        f"contact by {values['sensor']} at Z {mm(result.contact_z_um)} mm after "
        f"{mm(start.z_um - result.contact_z_um)} mm, stopped by the board "
        f"{mm(result.contact_z_um - result.stop_z_um)} mm further down"
    )
    return [passed("probe_contact", figure, values=values)]


def audit_input_events(
    record: InputRecord, messages: Iterable[fp.Message]
) -> tuple[list[str], dict[str, Value]]:
    """What in the EVENT/FAULT reports between two STATUS snapshots breaks §3/§6.2: a
    counter not incremented by one per event, a snapshot bit that disagrees with the
    level, an edge that is no change, a final level that disagrees with STATUS."""
    c0, c1 = record.before.event_counter, record.after.event_counter
    span = (c1 - c0) & 0xFFFFFFFF
    events: list[fp.Event] = []
    seen: set[int] = set()
    repeated = 0  # only a FAULT re-report may repeat a counter
    for msg in messages:
        if isinstance(msg, fp.Event | fp.Fault) and 0 < (msg.counter - c0) & 0xFFFFFFFF <= span:
            if msg.counter in seen:
                repeated += isinstance(msg, fp.Event)
                continue
            seen.add(msg.counter)
            if isinstance(msg, fp.Event):
                events.append(msg)
    problems = []
    missing = span - len(seen)
    if missing:
        problems.append(f"{missing} of {span} events not reported (counter gaps)")
    if repeated:
        problems.append(f"{repeated} events repeat an earlier counter")
    level = {bit: (record.before.inputs >> bit) & 1 for bit in range(16)}
    bad_snapshots = bad_edges = 0
    for e in events:
        if (e.inputs >> e.input) & 1 != e.level:
            bad_snapshots += 1
        if level.get(e.input) == e.level:
            bad_edges += 1
        level[e.input] = e.level
    if bad_snapshots:
        problems.append(f"{bad_snapshots} events whose snapshot bit differs from their level")
    if bad_edges:
        problems.append(f"{bad_edges} events that repeat the input's previous level")
    changed = {e.input for e in events}
    final = [b for b in changed if (record.after.inputs >> b) & 1 != level[b]]
    if final:
        problems.append(f"STATUS inputs disagree with the last event for bits {sorted(final)}")
    counts = Counter(_input_name(e.input) for e in events)
    values: dict[str, Value] = {
        "events": len(events),
        "counter_first": (c0 + 1) & 0xFFFFFFFF,
        "counter_last": c1,
        "by_input": ", ".join(f"{name} x{n}" for name, n in sorted(counts.items())),
    }
    return problems, values


def _input_name(bit: int) -> str:
    try:
        return InputBit(bit).name
    except ValueError:
        return f"bit {bit}"


async def check_input_events(ctx: SuiteContext) -> list[CheckResult]:
    """Each input edge is reported once, with the next counter and a matching snapshot."""
    record: InputRecord | None
    missing: list[str] = []
    if ctx.options.interactive and ctx.operator is not None:
        record, missing = await _toggle_inputs(ctx)
    else:
        record = ctx.inputs
    if record is None:
        return [
            skipped(
                "input_events",
                "skipped: no input was toggled (the probe did not run)",
                hint="run with --interactive to toggle each input by hand",
            )
        ]
    problems, values = audit_input_events(
        record, (r.msg for r in ctx.link.history[record.since : record.until])
    )
    if missing:
        problems.append("not toggled within the time: " + ", ".join(missing))
    elif not values["events"]:
        return [
            skipped(
                "input_events",
                f"skipped: no input edges seen ({record.how})",
                hint="run with --interactive to toggle each input by hand",
                values=values,
            )
        ]
    if problems:
        return [failed("input_events", "; ".join(problems), values=values)]
    figure = (
        f"{values['events']} edges ({values['by_input']}) {record.how}: counters "
        f"{values['counter_first']}..{values['counter_last']} contiguous, snapshots match"
    )
    return [passed("input_events", figure, values=values)]


def _edge_of(bit: int, level: int) -> Callable[[fp.Message], bool]:
    return lambda m: isinstance(m, fp.Event) and m.input == bit and m.level == level


async def _toggle_inputs(ctx: SuiteContext) -> tuple[InputRecord, list[str]]:
    """Interactive: ask the operator to toggle each input the board has; wait for both
    edges of each."""
    link = ctx.link
    operator = ctx.operator
    assert operator is not None
    timeout_s = ctx.options.input_timeout_s
    await ctx.clear_faults()
    before = await ctx.status()
    mark = link.mark()
    missing: list[str] = []
    for bit, capability, how in _INPUTS:
        if capability is not None and not ctx.capable(capability):
            continue
        if bit == InputBit.OHMIC:
            await ctx.expect_ack(fp.OhmicSense(0, True))
        operator.tell(f"Input {bit.name}: {how} (within {timeout_s:.0f} s).")
        since = link.mark()
        for level in (1, 0):
            found = await link.wait_for(_edge_of(bit, level), timeout_s, since=since)
            if found is None:
                missing.append(bit.name)
                break
        if bit == InputBit.OHMIC:
            await ctx.expect_ack(fp.OhmicSense(0, False))
        status = await ctx.status()
        if status.faults:  # breakaway, E-stop, limits latch faults: clear them once released
            try:
                await ctx.clear_faults()
            except ConformanceError:
                operator.tell(f"Release {bit.name}: a fault stays latched while it is active.")
    after = await ctx.status()
    return InputRecord(before, after, mark, link.mark(), "toggled by the operator"), missing
