"""The cut history: records from the daemon's ``sequence`` events and telemetry."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from dthc_tools.panel.history import CutHistory, CutRecorder


def seq(t: float, state: str, error: str = "") -> dict[str, Any]:
    return {"type": "sequence", "t": t, "state": state, "error": error}


def point(t: float, state: str, volts: float, height: float | None, *locks: str) -> dict[str, Any]:
    return {"t": t, "state": state, "voltage_v": volts, "target_v": 120.0, "z_mm": 3.0,
            "height_mm": height, "locks": list(locks)}  # fmt: skip


def g200_s1_cut(recorder: CutRecorder) -> list[Any]:
    """A G200 S1 cut: touch-off, pierce, stop for cycle start, relight, cut, safe height."""
    done = []
    for t, state in [
        (1.0, "to_probe_height"), (2.0, "probing"), (3.0, "to_pierce_height"),
        (3.5, "arc_wait"), (3.9, "pierce_delay"), (4.2, "s1_raise"),
        (4.6, "s1_wait_cycle_start"), (8.0, "s1_lower"), (8.5, "arc_wait"), (8.6, "cutting"),
    ]:  # fmt: skip
        done.append(recorder.on_sequence(seq(t, state)))
    for i, height in enumerate((1.5, 1.7, 1.1, 1.5)):
        recorder.on_telemetry(
            point(9.0 + i * 0.1, "cutting", 121.0, height, *(["void"] * (i == 2)))
        )
    done.append(recorder.on_sequence(seq(12.6, "to_safe_height")))
    done.append(recorder.on_sequence(seq(13.0, "idle")))
    return done


def test_a_record_has_the_exact_times_of_its_cut() -> None:
    recorder = CutRecorder()
    recorder.set_context(line=5, program="part.nc", material=3, cut_height_mm=1.5)
    done = g200_s1_cut(recorder)
    assert done[:-1] == [None] * (len(done) - 1)  # complete only when back at idle
    record = done[-1]
    assert record is not None
    assert (record.number, record.start_line, record.program, record.material) == (
        1, 5, "part.nc", 3,
    )  # fmt: skip
    assert record.arc_start_s == 0.4  # torch on (arc_wait) -> arc OK
    assert record.pierce_s == 0.3  # the pierce delay, ended by the S1 stop
    assert record.arc_on_s == 4.3  # 3.9-4.2 and 8.6-12.6: the arc was out during the stop
    assert record.height_rms_mm == round(_rms(), 3)  # measured height vs the cut height
    assert record.height_max_mm == 0.4
    assert record.volts_rms_v == 1.0  # 121 V against 120 V, the locked point left out
    assert record.locks == {"void": 1}
    assert record.target_v == 120.0
    assert record.error == ""
    assert recorder.current is None


def _rms() -> float:
    deviations = (0.0, 0.2, -0.4, 0.0)  # the four heights against 1.5 mm
    return float((sum(d * d for d in deviations) / 4) ** 0.5)


def test_on_a_warped_sheet_the_voltage_error_stays_small_where_the_height_figure_grows() -> None:
    """The THC follows a sheet warped by 2 mm: the torch travels 2 mm from the point probed
    at the start (the height figure, relative to that point, reads 1.4 mm RMS) while the arc
    voltage stays within 0.5 V of the target: the headline figure says the THC held."""
    recorder = CutRecorder()
    recorder.set_context(cut_height_mm=1.5)
    for t, state in [(1.0, "to_probe_height"), (2.0, "arc_wait"), (2.2, "pierce_delay"),
                     (2.5, "cutting")]:  # fmt: skip
        recorder.on_sequence(seq(t, state))
    for i in range(40):
        warp = 2.0 * i / 39  # the plate rises under the torch
        volts = 120.0 + (0.5 if i % 2 else -0.5)
        recorder.on_telemetry(point(3.0 + i * 0.1, "cutting", volts, 1.5 + warp))
    record = recorder.on_sequence(seq(8.0, "idle"))
    assert record is not None
    assert record.volts_rms_v == 0.5
    assert record.height_rms_mm is not None
    assert record.height_rms_mm > 1.1
    assert record.summary()["volts_rms_v"] == 0.5


def test_a_fault_ends_the_record_with_its_reason() -> None:
    recorder = CutRecorder()
    for t, state in [(1.0, "to_probe_height"), (2.0, "arc_wait"), (2.2, "pierce_delay"),
                     (2.5, "cutting")]:  # fmt: skip
        assert recorder.on_sequence(seq(t, state)) is None
    record = recorder.on_sequence(seq(4.0, "faulted", "arc lost"))
    assert record is not None
    assert record.error == "arc lost"
    assert record.arc_on_s == 1.8
    # Re-armed: faulted -> idle is no cut; the next one is number 2.
    assert recorder.on_sequence(seq(5.0, "idle")) is None
    assert recorder.current is None
    recorder.on_sequence(seq(6.0, "to_probe_height"))
    assert recorder.current is not None
    assert recorder.current.number == 2


def test_moves_that_are_no_cut_make_no_record() -> None:
    recorder = CutRecorder()
    for t, state in [(1.0, "ohmic_test"), (1.5, "idle"), (2.0, "program_z_move"), (2.4, "idle"),
                     (3.0, "probe_test"), (3.5, "idle")]:  # fmt: skip
        assert recorder.on_sequence(seq(t, state)) is None
    assert recorder.current is None
    recorder.on_telemetry(point(3.0, "idle", 0.0, None))  # between cuts: not kept anywhere


def test_the_csv_has_one_row_per_telemetry_point() -> None:
    recorder = CutRecorder()
    record = g200_s1_cut(recorder)[-1]
    assert record is not None
    rows = list(csv.DictReader(io.StringIO(record.as_csv())))
    assert len(rows) == 4
    assert rows[0] == {
        "t_s": "9.0", "state": "cutting", "voltage_v": "121.0", "target_v": "120.0",
        "z_mm": "3.0", "height_mm": "1.5", "locks": "",
    }  # fmt: skip
    assert rows[2]["locks"] == "void"


def test_the_history_file_survives_a_restart_and_a_torn_last_line(tmp_path: Path) -> None:
    path = tmp_path / "cuts.jsonl"
    history = CutHistory(path)
    record = g200_s1_cut(CutRecorder(first_number=history.next_number))[-1]
    assert record is not None
    history.add(record)
    with path.open("a") as out:
        out.write('{"number": 2, "start_t"')  # the panel killed mid-write
    again = CutHistory(path)
    assert [r.number for r in again.records] == [1]
    assert again.next_number == 2
    kept = again.get(1)
    assert kept is not None
    assert kept.as_csv() == record.as_csv()
    assert kept.states == record.states
