"""The cut history: one record per cut, built from the daemon's ``sequence`` events (exact
board times) and its telemetry (the trace drawn for the cut), kept by the panel.

Sans-io: :class:`CutRecorder` is fed documents and says when a record is complete, so it
is tested without a broker; :class:`CutHistory` keeps the last records (and, when given a
file, appends each as a JSON line and reads them back at start)."""

from __future__ import annotations

import csv
import io
import json
import math
from collections import Counter, deque
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["CutHistory", "CutRecord", "CutRecorder"]

# A cut starts when the sequence leaves idle (or faulted) into one of these ...
START_STATES = frozenset({
    "to_probe_height", "probing", "creep_up", "to_pierce_height", "arc_wait", "cutting",
})  # fmt: skip
# ... the arc burns in these (a G200 S1 stop puts it out in s1_raise, a relight lights it)
ARC_ON_STATES = frozenset({"pierce_delay", "puddle_jump", "to_cut_height", "cutting"})
# ... and it is over when the sequence is back in one of these.
END_STATES = frozenset({"idle", "faulted"})
TRACE_MAX_POINTS = 20_000  # 33 min at 10 Hz: a cut longer than that keeps its first part
CSV_COLUMNS = ("t_s", "state", "voltage_v", "target_v", "z_mm", "height_mm", "locks")


@dataclass
class CutRecord:
    number: int  # 1, 2, ... in the panel's history
    start_t: float  # board time, s
    start_line: int | None = None  # the sender's program line when it started
    program: str = ""
    material: int | None = None
    end_t: float | None = None
    arc_start_s: float | None = None  # torch on -> arc OK (the last attempt)
    pierce_s: float | None = None  # arc OK -> the pierce delay over (motion starts)
    arc_on_s: float = 0.0  # arc burning, summed over the cut (a G200 S1 stop relights)
    target_v: float | None = None  # the THC's target in force at the end
    # The headline: arc voltage minus the THC's target, RMS, while cutting with the THC in
    # control (no lock): the THC's tracking error, which a warped sheet does not inflate.
    volts_rms_v: float | None = None
    # Height above the point probed at the cut's start minus the cut height, RMS and max,
    # while cutting: on a warped sheet this includes the warp the THC follows on purpose.
    height_rms_mm: float | None = None
    height_max_mm: float | None = None
    cut_height_mm: float | None = None
    locks: dict[str, int] = field(default_factory=dict)  # telemetry points with each lock
    error: str = ""  # the fault that ended it, if one did
    states: list[tuple[float, str]] = field(default_factory=list)
    trace: list[dict[str, Any]] = field(default_factory=list)

    @property
    def done(self) -> bool:
        return self.end_t is not None

    def summary(self) -> dict[str, Any]:
        """Everything but the trace: the history's list."""
        out = asdict(self)
        out.pop("trace")
        out["points"] = len(self.trace)
        out["duration_s"] = None if self.end_t is None else round(self.end_t - self.start_t, 3)
        return out

    def as_csv(self) -> str:
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        for point in self.trace:
            row = [point.get(column) for column in CSV_COLUMNS]
            row[-1] = " ".join(point.get("locks") or [])
            writer.writerow(["" if value is None else value for value in row])
        return buffer.getvalue()

    @classmethod
    def from_dict(cls, document: Mapping[str, Any]) -> CutRecord:
        fields = {k: v for k, v in document.items() if k in cls.__dataclass_fields__}
        fields["states"] = [tuple(s) for s in fields.get("states", [])]
        return cls(**fields)


