"""The probe away (protocol 1.2, PROTOCOL.md §6.1): probe_away_release.

A program lifts off its float switch after a touch-off with G38.4 Z0.5 (LinuxCNC: probe
away from the work, stop on the loss of contact). The board does that as Z_PROBE_AWAY: up
until every sensor of the set is released, stopped by the board on the release. The check
touches off with Z_PROBE (the sensors probe_contact uses), then probes away with the same
set and judges the PROBE_RESULT: RELEASED, where, and that the board stopped itself. A
board announcing a minor below 1.2 is skipped, as lease_idle_lapse skips a 1.0 board.
"""

from __future__ import annotations

import firmware_protocol as fp
from firmware_protocol import Capability, InputBit, InputMask, StatusBit

from .context import SuiteContext, mm
from .options import PROBE_DECEL_ALLOWANCE_MM
from .report import CheckResult, Value, failed, passed, skipped

__all__ = ["PROBE_AWAY_MINOR", "check_probe_away_release"]

PROBE_AWAY_MINOR = 2  # the protocol minor that brought Z_PROBE_AWAY (1.2)
PROBE_EXTRA_S = 3.0  # beyond travel / feed, for the deceleration and the report
NAME = "probe_away_release"


def _names(bits: int) -> str:
    return "+".join(b.name for b in InputBit if bits & (1 << b)) or "none"


def _outcome(code: int) -> str:
    try:
        return fp.ProbeOutcome(code).name
    except ValueError:
        return f"code {code}"


async def _probe(
    ctx: SuiteContext, command: fp.ZProbe | fp.ZProbeAway, since: int
) -> fp.ProbeResult | None:
    """Send a probe and wait for its PROBE_RESULT (None if none came in time)."""
    ack = await ctx.expect_ack(command)
    timeout_s = command.max_travel_um / command.feed_um_s + PROBE_EXTRA_S
    found = await ctx.link.wait_for_type(
        fp.ProbeResult, timeout_s, since=since, where=lambda m: m.seq == ack.seq
    )
    return found[1] if found is not None else None


