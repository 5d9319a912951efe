"""``bench latency``: the daemon's hot path, in this process and end to end over a pty.

Both parts build the daemon's real receive path, through the daemon's own builders
(``daemon.board_link``, ``board_setup``, ``controller_service``): transport callback ->
BoardSession (StreamDecoder) -> BoardClient (the batch in SI units) ->
ControllerService._on_batch -> CutSequence.on_samples -> ThcController -> ZVelocity ->
BoardSession.send_velocity -> transport write. The bench watches it through the session's
trace hooks (:class:`LatencyTrace`), not by wiring listeners of its own around the
service's. A cut is started the way a sender does it (``T112 M6``, ``G200 ...``,
``M667 F3000``, the cut's ``G1 ... F5500`` for the requested feed, ``M3`` through
``ControllerService.execute_gcode``); measuring starts once the THC has its target and no
lock (XY at 100 % of the requested feed).

**End to end over a pty** (runs first): the mock board as its own process
(``python -m mock_device --pty ... --latency-log PATH``) running a long rectangle at the
requested feed, the board configured to 1 kHz, batch 1 (``--e2e-batch``).

The figure asked for, board time from a SAMPLES batch to the board's receipt of the
answering Z_VELOCITY, is *measured* (``e2e``). The batch's time is its last sample's,
``t0_us + (N - 1) * period_us`` (PROTOCOL.md: the frame's ``t0_us`` is its first sample;
the batch is complete at its last). The receipt is taken from the mock's latency log: the
instant its event loop read the Z_VELOCITY bytes, on its real clock mapped to board time
the way its run loop decides which ticks are due (``fw_t0_us + (loop.time() - t0) * 1e6``),
not the firmware's burst-ticked ``t_us``. The host's records (which batch each Z_VELOCITY
answered, its stream seq) are matched to those receipts by seq and nearest board time
(``match_board_e2e``). ``board_e2e_us`` = receipt - last sample. It includes the mock's
own send lag, ``mock_send_lag_us`` = the link write of the batch - its last sample: a
real MCU sends a batch when it is complete; the mock runs a tick once its sample time has
come and sends at that wake, later by its wake-up delay (``early`` counts batches written
before their board time: 0 since the mock stopped running ticks that had only begun).
``board_e2e_net_of_mock_lag_us`` = receipt - the batch's
write is what a board that sends at once would see; the e2e goal (p99 <= 1 ms) is judged
on it. On Linux the host's ``perf_counter`` and the mock's loop clock are both
CLOCK_MONOTONIC, so ``net_legs_us`` splits it: mock write -> host read, host read ->
Z_VELOCITY written, host write -> mock read. The receipt is when the mock's loop read the
bytes, later than their arrival when the loop was busy ticking a burst: that mock receive
delay is in the figure (an MCU's UART interrupt would not add it), which errs high.

Cross-checks kept from before: per batch the host records when its bytes arrived and
when the answering Z_VELOCITY write returned (``host_us``); a Heartbeat every 20 ms
measures the round trip through the same pty and mock event loop, timed at the transport
(``rtt_us``: the request's write returned -> the read that holds its ACK);
``e2e_estimate_us`` = ``host + rtt`` percentile by percentile, the old estimate. SAMPLES
carry ``zvel_seq``, so the first batch that shows an answer bounds when the board had it
(``board_bound_us``, resolution one mock wake: an upper bound). CPU share (``getrusage``
deltas) and RSS (``/proc/self/status``) are this process's: the daemon part (link,
session, controller; no MQTT); the mock runs in its own process (``mock_cpu_percent``).

**In-process processing** (runs second): a SimulatedBoard in this process brings the
session up and the cut to THC-active in real time; then the board stops and pre-encoded
SAMPLES frames (the cut's voltage: target + 2 V slow drift + 0.4 V noise, XY at the
requested feed) are fed to the transport callback at their real pace (1 kHz sample rate),
batch 1 and batch 5, ``--duration`` seconds each. Per batch: bytes in -> Z_VELOCITY bytes
handed to the (recording) transport, ``perf_counter_ns``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import random
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import firmware_protocol as fp
from dthc_bridge.board import BoardClient
from dthc_bridge.config import BoardSettings, ControllerSettings
from dthc_bridge.consumables import ConsumableLog
from dthc_bridge.controller.sequence import CutSequence, State
from dthc_bridge.daemon import board_link, board_setup, controller_service
from dthc_bridge.link import BoardSession, LinkError, LinkSupervisor, extend_u32
from dthc_bridge.mqtt.settings import MqttSettings
from dthc_bridge.service import ControllerService
from dthc_bridge.transport import Transport, TransportOpener, open_transport
from dthc_bridge.transport.base import BytesCallback, LostCallback
from dthc_tools.sim.link import SimulatedLink
from mock_device.latency_log import read_latency_log
from mock_device.plant import load_scenario
from mock_device.sim import SimulatedBoard

from ..procs import die_with_parent
from .report import Goal, goals_block, percentiles, proc_cpu_s

__all__ = [
    "BoardE2e",
    "LatencyTrace",
    "add_arguments",
    "log_records",
    "match_board_e2e",
    "run",
    "run_async",
]

SCENARIO = "flat_clean"
FEED_MM_MIN = 5500.0
PROCESSING_P99_GOAL_US = 200.0
E2E_P99_GOAL_US = 1000.0
CPU_GOAL_PERCENT = 15.0
RTT_PROBE_PERIOD_S = 0.02
MATCH_WINDOW_US = 1_000_000  # a Z_VELOCITY stream seq repeats after >= 65 s at 1 kHz


class LatencyTrace:
    """The session's trace hooks (``SessionTrace``): which batch each Z_VELOCITY answers,
    and when it left. A Z_VELOCITY written while a batch is being handled answers that
    batch."""

    def __init__(self) -> None:
        self.chunk_ns = 0  # set by the byte source just before the session decodes
        self.recording = False
        self._batch: fp.Samples | None = None
        self._t_last_us = 0
        # (stream_seq, t_last_us 64-bit, zvel_seq, samples) per batch while recording
        self.batches: list[tuple[int, int, int, int]] = []
        # (chunk_ns, out_ns, velocity_seq, batch index) per answer while recording
        self.answers: list[tuple[int, int, int, int]] = []
        self.last_batch: fp.Samples | None = None  # as it came off the wire
        self.configured_batch: tuple[int, int] | None = None  # (samples, period_us) to wait for
        self.configured = asyncio.Event()  # a batch of that shape arrived
        self.waiting = True  # for that batch

    def samples_received(self, batch: fp.Samples, t_us: int) -> None:
        self._batch = batch
        self.last_batch = batch
        if self.waiting and (len(batch.samples_cv), batch.period_us) == self.configured_batch:
            self.waiting = False
            self.configured.set()
        if self.recording:
            self._t_last_us = extend_u32(batch.t_last_us, self._t_last_us)
            self.batches.append(
                (batch.stream_seq, self._t_last_us, batch.zvel_seq, len(batch.samples_cv))
            )

    def samples_handled(self, batch: fp.Samples) -> None:
        self._batch = None

    def velocity_sent(self, velocity_seq: int) -> None:
        if self.recording and self._batch is not None:
            out = time.perf_counter_ns()
            self.answers.append((self.chunk_ns, out, velocity_seq, len(self.batches) - 1))


@dataclass
class Rig:
    supervisor: LinkSupervisor
    client: BoardClient
    service: ControllerService
    trace: LatencyTrace
    tasks: list[asyncio.Task[None]] = field(default_factory=list)

    @property
    def sequence(self) -> CutSequence:
        return self.service.sequence

    def thc_active(self) -> bool:
        sequence = self.sequence
        return (
            sequence.state is State.CUTTING
            and sequence.thc.target_v is not None
            and not sequence.thc.locks(self.service.now)
        )

    async def close(self) -> None:
        for task in self.tasks:
            task.cancel()
        for task in self.tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        session = self.supervisor.session
        if session is not None:
            await session.close()


SessionOf = Callable[[], BoardSession | None]


def build_rig(
    url: str,
    opener_factory: Callable[[LatencyTrace, SessionOf], TransportOpener],
    batch_size: int,
) -> Rig:
    """The daemon's link and controller service, built by the daemon's own builders from
    its default ``[board]`` (1 kHz, ``batch_size``) and ``[controller]`` settings; the bench
    gives the transport opener and the session's trace hooks. Nothing is written to an
    owner's consumables file."""
    trace = LatencyTrace()
    trace.configured_batch = (batch_size, 1000)
    board = BoardSettings(link=url, sample_rate_hz=1000, batch_size=batch_size)
    holder: list[LinkSupervisor] = []

    def session() -> BoardSession | None:
        return holder[0].session if holder else None

    supervisor, client = board_link(
        board, opener=opener_factory(trace, session), session_trace=trace
    )
    holder.append(supervisor)
    service = controller_service(
        ControllerSettings(), supervisor, client, board_setup=board_setup(board),
        consumables=ConsumableLog(None),
        command_timeout_s=MqttSettings().request_deadline_s + 5.0,
    )  # fmt: skip
    rig = Rig(supervisor, client, service, trace)
    rig.tasks.append(asyncio.create_task(supervisor.run(), name="link"))
    rig.tasks.append(asyncio.create_task(service.run(), name="controller"))
    return rig


