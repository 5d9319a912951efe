"""Telemetry checks (PROTOCOL.md §3, §6.2, §8): one measurement window, four verdicts.

For ``telemetry_s`` seconds the suite records every SAMPLES batch while it loads the link
with ``rtt_queries`` STATUS queries, one after the other, each timed. From that window:

- telemetry_rate: samples per second by the host clock (and by board timestamps) against
  the advertised rate; the batch size and period against HELLO_INFO.
- telemetry_jitter: board timestamps, each batch's ``t0_us`` step against batch x period.
- telemetry_gaps: ``stream_seq`` gaps and SAMPLE_OVERFLOW under that load.
- status_rtt: p50/p99 of the STATUS round trips, against ``rtt_limit_ms``.
"""

from __future__ import annotations

import asyncio
import itertools
import statistics
from collections.abc import Sequence

import firmware_protocol as fp
from firmware_protocol import StatusBit

from ..link import RequestTimeout, extend_u32
from .context import SuiteContext, percentile
from .report import CheckResult, Value, failed, passed

__all__ = ["RATE_TOLERANCE", "check_telemetry"]

RATE_TOLERANCE = 0.02  # host-clock rate within ±2 % of the advertised one
BOARD_RATE_TOLERANCE = 0.005  # board-timestamp rate within ±0.5 % (period rounding)
MIN_BATCHES = 10
RTT_ATTEMPT_TIMEOUT_S = 0.5


def count_losses(batches: Sequence[fp.Samples]) -> tuple[int, int, bool]:
    """Batches lost within the window: (stream_seq gaps, batches flagged SAMPLE_OVERFLOW
    after the first, whether the first is flagged). The flag marks the batch after a lost
    one; on the window's first batch it tells of a loss before the window (the previous
    check's garbage storm, say), which no gap here can show: reported, not counted."""
    gaps = sum(
        d - 1
        for d in ((b.stream_seq - a.stream_seq) & 0xFFFF for a, b in itertools.pairwise(batches))
        if 0 < d < 0x8000
    )
    overflow = sum(1 for b in batches[1:] if b.status & StatusBit.SAMPLE_OVERFLOW)
    return gaps, overflow, bool(batches and batches[0].status & StatusBit.SAMPLE_OVERFLOW)