class CutRecorder:
    """Feed it the daemon's documents in arrival order; :meth:`on_sequence` returns the
    record a ``sequence`` event completed, if any."""

    def __init__(self, *, first_number: int = 1) -> None:
        self.current: CutRecord | None = None
        self._numbers = first_number - 1
        self._state = "idle"
        self._arc_on_since: float | None = None
        self._torch_on_t: float | None = None
        self._arc_ok_t: float | None = None
        self._context: dict[str, Any] = {}  # line, program, material, cut height
        self._deviations: list[float] = []
        self._volt_errors: list[float] = []

    def set_context(self, **context: Any) -> None:
        """What the next record starts with: the sender's line and program, the material
        selected, the cut height in force."""
        self._context.update(context)

    def on_telemetry(self, point: Mapping[str, Any]) -> None:
        record = self.current
        if record is None or not isinstance(point.get("t"), int | float):
            return
        if len(record.trace) < TRACE_MAX_POINTS:
            record.trace.append(
                {"t_s": point["t"], **{column: point.get(column) for column in CSV_COLUMNS[1:]}}
            )
        locks = point.get("locks")
        if isinstance(locks, list):
            record.locks = dict(Counter(record.locks) + Counter(str(lock) for lock in locks))
        target = point.get("target_v")
        if isinstance(target, int | float):
            record.target_v = round(float(target), 2)
        height, cut_height = point.get("height_mm"), record.cut_height_mm
        if (
            point.get("state") == "cutting"
            and isinstance(height, int | float)
            and cut_height is not None
        ):
            self._deviations.append(float(height) - cut_height)
        volts = point.get("voltage_v")
        if (
            point.get("state") == "cutting"
            and isinstance(volts, int | float)
            and isinstance(target, int | float)
            and locks == []
        ):
            self._volt_errors.append(float(volts) - float(target))

    def on_sequence(self, event: Mapping[str, Any]) -> CutRecord | None:
        state, t = str(event.get("state")), event.get("t")
        if not isinstance(t, int | float):
            return None
        previous, self._state = self._state, state
        record = self.current
        if record is None:
            if previous in END_STATES and state in START_STATES:
                self._open(float(t))
                record = self.current
            else:
                return None
        assert record is not None
        record.states.append((float(t), state))
        if state == "arc_wait":
            self._torch_on_t = float(t)
        was_on, is_on = previous in ARC_ON_STATES, state in ARC_ON_STATES
        if is_on and not was_on:
            self._arc_on_since = float(t)
            if self._arc_ok_t is None and self._torch_on_t is not None:
                self._arc_ok_t = float(t)
                record.arc_start_s = round(float(t) - self._torch_on_t, 3)
        elif was_on and not is_on:
            self._close_arc(float(t))
        pierced = previous in ("pierce_delay", "puddle_jump") and state != "puddle_jump"
        if pierced and record.pierce_s is None and self._arc_ok_t is not None:
            record.pierce_s = round(float(t) - self._arc_ok_t, 3)
        if state in END_STATES:
            self._close_arc(float(t))
            record.end_t = float(t)
            record.error = str(event.get("error") or "")
            self._finish_stats(record)
            self.current = None
            return record
        return None

    def _open(self, t: float) -> None:
        self._numbers += 1
        context = self._context
        self.current = CutRecord(
            number=self._numbers, start_t=t, start_line=context.get("line"),
            program=str(context.get("program") or ""), material=context.get("material"),
            cut_height_mm=context.get("cut_height_mm"),
        )  # fmt: skip
        self._arc_on_since = self._torch_on_t = self._arc_ok_t = None
        self._deviations = []
        self._volt_errors = []

    def _close_arc(self, t: float) -> None:
        if self._arc_on_since is not None and self.current is not None:
            self.current.arc_on_s = round(self.current.arc_on_s + t - self._arc_on_since, 3)
        self._arc_on_since = None

    def _finish_stats(self, record: CutRecord) -> None:
        deviations = self._deviations
        if deviations:
            record.height_rms_mm = round(_rms(deviations), 3)
            record.height_max_mm = round(max(abs(d) for d in deviations), 3)
        if self._volt_errors:
            record.volts_rms_v = round(_rms(self._volt_errors), 2)


def _rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


class CutHistory:
    """The last ``keep`` records, newest last; each finished record appended to ``path``."""

    def __init__(self, path: Path | None = None, *, keep: int = 200) -> None:
        self.path = path
        self.records: deque[CutRecord] = deque(maxlen=keep)
        if path is not None and path.exists():
            self.records.extend(_read(path.read_text().splitlines()))

    @property
    def next_number(self) -> int:
        return self.records[-1].number + 1 if self.records else 1

    def add(self, record: CutRecord) -> None:
        self.records.append(record)
        if self.path is not None:
            with self.path.open("a") as out:
                out.write(json.dumps(asdict(record)) + "\n")

    def get(self, number: int) -> CutRecord | None:
        return next((r for r in self.records if r.number == number), None)


def _read(lines: Iterable[str]) -> Iterable[CutRecord]:
    for line in lines:
        try:
            yield CutRecord.from_dict(json.loads(line))
        except (ValueError, TypeError):
            continue  # a line cut short by a crash: the others still count