async def start_cut(rig: Rig, scenario: str, timeout_s: float = 30.0) -> None:
    """Online, configured, a cut started by G-code, THC with target and no lock."""
    await rig.supervisor.wait_online(timeout_s)
    await asyncio.wait_for(rig.trace.configured.wait(), timeout_s)  # the board set up
    m = load_scenario(scenario).material
    lines = (
        "T112 M6",
        f"G200 F300 P{m.pierce_height_mm:g} D300 C{m.cut_height_mm:g} V{m.cut_voltage_v:g} A90 O1",
        "M667 F3000",
        f"G1 X1150 F{FEED_MM_MIN:g}",  # the cut's motion: the requested feed
        "M3",
    )
    for line in lines:
        result = await rig.service.execute_gcode(line)
        if not result.ok:
            raise RuntimeError(f"{line}: {result.error}")
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while not rig.thc_active():
        if loop.time() > end:
            raise RuntimeError(f"THC not active within {timeout_s} s: {rig.sequence.snapshot()}")
        await asyncio.sleep(0.01)


# --- end to end over a pty -----------------------------------------------------------------


def rectangle_program(duration_s: float) -> list[str]:
    """Laps of a 1050 mm square at the cut feed: XY keeps moving for ``duration_s``."""
    lap_s = 4 * 1050 / (FEED_MM_MIN / 60.0)
    laps = math.ceil((duration_s + 60.0) / lap_s)
    lines = ["G21 G90", "G0 X100 Y100"]
    for _ in range(laps):
        lines += [
            f"G1 X1150 Y100 F{FEED_MM_MIN:g}",
            "G1 X1150 Y1150",
            "G1 X100 Y1150",
            "G1 X100 Y100",
        ]
    return lines


