"""The conformance suite: open the link, run every check in order, leave the board safe.

Each check runs under a time limit and reports PASS, FAIL or SKIP with its figures; an
exception inside a check fails that check only. When the handshake fails (nothing
answers, every frame fails its CRC, the majors differ) the remaining checks are reported
skipped at once instead of each waiting for its own timeouts; a board that cannot be
prepared (a fault whose cause is still present) adds one failed ``setup`` entry. The
suite ends with the
torch relay and ohmic sensing off, Z stopped and the board's own lease back in force.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import structlog

import firmware_protocol as fp

from ..link import LinkError, RequestTimeout
from ..transport import TransportError, TransportOpener
from .checks_homing import check_z_home
from .checks_lease import check_lease_expiry, check_lease_idle_lapse
from .checks_link import (
    capability_names,
    check_boot_id_reset,
    check_command_replies,
    check_corrupt_frames,
    check_duplicate_seq,
    check_handshake,
    check_protocol_version,
)
from .checks_motion import (
    check_input_events,
    check_probe_contact,
    check_z_velocity_expiry,
)
from .checks_probe_away import check_probe_away_release
from .checks_telemetry import check_telemetry
from .context import Operator, SuiteContext
from .errors import ConformanceError
from .options import CHECK_TIMEOUT_S, SUITE_LEASE_MS, WINDOW_GUARD_MARGIN_MM, ConformanceOptions
from .rawlink import RawBoardLink
from .report import CheckResult, SuiteReport, Value, failed, skipped
from .window import MotionWindow

__all__ = ["CHECK_NAMES", "ResultCallback", "run_suite"]

log = structlog.get_logger("dthc_bridge.conformance")

ResultCallback = Callable[[CheckResult], None]
CheckFunction = Callable[[SuiteContext], Awaitable[list[CheckResult]]]


@dataclass(frozen=True, slots=True)
class _Step:
    names: tuple[str, ...]
    run: CheckFunction
    timeout_s: Callable[[ConformanceOptions], float] = lambda _: CHECK_TIMEOUT_S


def _probe_timeout_s(o: ConformanceOptions) -> float:
    return CHECK_TIMEOUT_S + 2 * o.probe_max_travel_mm / o.probe_feed_mm_s


def _inputs_timeout_s(o: ConformanceOptions) -> float:
    return CHECK_TIMEOUT_S + (len(fp.InputBit) * 2 * o.input_timeout_s if o.interactive else 0)


_STEPS: tuple[_Step, ...] = (
    _Step(("command_replies",), check_command_replies),
    _Step(("duplicate_seq",), check_duplicate_seq),
    _Step(("corrupt_frames",), check_corrupt_frames),
    _Step(
        ("telemetry_rate", "telemetry_jitter", "telemetry_gaps", "status_rtt"),
        check_telemetry,
        lambda o: CHECK_TIMEOUT_S + o.telemetry_s,
    ),
    _Step(("z_velocity_expiry",), check_z_velocity_expiry),
    _Step(("probe_contact",), check_probe_contact, _probe_timeout_s),
    # A touch-off, the probe away, the move back.
    _Step(
        ("probe_away_release",),
        check_probe_away_release,
        lambda o: _probe_timeout_s(o) + o.probe_max_travel_mm / o.probe_feed_mm_s,
    ),
    _Step(("input_events",), check_input_events, _inputs_timeout_s),
    _Step(("lease_expiry",), check_lease_expiry),
    _Step(("lease_idle_lapse",), check_lease_idle_lapse),
    # After every check that moves Z inside the window: once homed, Z is where the window no
    # longer says (checks_homing); the reset check after it moves nothing.
    _Step(("z_home_refusals", "z_home_cycle"), check_z_home, lambda _: CHECK_TIMEOUT_S + 70.0),
    _Step(("boot_id_reset",), check_boot_id_reset, lambda o: CHECK_TIMEOUT_S + 60.0),
)

CHECK_NAMES: tuple[str, ...] = (
    "handshake",
    "protocol_version",
    *(name for step in _STEPS for name in step.names),
)
"""Every check, in the order the suite runs and reports them."""


async def run_suite(
    options: ConformanceOptions,
    *,
    operator: Operator | None = None,
    on_result: ResultCallback | None = None,
    opener: TransportOpener | None = None,
) -> SuiteReport:
    """Run the whole suite against the board at ``options.link`` (reached through
    ``opener`` where one is given); never raises for a board fault, a lost link or a
    missing device: those are failed checks in the report."""
    loop = asyncio.get_running_loop()
    started_s = loop.time()
    report = SuiteReport(options.link)

    def record(result: CheckResult) -> None:
        report.checks.append(result)
        if on_result is not None:
            on_result(result)

    def skip_rest(reason: str, hint: str = "") -> None:
        done = {c.name for c in report.checks}
        for name in CHECK_NAMES:
            if name not in done:
                record(skipped(name, f"not run: {reason}", hint=hint))

    link = RawBoardLink(
        options.link, ack_timeout_s=options.ack_timeout_s, baudrate=options.baudrate,
        opener=opener,
    )  # fmt: skip
    ctx = SuiteContext(link, options, operator)
    try:
        await link.open()
    except (TransportError, ValueError, OSError) as exc:
        record(failed("handshake", f"cannot open {options.link}: {exc}"))
        skip_rest("the link could not be opened")
        report.seconds = loop.time() - started_s
        return report
    try:
        for result in await _run_step(ctx, _Step(("handshake",), check_handshake)):
            record(result)
        if ctx.info is not None:
            report.board = _board_summary(ctx.info)
            for result in await _run_step(
                ctx, _Step(("protocol_version",), check_protocol_version)
            ):
                record(result)
        if ctx.info is None or ctx.info.proto_major != fp.PROTOCOL_MAJOR or not ctx.session_open:
            skip_rest("no usable session with the board (see the failures above)")
            return report
        setup_error = await _setup(ctx)
        if setup_error is not None:
            record(failed("setup", setup_error))
            skip_rest("the board could not be prepared", hint=setup_error)
            return report
        for step in _STEPS:
            if options.only and not set(step.names) & set(options.only):
                for name in step.names:
                    record(skipped(name, "not selected (--only)"))
                continue
            for result in await _run_step(ctx, step):
                record(result)
            if link.lost_reason is not None:
                skip_rest(f"the link was lost ({link.lost_reason})")
                break
    finally:
        await _leave_safe(ctx)
        await link.close()
        report.seconds = loop.time() - started_s
    return report


async def _run_step(ctx: SuiteContext, step: _Step) -> list[CheckResult]:
    loop = asyncio.get_running_loop()
    started_s = loop.time()
    limit_s = step.timeout_s(ctx.options)
    try:
        async with asyncio.timeout(limit_s):
            results = await step.run(ctx)
    except TimeoutError:
        results = [failed(n, f"did not finish within {limit_s:.0f} s") for n in step.names]
    except (LinkError, ConformanceError, TransportError) as exc:
        log.info("conformance_check_error", check=step.names[0], error=str(exc))
        results = [failed(n, str(exc)) for n in step.names]
    seconds = loop.time() - started_s  # checks of one step share its measurement
    return [CheckResult(r.name, r.passed, r.figure, r.values, r.hint, seconds) for r in results]


async def _setup(ctx: SuiteContext) -> str | None:
    """Suite lease and keep-alive, faults cleared, the start move, the motion window.
    Returns why the board could not be prepared, or None."""
    link = ctx.link
    info = ctx.require_info()
    opts = ctx.options
    try:
        await ctx.expect_ack(fp.SetLease(0, SUITE_LEASE_MS))
        link.start_keepalive(SUITE_LEASE_MS)
        await ctx.clear_faults()
        if opts.start_z_mm is not None:
            await ctx.move_z(round(opts.start_z_mm * 1000), inside_window=False)
        status = await ctx.status()
    except (LinkError, ConformanceError) as exc:
        return (
            f"{exc} (a fault whose cause is still present, e.g. a pressed E-stop, must be "
            "released first)"
        )
    window = MotionWindow(
        ref_um=status.z_um,
        half_width_um=round(opts.z_window_mm * 1000),
        z_min_um=info.z_min_um,
        z_max_um=info.z_max_um,
        guard_margin_um=round(WINDOW_GUARD_MARGIN_MM * 1000),
    )
    ctx.window = window

    def stop() -> None:
        log.warning("conformance_z_outside_window", window=window.describe())
        with contextlib.suppress(LinkError):  # a lost link cannot move Z either
            link.send(fp.ZStop(link.next_seq()))

    link.add_samples_listener(window.guard(stop))
    log.info("conformance_window", window=window.describe())
    return None


async def _leave_safe(ctx: SuiteContext) -> None:
    """Torch relay and ohmic sensing off, Z stopped, the board's own lease back."""
    link = ctx.link
    if link.lost_reason is not None or not ctx.session_open or ctx.info is None:
        return
    with contextlib.suppress(LinkError, RequestTimeout, ConformanceError):
        await ctx.expect_ack(fp.Torch(0, False))
        if ctx.info.capabilities & fp.Capability.OHMIC:
            await ctx.expect_ack(fp.OhmicSense(0, False))
        status = await ctx.status()
        if status.status & fp.StatusBit.Z_BUSY:
            await ctx.expect_ack(fp.ZStop(0))
        await ctx.expect_ack(fp.SetLease(0, ctx.info.lease_ms))


def _board_summary(info: fp.HelloInfo) -> dict[str, Value]:
    return {
        "serial": info.serial,
        "boot_id": f"{info.boot_id:08x}",
        "firmware": f"{info.fw_major}.{info.fw_minor}.{info.fw_patch}",
        "protocol": f"{info.proto_major}.{info.proto_minor}",
        "sample_rate_hz": info.sample_rate_hz,
        "batch_size": info.batch_size,
        "lease_ms": info.lease_ms,
        "z_min_mm": info.z_min_um / 1000,
        "z_max_mm": info.z_max_um / 1000,
        "capabilities": capability_names(info.capabilities),
    }
