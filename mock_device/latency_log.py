"""``--latency-log PATH``: when the board really had a Z command, and when a batch really left.

The firmware's clock ``t_us`` advances in bursts (the process ticks every due sample at
each wake), so it cannot say when host bytes arrived. This instrument stamps events with
the real clock mapped to board time, the same mapping the run loop uses to decide which
ticks are due: ``fw_t0_us + (loop.time() - t0) * 1e6``.

JSON lines, written when the process ends (or every ``CHUNK_RECORDS`` records, which is
noted on stderr as ``latency_log_chunk``, since writing a chunk stalls the loop a little):

- ``{"kind": "start", "boot_id", "fw_t0_us", "t0_loop_s"}`` (first line);
- ``{"kind": "zvel_rx", "stream_seq", "rx_board_us", "rx_mono_s", "fw_t_us", "current"}``
  per Z_VELOCITY frame the firmware decoded: ``rx_board_us`` is when the mock's event loop
  read its bytes (later than their arrival if the loop was busy ticking a burst then),
  ``fw_t_us`` the firmware's burst-ticked clock at that moment, ``current`` whether the
  frame is the firmware's last applied one afterwards;
- ``{"kind": "samples_tx", "stream_seq", "t0_us", "t_last_us", "samples", "zvel_seq",
  "tx_board_us", "tx_mono_s"}`` per SAMPLES frame handed to the link: ``t0_us`` as the
  frame carries it (first sample, 32 bits), ``t_last_us`` its last sample (32 bits),
  ``tx_board_us`` when the link write returned;
- ``{"kind": "reboot", "boot_id"}``: board time restarts; records after it are a new run.

``*_mono_s`` are the same instants as raw ``loop.time()`` (CLOCK_MONOTONIC on Linux, the
clock of ``time.perf_counter`` too), so a host on the same machine can split the round
trip into its legs. The hot path only appends the loop time; conversion happens on write.
Nothing of this runs unless the option is given: the firmware's hooks stay ``None``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import firmware_protocol as fp

__all__ = ["CHUNK_RECORDS", "LatencyLog", "read_latency_log"]

CHUNK_RECORDS = 200_000  # ~100 s of batch-1 traffic at 1 kHz before a chunk is written

_ZVEL = 0
_SAMPLES = 1
_MARK = 2

Record = tuple[int, int, float, int, int, int, int, int]


class LatencyLog:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.t0_loop_s = 0.0
        self.fw_t0_us = 0
        self.boot_id = 0
        self._records: list[Record] = []
        self._pending: list[fp.Samples] = []
        self._started = False
        self._file_open = False

    def start(self, t0_loop_s: float, fw_t0_us: int, boot_id: int) -> None:
        """The run loop's mapping from the loop clock to board time (used on write)."""
        self.t0_loop_s, self.fw_t0_us, self.boot_id = t0_loop_s, fw_t0_us, boot_id

    def board_us(self, loop_time_s: float) -> int:
        return self.fw_t0_us + round((loop_time_s - self.t0_loop_s) * 1e6)

    # --- hot path (only with the option) -------------------------------------------------

    def zvel_received(self, stream_seq: int, rx_loop_s: float, fw_t_us: int, current: bool) -> None:
        self._records.append((_ZVEL, stream_seq, rx_loop_s, fw_t_us, int(current), 0, 0, 0))
        self._maybe_chunk()

    def samples_built(self, msg: fp.Samples) -> None:
        self._pending.append(msg)

    def take_pending(self) -> list[fp.Samples]:
        pending, self._pending = self._pending, []
        return pending

    def samples_sent(self, sent: list[fp.Samples], tx_loop_s: float) -> None:
        for m in sent:
            n = len(m.samples_cv)
            t_last = (m.t0_us + m.period_us * (n - 1)) & 0xFFFFFFFF
            self._records.append(
                (_SAMPLES, m.stream_seq, tx_loop_s, m.t0_us, t_last, n, m.zvel_seq, 0)
            )
        self._maybe_chunk()

    def reboot(self, boot_id: int) -> None:
        self._pending.clear()
        self._records.append((_MARK, 0, 0.0, 0, 0, 0, 0, boot_id))

    # --- output --------------------------------------------------------------------------

    def _maybe_chunk(self) -> None:
        if len(self._records) >= CHUNK_RECORDS:
            n = len(self._records)
            self.write()
            print(json.dumps({"event": "latency_log_chunk", "records": n}), file=sys.stderr)

    def _lines(self) -> list[str]:
        lines = []
        if not self._started:
            self._started = True
            head = {
                "kind": "start",
                "boot_id": f"{self.boot_id:08x}",
                "fw_t0_us": self.fw_t0_us,
                "t0_loop_s": self.t0_loop_s,
                "clock": "fw_t0_us + (loop.time() - t0_loop_s) * 1e6",
            }
            lines.append(json.dumps(head))
        board_us = self.board_us
        for kind, seq, t, a, b, c, d, e in self._records:
            if kind == _ZVEL:
                lines.append(
                    f'{{"kind": "zvel_rx", "stream_seq": {seq}, "rx_board_us": {board_us(t)}, '
                    f'"rx_mono_s": {t!r}, "fw_t_us": {a}, "current": {"true" if b else "false"}}}'
                )
            elif kind == _SAMPLES:
                lines.append(
                    f'{{"kind": "samples_tx", "stream_seq": {seq}, "t0_us": {a}, '
                    f'"t_last_us": {b}, "samples": {c}, "zvel_seq": {d}, '
                    f'"tx_board_us": {board_us(t)}, "tx_mono_s": {t!r}}}'
                )
            else:
                lines.append(f'{{"kind": "reboot", "boot_id": "{e:08x}"}}')
        return lines

    def write(self) -> None:
        """Append what is buffered (the first call truncates the file)."""
        lines = self._lines()
        self._records.clear()
        mode = "a" if self._file_open else "w"
        self._file_open = True
        with self.path.open(mode, encoding="ascii") as f:
            f.writelines(line + "\n" for line in lines)


def read_latency_log(path: Path) -> list[dict[str, object]]:
    """The records of a latency log, in order."""
    out: list[dict[str, object]] = []
    for line in path.read_text(encoding="ascii").splitlines():
        if line.strip():
            rec = json.loads(line)
            assert isinstance(rec, dict)
            out.append(rec)
    return out
