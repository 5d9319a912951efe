"""Ground truth: what really happened in the simulation, for tests and reports.

The recorder sees every sample: it keeps per-cut statistics and safety-violation counts
over the whole run, and stores every ``decimation``-th sample in a fixed-size ring buffer
(column arrays of doubles, so memory is bounded: about 88 bytes per stored sample).
"""

import csv
import json
import math
from array import array
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

__all__ = [
    "TRUTH_FIELDS",
    "VIOLATION_LEASE",
    "VIOLATION_TOUCH",
    "CutStats",
    "TruthRecorder",
    "TruthRow",
    "TruthSummary",
]

#: Counted by the recorder itself, once per episode (tip height <= 0 with a transferred arc).
VIOLATION_TOUCH = "torch_touching_plate_while_cutting"
#: Counted by the board firmware through ``count_violation``: torch on after lease expiry.
VIOLATION_LEASE = "torch_on_after_lease_expiry"

_ARC_TRANSFERRED = 2  # ArcState.TRANSFERRED, kept as a plain int on the hot path


class TruthRow(NamedTuple):
    """One recorded sample."""

    t_s: float
    x_mm: float
    y_mm: float
    xy_speed_mm_s: float
    true_height_mm: float
    carriage_z_mm: float
    surface_z_mm: float
    torch_on: bool
    arc_state: int
    arc_voltage_true_v: float
    measured_v: float


TRUTH_FIELDS: tuple[str, ...] = TruthRow._fields


@dataclass(frozen=True, slots=True)
class CutStats:
    """One cut (one transferred-arc episode).

    Height errors are measured against the material cut height only once the arc has
    been transferred for the THC delay and while the gantry moves; ``dives`` counts the
    episodes within that window with the true height below half the cut height.
    """

    index: int
    start_t_s: float
    end_t_s: float
    duration_s: float
    measured_samples: int
    height_rms_error_mm: float
    height_max_error_mm: float
    min_height_mm: float
    dives: int
    touches: int


@dataclass(frozen=True, slots=True)
class TruthSummary:
    """Per-cut statistics and violation counts of a run."""

    cuts: tuple[CutStats, ...]
    violations: Mapping[str, int]
    samples_seen: int
    samples_stored: int
    samples_dropped: int