def _status_kb(key: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text(encoding="ascii").splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return None


def board_bound(
    batches: Sequence[tuple[int, int, int, int]], answers: Sequence[tuple[int, int, int, int]]
) -> tuple[list[float], Counter[str]]:
    """Per answer: board time from the answered batch's last sample to the first batch that
    shows the answer applied (an upper bound); and after how many batches that was."""
    bounds: list[float] = []
    after: Counter[str] = Counter()
    for _, _, vseq, index in answers:
        if index < 0:
            continue
        t_answered = batches[index][1]
        k = index + 1
        while k < len(batches) and (batches[k][2] - vseq) & 0xFFFF >= 0x8000:
            k += 1
        if k >= len(batches):
            break  # the run ended first
        bounds.append(batches[k][1] - t_answered)
        gap = k - index
        after[str(gap) if gap < 4 else "4+"] += 1
    return bounds, after


@dataclass
class BoardE2e:
    """Per matched answer, in board time (µs): the answered batch's last sample -> the
    mock's receipt of the answer (``e2e_us``); that batch's last sample -> the mock's
    write of it (``send_lag_us``); the write -> the receipt (``net_us``). The legs of
    ``net_us`` on the machine's monotonic clock: the mock's write -> the host's read
    (``to_host_us``), the host's read -> its Z_VELOCITY write returned (``host_us``), that
    write -> the mock's read (``to_board_us``)."""

    e2e_us: list[float] = field(default_factory=list)
    send_lag_us: list[float] = field(default_factory=list)
    net_us: list[float] = field(default_factory=list)
    to_host_us: list[float] = field(default_factory=list)
    host_us: list[float] = field(default_factory=list)
    to_board_us: list[float] = field(default_factory=list)
    answers: int = 0
    no_receipt: int = 0  # answers the mock's log has no receipt of (within the window)
    no_send: int = 0  # matched answers whose batch the mock's log has no send record of


# (stream_seq, rx_board_us, rx_mono_ns) and (stream_seq, t_last_us & 0xFFFFFFFF,
# tx_board_us, tx_mono_ns): what the bench takes from the mock's latency log.
Receipt = tuple[int, int, int]
Send = tuple[int, int, int, int]


def log_records(records: Sequence[dict[str, object]]) -> tuple[list[Receipt], list[Send]]:
    """The mock latency log's Z_VELOCITY receipts and SAMPLES sends, up to the first
    reboot (board time restarts there)."""
    rx: list[Receipt] = []
    tx: list[Send] = []

    def num(rec: dict[str, object], key: str) -> float:
        value = rec[key]
        assert isinstance(value, int | float)
        return value

    for rec in records:
        kind = rec.get("kind")
        if kind == "reboot":
            break
        if kind == "zvel_rx":
            seq, t_rx = int(num(rec, "stream_seq")), int(num(rec, "rx_board_us"))
            rx.append((seq, t_rx, round(num(rec, "rx_mono_s") * 1e9)))
        elif kind == "samples_tx":
            seq, t_last = int(num(rec, "stream_seq")), int(num(rec, "t_last_us")) & 0xFFFFFFFF
            t_tx = int(num(rec, "tx_board_us"))
            tx.append((seq, t_last, t_tx, round(num(rec, "tx_mono_s") * 1e9)))
    return rx, tx


def match_board_e2e(
    batches: Sequence[tuple[int, int, int, int]],
    answers: Sequence[tuple[int, int, int, int]],
    rx: Sequence[Receipt],
    tx: Sequence[Send],
    window_us: int = MATCH_WINDOW_US,
) -> BoardE2e:
    """Match the host's answers to the mock's receipts and sends.

    ``batches``/``answers`` as LatencyTrace records them (``(stream_seq, t_last_us,
    zvel_seq, samples)``; ``(chunk_ns, out_ns, velocity_seq, batch index)``); ``rx``/``tx``
    as ``log_records`` gives them. An answer's receipt is the one carrying its Z_VELOCITY
    stream seq whose board time is nearest the answered batch's last sample, within
    ``window_us`` (seqs are 16 bits and repeat; the log starts before recording does; a
    lost frame has no receipt). Its batch's send is the one with the same SAMPLES stream
    seq and last-sample time. The legs need the host's ``perf_counter_ns`` and the mock's
    ``loop.time()`` to be one clock (both CLOCK_MONOTONIC on Linux).
    """
    by_seq: dict[int, list[tuple[int, int]]] = {}
    for seq, t_rx, mono_rx in rx:
        by_seq.setdefault(seq & 0xFFFF, []).append((t_rx, mono_rx))
    sends: dict[tuple[int, int], tuple[int, int]] = {}
    for seq, t_sent_last, t_sent, mono_sent in tx:
        sends.setdefault((seq & 0xFFFF, t_sent_last & 0xFFFFFFFF), (t_sent, mono_sent))
    out = BoardE2e()
    for chunk_ns, out_ns, vseq, index in answers:
        if index < 0 or index >= len(batches):
            continue
        out.answers += 1
        stream_seq, t_last, _, _ = batches[index]
        candidates = [c for c in by_seq.get(vseq & 0xFFFF, ()) if abs(c[0] - t_last) <= window_us]
        if not candidates:
            out.no_receipt += 1
            continue
        t_rx, mono_rx = min(candidates, key=lambda c: abs(c[0] - t_last))
        out.e2e_us.append(float(t_rx - t_last))
        sent = sends.get((stream_seq & 0xFFFF, t_last & 0xFFFFFFFF))
        if sent is None:
            out.no_send += 1
            continue
        t_tx, mono_tx = sent
        out.send_lag_us.append(float(t_tx - t_last))
        out.net_us.append(float(t_rx - t_tx))
        out.to_host_us.append((chunk_ns - mono_tx) / 1000)
        out.host_us.append((out_ns - chunk_ns) / 1000)
        out.to_board_us.append((mono_rx - out_ns) / 1000)
    return out


def _dist(values: Sequence[float], digits: int = 0) -> dict[str, object]:
    p = percentiles(values, digits=digits)
    low = round(min(values), digits) if values else None
    return {"p50": p["p50"], "p99": p["p99"], "max": p["max"], "min": low, "count": p["n"]}


def _same_clock() -> bool:
    """The host's perf_counter and the mock's loop.time() (time.monotonic) are one clock."""
    a, b = time.get_clock_info("perf_counter"), time.get_clock_info("monotonic")
    return a.implementation == b.implementation and sys.platform == "linux"


def board_e2e_block(m: BoardE2e, log_ok: bool) -> dict[str, object]:
    block: dict[str, object] = {
        "measured": (
            "board time of the answered SAMPLES batch's last sample (t0_us + (N-1) * period_us;"
            " the frame's t0_us is its first sample) -> the mock's receipt of the answering"
            " Z_VELOCITY: when its event loop read the bytes, its real clock mapped to board"
            " time as its run loop maps due ticks (mock --latency-log)"
        ),
        "log": log_ok,
        "board_e2e_us": _dist(m.e2e_us),
        "mock_send_lag_us": {
            **_dist(m.send_lag_us),
            "early": sum(lag < 0 for lag in m.send_lag_us),
            "note": (
                "the mock writes a batch at the wake that runs its last tick, late by its"
                " wake-up delay, which a board sending at once does not have; early counts"
                " batches written before their board time (expected 0)"
            ),
        },
        "board_e2e_net_of_mock_lag_us": _dist(m.net_us),
        "answers": m.answers,
        "answers_without_receipt": m.no_receipt,
        "answers_without_send_record": m.no_send,
        "cross_checks": ["e2e_estimate_us", "board_bound_us"],
    }
    if _same_clock():
        block["net_legs_us"] = {
            "mock_write_to_host_read": _dist(m.to_host_us, 1),
            "host_read_to_zvel_written": _dist(m.host_us, 1),
            "host_write_to_mock_read": _dist(m.to_board_us, 1),
        }
    return block


async def measure_pty(duration_s: float, batch_size: int, scenario: str) -> dict[str, object]:
    with tempfile.TemporaryDirectory(prefix="dthc-bench-") as tmp:
        pty = Path(tmp) / "board"
        program = Path(tmp) / "program.ngc"
        log = Path(tmp) / "latency.jsonl"
        program.write_text("\n".join(rectangle_program(duration_s)) + "\n", encoding="ascii")
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "mock_device", "--pty", str(pty), "--scenario", scenario,
            "--seed", "1", "--program", str(program), "--latency-log", str(log),
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, preexec_fn=die_with_parent(),
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            ready = await asyncio.wait_for(proc.stdout.readline(), 20.0)
            if not ready.startswith(b"READY"):
                raise RuntimeError(f"mock did not start: {ready!r}")
            result, trace = await _measure_pty_link(
                str(pty), proc.pid, duration_s, batch_size, scenario
            )
        finally:
            if proc.returncode is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    await asyncio.wait_for(proc.wait(), 5.0)
                except TimeoutError:
                    proc.kill()
                    await proc.wait()
        # The mock writes its log when it exits.
        rx, tx = log_records(read_latency_log(log)) if log.exists() else ([], [])
    matched = match_board_e2e(trace.batches, trace.answers, rx, tx)
    return {"e2e": board_e2e_block(matched, log_ok=bool(rx)), **result}


class RttProbe:
    """Round trips of Heartbeat requests, timed at the transport: write returned -> the
    read that holds the ACK frame (whose bytes are known once the request's seq is)."""

    def __init__(self) -> None:
        self.armed = False
        self.sent_ns = 0
        self.expect: bytes | None = None
        self.rtts_us: list[float] = []
        self.lost = 0

    def on_write(self, data: bytes, boot_id: int | None) -> None:
        if not self.armed:
            return
        self.sent_ns = time.perf_counter_ns()
        self.armed = False
        msgs = fp.StreamDecoder().feed(data)
        if msgs and boot_id is not None:
            self.expect = fp.encode(fp.Ack(msgs[0].seq, boot_id))

    def on_read(self, data: bytes, t_ns: int) -> None:
        if self.expect is not None and self.expect in data:
            self.rtts_us.append((t_ns - self.sent_ns) / 1000)
            self.expect = None


class TimedTransport(Transport):
    """Passes everything through; lets the RTT probe see its request leave."""

    def __init__(self, inner: Transport, probe: RttProbe, boot_id: Callable[[], int | None]):
        self.inner = inner
        self.url = inner.url
        self.probe = probe
        self.boot_id = boot_id

    @property
    def is_open(self) -> bool:
        return self.inner.is_open

    def write(self, data: bytes) -> None:
        self.inner.write(data)
        if self.probe.armed:
            self.probe.on_write(data, self.boot_id())

    def discard_output(self) -> None:
        self.inner.discard_output()

    async def close(self) -> None:
        await self.inner.close()


async def _measure_pty_link(
    url: str, mock_pid: int, duration_s: float, batch_size: int, scenario: str
) -> tuple[dict[str, object], LatencyTrace]:
    reads = [0]
    probe = RttProbe()

    def opener_factory(trace: LatencyTrace, session_of: SessionOf) -> TransportOpener:
        async def opener(on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
            def timed(data: bytes) -> None:
                t_ns = time.perf_counter_ns()
                trace.chunk_ns = t_ns
                reads[0] += 1
                on_bytes(data)
                if probe.expect is not None:
                    probe.on_read(data, t_ns)

            def boot_id() -> int | None:
                session = session_of()
                return None if session is None else session.boot_id

            inner = await open_transport(url, timed, on_lost)
            return TimedTransport(inner, probe, boot_id)

        return opener

    rig = build_rig(url, opener_factory, batch_size)
    try:
        await start_cut(rig, scenario)
        trace = rig.trace
        active = [0, 0]

        async def probe_rtt() -> None:
            while True:
                await asyncio.sleep(RTT_PROBE_PERIOD_S)
                active[0] += rig.thc_active()
                active[1] += 1
                if probe.expect is not None:
                    probe.lost += 1  # the ACK was split over two reads, or lost
                    probe.expect = None
                with contextlib.suppress(LinkError):
                    session = rig.supervisor.current()
                    probe.armed = True  # the request's write is the next one, in this step
                    await session.request(fp.Heartbeat(0))
                probe.armed = False

        stats = rig.supervisor.stats
        gaps0, reads0 = stats.telemetry_gaps, reads[0]
        mock_cpu0 = proc_cpu_s(mock_pid)
        usage0 = resource.getrusage(resource.RUSAGE_SELF)
        wall0 = time.perf_counter()
        trace.recording = True
        prober = asyncio.create_task(probe_rtt(), name="rtt-probe")
        await asyncio.sleep(duration_s)
        trace.recording = False
        prober.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await prober
        wall = time.perf_counter() - wall0
        usage1 = resource.getrusage(resource.RUSAGE_SELF)
        mock_cpu1 = proc_cpu_s(mock_pid)
        rss_kb, hwm_kb = _status_kb("VmRSS"), _status_kb("VmHWM")
        state = str(rig.sequence.state)
        with contextlib.suppress(Exception):
            await asyncio.wait_for(rig.service.execute_gcode("M5"), 10.0)
    finally:
        await rig.close()
    cpu_s = (usage1.ru_utime - usage0.ru_utime) + (usage1.ru_stime - usage0.ru_stime)
    batches, answers = trace.batches, trace.answers
    host = [(out - chunk) / 1000 for chunk, out, _, _ in answers]
    bounds, after = board_bound(batches, answers)
    host_p = percentiles(host)
    rtt_p = percentiles(probe.rtts_us)
    e2e: dict[str, object] = {"n": len(host)}
    for key in ("p50", "p99", "max"):
        h, r = host_p[key], rtt_p[key]
        e2e[key] = round(h + r, 1) if isinstance(h, float) and isinstance(r, float) else None
    answered = len({index for *_, index in answers})
    samples = sum(b[3] for b in batches)
    return {
        "duration_s": round(wall, 2),
        "sample_rate_hz": 1000,
        "batch": batch_size,
        "batches": len(batches),
        "samples": samples,
        "answered_batches": answered,
        "telemetry_gaps": stats.telemetry_gaps - gaps0,
        "batches_per_read": round(len(batches) / max(1, reads[0] - reads0), 2),
        "thc_active_fraction": round(active[0] / active[1], 3) if active[1] else None,
        "state_at_end": state,
        "e2e_estimate_us": e2e,
        "host_us": host_p,
        "rtt_us": {**rtt_p, "unmatched": probe.lost},
        "board_bound_us": {
            **percentiles(bounds, digits=0),
            "answer_seen_after_batches": dict(sorted(after.items())),
            "resolution": "one mock wake (its firmware ticks in bursts); an upper bound",
        },
        "cpu_percent": round(100.0 * cpu_s / wall, 2),
        "mock_cpu_percent": (
            None
            if mock_cpu0 is None or mock_cpu1 is None
            else round(100.0 * (mock_cpu1 - mock_cpu0) / wall, 2)
        ),
        "rss_mb": None if rss_kb is None else round(rss_kb / 1024, 1),
        "peak_rss_mb": None if hwm_kb is None else round(hwm_kb / 1024, 1),
    }, trace


# --- in-process processing -----------------------------------------------------------------


class SimLink(SimulatedLink):
    """The simulation's link to a SimulatedBoard, but the board ticks in real time here,
    until ``stop_board``; after that the firmware no longer ticks (it still answers
    requests) and the bench feeds SAMPLES frames itself through ``feed``."""

    URL = "sim://bench"

    def __init__(self, board: SimulatedBoard, on_bytes: BytesCallback, on_lost: LostCallback):
        super().__init__(board, on_bytes, on_lost, url=self.URL)
        self._ticking = True
        self.ticker = self._loop.create_task(self._run(), name="sim-board")

    def feed(self, frame: bytes) -> None:
        self._on_bytes(frame)

    async def close(self) -> None:
        self._ticking = False
        await super().close()

    def stop_board(self) -> None:
        self._ticking = False

    async def _run(self) -> None:
        while self._ticking:
            self.board.tick_due(self._loop.time())
            self.deliver()
            await asyncio.sleep(0.001)


def make_frames(
    last: fp.Samples, target_v: float, count: int, batch: int, seed: int = 1
) -> tuple[list[bytes], fp.Samples]:
    """``count`` SAMPLES frames continuing ``last``: the cut's voltage at the requested feed."""
    rng = random.Random(seed)
    period_us = 1000
    frames = []
    msg = last
    stream = last.stream_seq
    t_us = last.t0_us + last.period_us * len(last.samples_cv)
    xy = round(FEED_MM_MIN / 60.0 * 10.0)
    for _ in range(count):
        stream = (stream + 1) & 0xFFFF
        cv = []
        for k in range(batch):
            t = (t_us + k * period_us) / 1e6
            v = target_v + 2.0 * math.sin(2 * math.pi * 0.5 * t) + rng.gauss(0.0, 0.4)
            cv.append(round(v * 100))
        msg = fp.Samples(
            0, stream, t_us & 0xFFFFFFFF, period_us, last.z_um, last.inputs, last.zvel_seq, xy,
            last.status, tuple(cv),
        )  # fmt: skip
        frames.append(fp.encode(msg))
        t_us += period_us * batch
    return frames, msg


async def feed_paced(
    rig: Rig, link: SimLink, frames: Sequence[bytes], batch: int
) -> dict[str, object]:
    trace = rig.trace
    trace.batches.clear()
    trace.answers.clear()
    loop = asyncio.get_running_loop()
    spacing = batch / 1000.0
    calls: list[float] = []
    active = 0
    trace.recording = True
    start = loop.time()
    i = 0
    n = len(frames)
    while i < n:
        delay = start + i * spacing - loop.time()
        if delay > 0:
            await asyncio.sleep(delay)
        now = loop.time()
        while i < n and start + i * spacing <= now:
            t_in = time.perf_counter_ns()
            trace.chunk_ns = t_in
            link.feed(frames[i])
            calls.append((time.perf_counter_ns() - t_in) / 1000)
            active += rig.thc_active()
            i += 1
    trace.recording = False
    wall = loop.time() - start
    latencies = [(out - chunk) / 1000 for chunk, out, _, _ in trace.answers]
    return {
        "batch": batch,
        "batches": n,
        "data_s": round(n * spacing, 2),
        "wall_s": round(wall, 2),
        "answers": len(trace.answers),
        "thc_active_fraction": round(active / n, 4) if n else None,
        "processing_us": percentiles(latencies),
        "call_us": percentiles(calls),
    }


async def measure_in_process(
    duration_s: float, batches: Sequence[int], scenario: str
) -> dict[str, object]:
    board = SimulatedBoard(scenario, seed=1)
    board.plant.gantry.feed_line("G21 G90")
    board.plant.gantry.feed_line("G0 X100 Y100")
    board.plant.gantry.feed_line(f"G1 X1150 Y100 F{FEED_MM_MIN:g}")
    links: list[SimLink] = []

    def opener_factory(_trace: LatencyTrace, _session_of: SessionOf) -> TransportOpener:
        async def opener(on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
            link = SimLink(board, on_bytes, on_lost)
            links.append(link)
            return link

        return opener

    rig = build_rig(SimLink.URL, opener_factory, 1)
    results = []
    try:
        await start_cut(rig, scenario)
        link = links[-1]
        link.stop_board()
        await link.ticker
        last = rig.trace.last_batch
        target = rig.sequence.thc.target_v
        assert last is not None
        assert target is not None
        for batch in batches:
            count = max(1, round(duration_s * 1000 / batch))
            frames, last = make_frames(last, target, count, batch)
            results.append(await feed_paced(rig, link, frames, batch))
    finally:
        await rig.close()
    return {"scenario": scenario, "sample_rate_hz": 1000, "runs": results}


# --- the suite -----------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--duration", type=float, default=30.0,
        help="seconds of 1 kHz data per measurement (pty run; each in-process batch size)",
    )  # fmt: skip
    parser.add_argument("--e2e-batch", type=int, default=1, help="board batch size over the pty")
    parser.add_argument(
        "--batches", default="1,5", help="batch sizes for the in-process measurement"
    )
    parser.add_argument("--scenario", default=SCENARIO, help="mock plant scenario")
    parser.add_argument(
        "--skip", choices=("pty", "in-process"), action="append", default=[],
        help="leave out one part",
    )  # fmt: skip


async def run_async(args: argparse.Namespace) -> dict[str, object]:
    out: dict[str, object] = {}
    goals: list[Goal] = []
    if "pty" not in args.skip:
        pty = await measure_pty(args.duration, args.e2e_batch, args.scenario)
        out["pty"] = pty
        e2e = pty["e2e"]
        assert isinstance(e2e, dict)
        net = e2e["board_e2e_net_of_mock_lag_us"]
        assert isinstance(net, dict)
        goals.append(Goal("e2e_p99_us", net["p99"], E2E_P99_GOAL_US, at_most=True, unit=" us"))
        cpu = pty["cpu_percent"]
        assert isinstance(cpu, float)
        goals.append(Goal("daemon_cpu_percent", cpu, CPU_GOAL_PERCENT, at_most=True, unit=" %"))
    if "in-process" not in args.skip:
        batches = [int(b) for b in str(args.batches).split(",") if b.strip()]
        inproc = await measure_in_process(args.duration, batches, args.scenario)
        out["in_process"] = inproc
        runs = inproc["runs"]
        assert isinstance(runs, list)
        for r in runs:
            p99 = r["processing_us"]["p99"]
            name = f"processing_p99_us_batch{r['batch']}"
            goals.append(Goal(name, p99, PROCESSING_P99_GOAL_US, at_most=True, unit=" us"))
    out["goals"] = goals_block(goals)
    return out


def run(args: argparse.Namespace) -> dict[str, object]:
    return asyncio.run(run_async(args))
