"""Z homing (protocol 1.3, PROTOCOL.md §6.1): z_home_refusals, z_home_cycle.

z_home_refusals runs on every board: one without HOMING (or older than 1.3) refuses Z_HOME
and moves nothing; one with it refuses a zero seek speed naming the field, and moves
nothing. z_home_cycle homes twice and judges both HOME_RESULTs: HOMED, the HOMED status
bit, Z parked inside the soft limits, nothing latched, and the second homing's shift (how
far it moved the count the first one set: the switch's repeatability). Homing runs Z up to
its home switch, beyond the suite's motion window: the cycle runs only when asked
(``--home``), on a board whose switch is wired. It runs after every check that moves Z
inside the window, which no longer describes where Z is once it has homed.
"""

from __future__ import annotations

import firmware_protocol as fp
from firmware_protocol import Capability, HomeOutcome, NakCode, StatusBit

from .context import SuiteContext, mm
from .report import CheckResult, Value, failed, passed, skipped

__all__ = ["HOMING_MINOR", "REPEATABILITY_LIMIT_UM", "check_z_home"]

HOMING_MINOR = 3  # the protocol minor that brought Z_HOME (1.3)
REPEATABILITY_LIMIT_UM = 50  # a second homing moves the count by at most this
REFUSALS = "z_home_refusals"
CYCLE = "z_home_cycle"
# The cycle's settings: a seek, a slow re-seek, a backoff; travel and time generous.
SEEK_UM_S, LOCATE_UM_S, BACKOFF_UM = 20_000, 2_000, 2_000
MAX_TRAVEL_UM, TIMEOUT_MS = 300_000, 30_000


def _outcome(code: int) -> str:
    try:
        return HomeOutcome(code).name
    except ValueError:
        return f"code {code}"


async def _refusals(ctx: SuiteContext, homing: bool) -> CheckResult:
    before = await ctx.status()
    bad = fp.ZHome(0, 0 if homing else SEEK_UM_S, LOCATE_UM_S, BACKOFF_UM, 1_000, 1_000)
    reply = await ctx.link.request(bad)
    after = await ctx.status()
    values: dict[str, Value] = {"homing": homing}
    moved = after.status & StatusBit.Z_BUSY or after.z_um != before.z_um
    if homing:
        wanted = "NAK OUT_OF_RANGE detail 0 (the zero seek speed)"
        ok = isinstance(reply, fp.Nak) and (reply.code, reply.detail) == (
            NakCode.OUT_OF_RANGE,
            0,
        )
    else:
        wanted = "NAK UNSUPPORTED detail 9 (no HOMING) or UNKNOWN_TYPE (a board before 1.3)"
        ok = isinstance(reply, fp.Nak) and (
            (reply.code, reply.detail) == (NakCode.UNSUPPORTED, 9)
            or reply.code == NakCode.UNKNOWN_TYPE
        )
    values["reply"] = type(reply).__name__ + (
        f" {reply.code}/{reply.detail}" if isinstance(reply, fp.Nak) else ""
    )
    if not ok:
        return failed(REFUSALS, f"Z_HOME answered {values['reply']}, not {wanted}", values=values)
    if moved:
        return failed(REFUSALS, "a refused Z_HOME moved Z", values=values)
    return passed(REFUSALS, f"refused as the protocol says: {wanted}", values=values)


async def _home(ctx: SuiteContext) -> fp.HomeResult | None:
    mark = ctx.link.mark()
    ack = await ctx.expect_ack(
        fp.ZHome(0, SEEK_UM_S, LOCATE_UM_S, BACKOFF_UM, MAX_TRAVEL_UM, TIMEOUT_MS)
    )
    found = await ctx.link.wait_for_type(
        fp.HomeResult, TIMEOUT_MS / 1000 + 3.0, since=mark, where=lambda m: m.seq == ack.seq
    )
    return found[1] if found is not None else None


async def _cycle(ctx: SuiteContext) -> CheckResult:
    info = ctx.require_info()
    window = ctx.require_window()
    await ctx.clear_faults()
    window.suspended = True  # Z goes to its home switch, beyond the window, on purpose
    first = await _home(ctx)
    second = await _home(ctx) if first is not None and first.result == HomeOutcome.HOMED else None
    status = await ctx.status()
    values: dict[str, Value] = {}
    if first is None:
        await ctx.stop_z()
        return failed(CYCLE, "no HOME_RESULT within the cycle's timeout", values=values)
    values.update(first=_outcome(first.result), first_shift_mm=first.shift_um / 1000)
    if first.result != HomeOutcome.HOMED:
        return failed(
            CYCLE,
            f"homing ended {_outcome(first.result)} at {mm(first.z_um)} mm",
            hint="a home switch on Z_LIMIT_MAX within 300 mm above Z, closing when Z reaches it",
            values=values,
        )
    if second is None:
        return failed(CYCLE, "no HOME_RESULT for the second homing", values=values)
    values.update(
        second=_outcome(second.result),
        repeatability_mm=second.shift_um / 1000,
        parked_z_mm=second.z_um / 1000,
    )
    problems = []
    if second.result != HomeOutcome.HOMED:
        problems.append(f"the second homing ended {_outcome(second.result)}")
    if abs(second.shift_um) > REPEATABILITY_LIMIT_UM:
        problems.append(
            f"the second homing moved Z by {mm(second.shift_um)} mm "
            f"(at most {REPEATABILITY_LIMIT_UM / 1000} mm)"
        )
    if not status.status & StatusBit.HOMED:
        problems.append("STATUS does not say HOMED")
    if not info.z_min_um <= status.z_um <= info.z_max_um:
        problems.append(f"parked at {mm(status.z_um)} mm, outside the soft limits")
    if status.faults:
        problems.append(f"faults latched: 0x{status.faults:04x} (the home switch latches none)")
    if problems:
        return failed(CYCLE, "; ".join(problems), values=values)
    return passed(
        CYCLE,
        f"homed twice; the second moved Z by {mm(second.shift_um)} mm; parked at "
        f"{mm(status.z_um)} mm",
        values=values,
    )


async def check_z_home(ctx: SuiteContext) -> list[CheckResult]:
    """Z_HOME's refusals on every board; the homing cycle when asked (``--home``)."""
    info = ctx.require_info()
    homing = info.proto_minor >= HOMING_MINOR and ctx.capable(Capability.HOMING)
    results = [await _refusals(ctx, homing)]
    if not homing:
        results.append(skipped(CYCLE, "skipped: the board does not home (no HOMING)"))
    elif not ctx.options.home:
        results.append(
            skipped(
                CYCLE,
                "not asked: homing runs Z up to its home switch, beyond the motion window",
                hint="--home on a board whose home switch (Z_LIMIT_MAX) is wired",
            )
        )
    else:
        results.append(await _cycle(ctx))
    return results