class TruthRecorder:
    """Records samples and counts violations; ``record`` once per plant step."""

    def __init__(
        self,
        *,
        cut_height_mm: float = 1.5,
        thc_delay_s: float = 0.5,
        decimation: int = 1,
        capacity: int = 120_000,
    ) -> None:
        if decimation < 1 or capacity < 1:
            raise ValueError("decimation and capacity must be >= 1")
        self.cut_height_mm = cut_height_mm
        self.thc_delay_s = thc_delay_s
        self.decimation = decimation
        self.capacity = capacity
        self._cols = tuple(array("d", bytes(8 * capacity)) for _ in TRUTH_FIELDS)
        self._next = 0  # next ring index
        self._stored = 0
        self._seen = 0
        self._countdown = 1
        self._violations: dict[str, int] = {}
        self._cuts: list[CutStats] = []
        self._in_cut = False
        self._touching = False
        self._reset_cut(0.0)

    def _reset_cut(self, t_s: float) -> None:
        self._cut_start_t = t_s
        self._cut_last_t = t_s
        self._n = 0
        self._sum2 = 0.0
        self._max_err = 0.0
        self._min_h = math.inf
        self._dives = 0
        self._in_dive = False
        self._touches = 0

    # ------------------------------------------------------------- violations
    def count_violation(self, kind: str) -> None:
        """Count one safety violation of ``kind`` (e.g. ``VIOLATION_LEASE``)."""
        self._violations[kind] = self._violations.get(kind, 0) + 1

    @property
    def violations(self) -> dict[str, int]:
        """Violation counts by kind (a copy)."""
        return dict(self._violations)

    # ---------------------------------------------------------------- record
    def record(  # noqa: PLR0917 - hot path, once per sample: positional calls are cheapest
        self,
        t_s: float,
        x_mm: float,
        y_mm: float,
        xy_speed_mm_s: float,
        true_height_mm: float,
        carriage_z_mm: float,
        surface_z_mm: float,
        torch_on: bool,
        arc_state: int,
        arc_voltage_true_v: float,
        measured_v: float,
    ) -> None:
        """Take one sample: update cut statistics, store it if the decimation says so."""
        self._seen += 1
        if arc_state == _ARC_TRANSFERRED:
            if not self._in_cut:
                self._in_cut = True
                self._reset_cut(t_s)
            self._cut_last_t = t_s
            h = true_height_mm
            self._min_h = min(self._min_h, h)
            if h <= 0.0:
                if not self._touching:
                    self._touching = True
                    self._touches += 1
                    self.count_violation(VIOLATION_TOUCH)
            else:
                self._touching = False
            if xy_speed_mm_s > 0.0 and t_s - self._cut_start_t >= self.thc_delay_s:
                err = h - self.cut_height_mm
                self._n += 1
                self._sum2 += err * err
                self._max_err = max(self._max_err, abs(err))
                if h < 0.5 * self.cut_height_mm:
                    if not self._in_dive:
                        self._in_dive = True
                        self._dives += 1
                else:
                    self._in_dive = False
        elif self._in_cut:
            self._close_cut()

        self._countdown -= 1
        if self._countdown:
            return
        self._countdown = self.decimation
        i = self._next
        c = self._cols
        c[0][i] = t_s
        c[1][i] = x_mm
        c[2][i] = y_mm
        c[3][i] = xy_speed_mm_s
        c[4][i] = true_height_mm
        c[5][i] = carriage_z_mm
        c[6][i] = surface_z_mm
        c[7][i] = 1.0 if torch_on else 0.0
        c[8][i] = arc_state
        c[9][i] = arc_voltage_true_v
        c[10][i] = measured_v
        i += 1
        self._next = 0 if i == self.capacity else i
        self._stored += 1

    def _close_cut(self) -> None:
        self._in_cut = False
        self._touching = False
        self._cuts.append(self._cut_stats())

    def _cut_stats(self) -> CutStats:
        n = self._n
        return CutStats(
            index=len(self._cuts),
            start_t_s=self._cut_start_t,
            end_t_s=self._cut_last_t,
            duration_s=self._cut_last_t - self._cut_start_t,
            measured_samples=n,
            height_rms_error_mm=math.sqrt(self._sum2 / n) if n else math.nan,
            height_max_error_mm=self._max_err if n else math.nan,
            min_height_mm=self._min_h,
            dives=self._dives,
            touches=self._touches,
        )

    # --------------------------------------------------------------- reading
    def __len__(self) -> int:
        return min(self._stored, self.capacity)

    def rows(self) -> Iterator[TruthRow]:
        """Stored samples, oldest first."""
        n = len(self)
        start = (self._next - n) % self.capacity
        cols = self._cols
        for k in range(n):
            i = (start + k) % self.capacity
            yield TruthRow(
                cols[0][i],
                cols[1][i],
                cols[2][i],
                cols[3][i],
                cols[4][i],
                cols[5][i],
                cols[6][i],
                cols[7][i] != 0.0,
                int(cols[8][i]),
                cols[9][i],
                cols[10][i],
            )

    def column(self, name: str) -> list[float]:
        """One stored field as a list, oldest first."""
        idx = TRUTH_FIELDS.index(name)
        col = self._cols[idx]
        n = len(self)
        start = (self._next - n) % self.capacity
        if start + n <= self.capacity:
            return col[start : start + n].tolist()
        return col[start:].tolist() + col[: (start + n) - self.capacity].tolist()

    def cuts(self) -> tuple[CutStats, ...]:
        """Finished cuts plus the running one, if any."""
        done = tuple(self._cuts)
        return (*done, self._cut_stats()) if self._in_cut else done

    def summary(self) -> TruthSummary:
        """Per-cut statistics and violation counts so far."""
        return TruthSummary(
            cuts=self.cuts(),
            violations=self.violations,
            samples_seen=self._seen,
            samples_stored=self._stored,
            samples_dropped=self._stored - len(self),
        )

    def write_csv(self, path: str | Path) -> int:
        """Write the stored samples as CSV with a header; return the number of rows."""
        count = 0
        with Path(path).open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(TRUTH_FIELDS)
            for row in self.rows():
                writer.writerow((*row[:7], int(row.torch_on), *row[8:]))
                count += 1
        return count

    def write_jsonl(self, path: str | Path) -> int:
        """Write the stored samples as JSON lines; return the number of rows."""
        count = 0
        with Path(path).open("w", encoding="utf-8") as fh:
            for row in self.rows():
                fh.write(json.dumps(row._asdict(), allow_nan=True) + "\n")
                count += 1
        return count