async def check_telemetry(ctx: SuiteContext) -> list[CheckResult]:
    info = ctx.require_info()
    link = ctx.link
    opts = ctx.options
    loop = asyncio.get_running_loop()
    mark = link.mark()
    started_s = loop.time()
    rtts_ms: list[float] = []
    unanswered = 0
    query = fp.Query(0, fp.QueryWhat.STATUS)
    for _ in range(opts.rtt_queries):
        t = loop.time()
        try:
            reply = await link.request(query, timeout_s=RTT_ATTEMPT_TIMEOUT_S, attempts=1)
        except RequestTimeout:
            unanswered += 1
            continue
        if isinstance(reply, fp.Status):
            rtts_ms.append((loop.time() - t) * 1e3)
        else:
            unanswered += 1
    loaded_s = loop.time() - started_s
    await asyncio.sleep(max(0.0, opts.telemetry_s - loaded_s))
    received = [r for r in link.since(mark) if isinstance(r.msg, fp.Samples)]
    batches = [r.msg for r in received if isinstance(r.msg, fp.Samples)]
    names = ("telemetry_rate", "telemetry_jitter", "telemetry_gaps", "status_rtt")
    if len(batches) < MIN_BATCHES:
        figure = f"{len(batches)} SAMPLES batches in {loop.time() - started_s:.1f} s"
        return [failed(name, figure, values={"batches": len(batches)}) for name in names[:3]] + [
            _rtt_result(rtts_ms, unanswered, opts.rtt_queries, opts.rtt_limit_ms, loaded_s)
        ]

    # Rate: samples of every batch but the last, over the time from the first to the last;
    # by the host clock as the slope of samples received against arrival time (a stall of
    # either process at one end of the window does not bend a fit of 2 s of arrivals).
    counted = sum(len(b.samples_cv) for b in batches[:-1])
    cumulative = list(itertools.accumulate((len(b.samples_cv) for b in batches), initial=0))
    arrival_s = [r.host_s - received[0].host_s for r in received]
    host_span_s = arrival_s[-1]
    rate_host = (
        statistics.linear_regression(arrival_s, cumulative[1:]).slope if host_span_s else 0.0
    )
    ref = extend_u32(batches[0].t0_us, 0)
    t0s = []
    for b in batches:
        ref = extend_u32(b.t0_us, ref)
        t0s.append(ref)
    board_span_s = (t0s[-1] - t0s[0]) / 1e6
    rate_board = counted / board_span_s if board_span_s > 0 else 0.0
    advertised = info.sample_rate_hz
    periods = sorted({b.period_us for b in batches})
    sizes = sorted({len(b.samples_cv) for b in batches})
    rate_values: dict[str, Value] = {
        "advertised_hz": advertised,
        "host_clock_hz": round(rate_host, 2),
        "board_clock_hz": round(rate_board, 2),
        "period_us": ",".join(map(str, periods)),
        "batch_size": ",".join(map(str, sizes)),
        "batches": len(batches),
    }
    problems = []
    if abs(rate_host / advertised - 1) > RATE_TOLERANCE:
        problems.append(f"{rate_host:.1f} samples/s by the host clock, advertised {advertised}")
    if abs(rate_board / advertised - 1) > BOARD_RATE_TOLERANCE:
        problems.append(f"{rate_board:.1f} samples/s by board timestamps")
    if periods != [round(1e6 / advertised)] and periods != [1_000_000 // advertised]:
        problems.append(f"period_us {rate_values['period_us']}, expected {1e6 / advertised:g}")
    if sizes != [info.batch_size]:
        problems.append(f"batch sizes {rate_values['batch_size']}, advertised {info.batch_size}")
    rate = (
        failed("telemetry_rate", "; ".join(problems), values=rate_values)
        if problems
        else passed(
            "telemetry_rate",
            f"{rate_host:.1f} samples/s by the host clock, {rate_board:.1f} by board "
            f"timestamps (advertised {advertised} Hz, {info.batch_size} per batch)",
            values=rate_values,
        )
    )

    # Jitter: consecutive batches (no gap between them) step by exactly batch x period.
    deviations = [
        (t1 - t0) - len(a.samples_cv) * a.period_us
        for (a, t0), (b, t1) in itertools.pairwise(zip(batches, t0s, strict=True))
        if (b.stream_seq - a.stream_seq) & 0xFFFF == 1
    ]
    period_us = periods[0]
    arrivals_ms = [(y.host_s - x.host_s) * 1e3 for x, y in itertools.pairwise(received)]
    max_dev_us = max((abs(d) for d in deviations), default=0)
    jitter_values: dict[str, Value] = {
        "board_dev_us_max": max_dev_us,
        "board_dev_us_std": round(statistics.pstdev(deviations), 2) if deviations else 0.0,
        "host_arrival_ms_std": round(statistics.pstdev(arrivals_ms), 3),
        "host_arrival_ms_max": round(max(arrivals_ms), 3),
        "limit_us": period_us,
    }
    jitter_figure = (
        f"board t0 steps deviate max {jitter_values['board_dev_us_max']} us, std "
        f"{jitter_values['board_dev_us_std']} us (limit {period_us} us); host arrival "
        f"std {jitter_values['host_arrival_ms_std']} ms, max gap "
        f"{jitter_values['host_arrival_ms_max']} ms"
    )
    jitter = (
        passed("telemetry_jitter", jitter_figure, values=jitter_values)
        if deviations and max_dev_us <= period_us
        else failed("telemetry_jitter", jitter_figure, values=jitter_values)
    )

    # Gaps under the query load.
    gaps, overflow, before_window = count_losses(batches)
    gap_values: dict[str, Value] = {
        "batches": len(batches),
        "gaps": gaps,
        "overflow_batches": overflow,
        "overflow_before_window": int(before_window),
        "queries": opts.rtt_queries,
        "seconds": round(loop.time() - started_s, 2),
    }
    gap_figure = (
        f"{gaps} gaps, {overflow} overflows in {len(batches)} batches over "
        f"{gap_values['seconds']} s with {opts.rtt_queries} STATUS queries"
        + ("; a batch was lost before the window" if before_window else "")
    )
    gap = (
        failed("telemetry_gaps", gap_figure, values=gap_values)
        if gaps or overflow
        else passed("telemetry_gaps", gap_figure, values=gap_values)
    )
    rtt = _rtt_result(rtts_ms, unanswered, opts.rtt_queries, opts.rtt_limit_ms, loaded_s)
    return [rate, jitter, gap, rtt]


def _rtt_result(
    rtts_ms: list[float], unanswered: int, queries: int, limit_ms: float, seconds: float
) -> CheckResult:
    if not rtts_ms:
        return failed("status_rtt", f"none of {queries} STATUS queries answered")
    p50, p99 = percentile(rtts_ms, 50), percentile(rtts_ms, 99)
    values: dict[str, Value] = {
        "p50_ms": round(p50, 3),
        "p99_ms": round(p99, 3),
        "max_ms": round(max(rtts_ms), 3),
        "queries": queries,
        "unanswered": unanswered,
        "limit_ms": limit_ms,
    }
    figure = (
        f"STATUS round trip p50 {values['p50_ms']} ms, p99 {values['p99_ms']} ms, max "
        f"{values['max_ms']} ms over {queries} queries in {seconds:.2f} s (limit p99 "
        f"{limit_ms:g} ms)"
    )
    if unanswered:
        return failed("status_rtt", f"{unanswered} unanswered; " + figure, values=values)
    if p99 > limit_ms:
        return failed("status_rtt", figure, values=values)
    return passed("status_rtt", figure, values=values)