async def check_probe_away_release(ctx: SuiteContext) -> list[CheckResult]:
    """After a touch-off, Z_PROBE_AWAY moves up and the board stops by itself when every
    sensor of the set is released: PROBE_RESULT RELEASED, the release above where the
    touch-off came to rest, Z at rest at or above it, an EVENT for the release."""
    info = ctx.require_info()
    if info.proto_minor < PROBE_AWAY_MINOR:
        return [
            skipped(
                NAME,
                f"the board speaks protocol {info.proto_major}.{info.proto_minor}: the probe "
                f"away (Z_PROBE_AWAY) came with {fp.PROTOCOL_MAJOR}.{PROBE_AWAY_MINOR}; a "
                "1.2 host does not offer G38.4/G38.5 with this board",
            )
        ]
    sensors = (InputMask.OHMIC if ctx.capable(Capability.OHMIC) else 0) | (
        InputMask.FLOAT if ctx.capable(Capability.FLOAT) else 0
    )
    if not sensors:
        return [skipped(NAME, "skipped: the board has no ohmic or float input")]
    link = ctx.link
    opts = ctx.options
    window = ctx.require_window()
    start = await ctx.clear_faults()
    travel_um = round(opts.probe_max_travel_mm * 1000)
    window.check(start.z_um - travel_um)
    feed_um_s = round(opts.probe_feed_mm_s * 1000)
    values: dict[str, Value] = {"start_z_mm": start.z_um / 1000, "feed_mm_s": opts.probe_feed_mm_s}
    if sensors & InputMask.OHMIC:
        await ctx.expect_ack(fp.OhmicSense(0, True))
    touch: fp.ProbeResult | None = None
    away: fp.ProbeResult | None = None
    mark = link.mark()
    excursions = window.excursions
    try:
        touch = await _probe(ctx, fp.ZProbe(0, feed_um_s, travel_um, sensors), mark)
        if touch is not None and touch.result == fp.ProbeOutcome.CONTACT:
            # Up at most as far as the touch-off came down, inside the window with room to
            # brake.
            allowance_um = round(PROBE_DECEL_ALLOWANCE_MM * 1000)
            up_um = min(start.z_um - touch.stop_z_um + allowance_um, travel_um)
            up_um = max(min(up_um, window.high_um - touch.stop_z_um - allowance_um), 1)
            values["max_travel_mm"] = up_um / 1000
            mark = link.mark()
            away = await _probe(ctx, fp.ZProbeAway(0, feed_um_s, up_um, sensors), mark)
    finally:
        if away is None:
            await ctx.stop_z()
        if sensors & InputMask.OHMIC:
            await ctx.expect_ack(fp.OhmicSense(0, False))
        await ctx.move_z(start.z_um)
    if touch is None or touch.result != fp.ProbeOutcome.CONTACT:
        ended = "no PROBE_RESULT" if touch is None else f"it ended {_outcome(touch.result)}"
        return [
            failed(
                NAME,
                f"the touch-off before the probe away found no contact ({ended}): nothing to "
                "lift off from",
                hint="the probe_contact check's setup applies: a plate or the floating head "
                "within reach of the probe",
                values=values,
            )
        ]
    values.update(
        touch_contact_z_mm=touch.contact_z_um / 1000, touch_stop_z_mm=touch.stop_z_um / 1000
    )
    if away is None:
        return [failed(NAME, "no PROBE_RESULT for Z_PROBE_AWAY in time", values=values)]
    values.update(
        outcome=_outcome(away.result),
        sensor=_names(away.sensor),
        release_z_mm=away.contact_z_um / 1000,
        stop_z_mm=away.stop_z_um / 1000,
        overrun_mm=(away.stop_z_um - away.contact_z_um) / 1000,
        lift_mm=(away.contact_z_um - touch.stop_z_um) / 1000,
    )
    problems = []
    if away.result == fp.ProbeOutcome.NO_RELEASE:
        return [
            failed(
                NAME,
                f"no release within {mm(away.stop_z_um - touch.stop_z_um)} mm of travel up: "
                f"{_names(away.sensor)} stayed active",
                hint="a jumper on the input never releases: use a plate or the floating head",
                values=values,
            )
        ]
    if away.result != fp.ProbeOutcome.RELEASED:
        problems.append(f"probe away ended {_outcome(away.result)}, not RELEASED")
    if not away.sensor & sensors or away.sensor & ~sensors:
        problems.append(f"PROBE_RESULT names sensor bits 0x{away.sensor:04x}")
    if away.contact_z_um < touch.stop_z_um:
        problems.append(
            f"released at {mm(away.contact_z_um)} mm, below where the touch-off rested "
            f"({mm(touch.stop_z_um)} mm)"
        )
    if away.stop_z_um < away.contact_z_um:
        problems.append("stop position below the release: a probe away moves up")
    if window.excursions != excursions:
        problems.append("Z ran beyond the window: the host had to stop it")
    falling = [
        e
        for e in link.messages(fp.Event, since=mark)
        if not e.level and (1 << e.input) & away.sensor
    ]
    if not falling:
        problems.append("no EVENT reported the release")
    after = await ctx.status()
    if after.status & StatusBit.Z_BUSY:
        problems.append("Z still busy after the move back")
    if problems:
        return [failed(NAME, "; ".join(problems), values=values)]
    figure = (
        f"released by {values['sensor']} at Z {mm(away.contact_z_um)} mm, "
        f"{mm(away.contact_z_um - touch.stop_z_um)} mm above the touch-off's rest, stopped "
        f"by the board {mm(away.stop_z_um - away.contact_z_um)} mm further up"
    )
    return [passed(NAME, figure, values=values)]
