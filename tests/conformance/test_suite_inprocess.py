"""The suite in-process, against a simulated board ticking in real time behind an injected opener.

Covers what the mock process cannot show: a board without ohmic sensing (the duplicate
check falls back to Z moves, the probe to the float switch; with no output to switch on
the lease is checked at rest only), a link that cannot be opened, and the pure parts
(window, input-event audit, options) on their own.
"""

from __future__ import annotations

import argparse

import pytest

import firmware_protocol as fp
from dthc_bridge.conformance import CHECK_NAMES, ConformanceOptions, run_suite
from dthc_bridge.conformance.checks_motion import audit_input_events
from dthc_bridge.conformance.checks_telemetry import count_losses
from dthc_bridge.conformance.cli import add_arguments, options_from_args
from dthc_bridge.conformance.context import InputRecord
from dthc_bridge.conformance.errors import OutsideWindow
from dthc_bridge.conformance.window import MotionWindow
from mock_device.board_logic import BoardIdentity
from mock_device.sim import SimulatedBoard
from tests.link.board_harness import RealtimeSimBoard

NO_OHMIC = BoardIdentity(
    serial="SIM-NO-OHMIC", capabilities=int(fp.Capability.FLOAT | fp.Capability.Z_LIMITS)
)


@pytest.mark.slow
async def test_board_without_ohmic_sensing_is_checked_by_moves_and_the_float_switch() -> None:
    """Without the OHMIC capability the suite still checks duplicates (a Z move resent must
    not move Z again), probes by the float switch and checks the idle lease lapse; all
    pass, the latched lease (no output to switch on without --allow-torch-relay) and the
    reset (no way to reset) are skipped, and nothing moved outside the window. It has no
    HOMING either: Z_HOME is refused as the protocol says, the homing cycle skipped."""
    sim = RealtimeSimBoard(SimulatedBoard("flat_clean", 11, identity=NO_OHMIC))
    options = ConformanceOptions(link="sim://conf-no-ohmic", start_z_mm=25.0, feed_mm_s=50.0,
                                 rtt_limit_ms=100.0, telemetry_s=1.0, rtt_queries=50)  # fmt: skip
    async with sim.running():
        report = await run_suite(options, opener=sim.opener)
    checks = {c.name: c for c in report.checks}
    assert list(checks) == list(CHECK_NAMES)
    verdicts = {name: c.passed for name, c in checks.items()}
    skips = {"lease_expiry": None, "boot_id_reset": None, "z_home_cycle": None}
    assert verdicts == {**dict.fromkeys(CHECK_NAMES, True), **skips}, [
        (c.name, c.figure) for c in report.checks if c.passed is not True
    ]
    assert report.exit_status == 0
    assert checks["duplicate_seq"].values["action"] == "Z_MOVE up 0.5 mm"
    assert checks["probe_contact"].values["sensor"] == "FLOAT"
    assert "--reset-signal-pid" in checks["boot_id_reset"].hint
    assert "--allow-torch-relay" in checks["lease_expiry"].hint
    assert checks["lease_idle_lapse"].values["detail"] == fp.LEASE_DETAIL_IDLE
    assert sim.board.firmware.torch_on is False


@pytest.mark.slow
async def test_only_runs_the_named_checks_and_skips_the_rest() -> None:
    """``--only telemetry_gaps`` runs the handshake, the set-up and the telemetry step (the
    checks measured in the same window report too); every other check is skipped as not
    selected, and an unknown name is refused naming the option."""
    sim = RealtimeSimBoard(SimulatedBoard("flat_clean", 12))
    options = ConformanceOptions(
        link="sim://conf-only", start_z_mm=25.0, rtt_limit_ms=100.0, telemetry_s=1.0,
        rtt_queries=50, only=("telemetry_gaps",),
    )  # fmt: skip
    async with sim.running():
        report = await run_suite(options, opener=sim.opener)
    verdicts = {c.name: c.passed for c in report.checks}
    assert list(verdicts) == list(CHECK_NAMES)
    ran = {"handshake", "protocol_version", "telemetry_rate", "telemetry_jitter",
           "telemetry_gaps", "status_rtt"}  # fmt: skip
    assert {n for n, v in verdicts.items() if v is not None} == ran
    assert verdicts["telemetry_gaps"] is True
    assert all(c.figure == "not selected (--only)" for c in report.checks if c.name not in ran)
    with pytest.raises(ValueError, match="--only: no check named telemetry_gap "):
        options_from_args(argparse.Namespace(**{**vars(_default_args()), "only": "telemetry_gap"}))


def _default_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(["/dev/null"])


async def test_unopenable_link_fails_the_handshake_and_skips_the_rest() -> None:
    """A link that cannot be opened is one failed check naming the link; the rest are
    skipped, and the exit status says failure."""
    report = await run_suite(ConformanceOptions(link="/nonexistent/dthc-nobody-here"))
    assert report.checks[0].name == "handshake"
    assert report.checks[0].passed is False
    assert "/nonexistent/dthc-nobody-here" in report.checks[0].figure
    assert [c.passed for c in report.checks[1:]] == [None] * (len(CHECK_NAMES) - 1)
    assert report.exit_status == 1


def test_window_refuses_targets_outside_it_and_guard_stops_once_per_excursion() -> None:
    """Targets beyond ref ± half width (or the soft limits) raise before anything is sent;
    Z seen beyond the window by more than the margin triggers one stop per excursion."""
    window = MotionWindow(ref_um=25_000, half_width_um=10_000, z_min_um=0, z_max_um=30_000,
                          guard_margin_um=1_000)  # fmt: skip
    assert window.check(15_000) == 15_000
    with pytest.raises(OutsideWindow):
        window.check(14_999)
    with pytest.raises(OutsideWindow):
        window.check(31_000)  # inside ±10 mm but above the board's soft limit
    stops: list[int] = []
    guard = window.guard(lambda: stops.append(1))

    def batch(z_um: int) -> fp.Samples:
        return fp.Samples(0, 0, 0, 1000, z_um, 0, 0, 0, 0, ())

    for z in (20_000, 14_500, 13_900, 13_000, 20_000, 13_000):
        guard(batch(z))
    assert len(stops) == 2
    assert window.excursions == 2


def _status(event_counter: int, inputs: int) -> fp.Status:
    return fp.Status(0, 1, 0, 0, inputs, 0, 250, event_counter, 0, 0, 0, 0, 0, 0, 0)


def test_input_event_audit_finds_gaps_wrong_snapshots_and_repeated_levels() -> None:
    """The audit passes a clean rise/fall of OHMIC (and a FAULT re-report), and names a
    lost event, an event counter used twice, a snapshot whose bit disagrees with the
    level, and an edge that repeats the previous level."""
    ohmic = fp.InputMask.OHMIC
    rise = fp.Event(0, 6, 100, fp.InputBit.OHMIC, 1, ohmic, 0)
    fall = fp.Event(0, 7, 200, fp.InputBit.OHMIC, 0, 0, 0)
    clean = InputRecord(_status(5, 0), _status(7, 0), 0, 2, "test")
    problems, values = audit_input_events(clean, [rise, fall])
    assert problems == []
    assert values["events"] == 2
    # A fault shares the counter; a re-report of it repeats its counter, which is fine.
    fault = fp.Fault(0, 8, 300, fp.FaultCode.LEASE_EXPIRED, 0, 1, 0)
    with_fault = InputRecord(_status(5, 0), _status(8, 0), 0, 4, "test")
    assert audit_input_events(with_fault, [rise, fall, fault, fault])[0] == []
    gap = InputRecord(_status(5, 0), _status(8, 0), 0, 2, "test")
    assert "1 of 3 events not reported" in audit_input_events(gap, [rise, fall])[0][0]
    twice = InputRecord(_status(5, 0), _status(7, 0), 0, 3, "test")
    assert "repeat an earlier counter" in audit_input_events(twice, [rise, rise, fall])[0][0]
    bad = fp.Event(0, 6, 100, fp.InputBit.OHMIC, 1, 0, 0)  # snapshot says inactive
    problems, _ = audit_input_events(
        InputRecord(_status(5, 0), _status(6, ohmic), 0, 1, "t"), [bad]
    )
    assert any("snapshot" in p for p in problems)
    repeat = fp.Event(0, 6, 100, fp.InputBit.OHMIC, 0, 0, 0)  # "falls" while already low
    problems, _ = audit_input_events(InputRecord(_status(5, 0), _status(6, 0), 0, 1, "t"), [repeat])
    assert any("previous level" in p for p in problems)


def test_options_keep_the_probe_inside_the_window_and_name_bad_values() -> None:
    """The probe's max travel leaves room for deceleration inside the window; an option
    out of range is refused with its command-line name."""
    assert ConformanceOptions(link="x").probe_max_travel_mm == pytest.approx(9.5)
    assert ConformanceOptions(link="x", probe_travel_mm=4).probe_max_travel_mm == 4
    with pytest.raises(ValueError, match="--probe-travel-mm"):
        ConformanceOptions(link="x", z_window_mm=5, probe_travel_mm=8)
    with pytest.raises(ValueError, match="--lease-ms"):
        ConformanceOptions(link="x", lease_ms=5)


def _batch(stream_seq: int, *, overflow: bool = False) -> fp.Samples:
    status = int(fp.StatusBit.SAMPLE_OVERFLOW) if overflow else 0
    return fp.Samples(0, stream_seq, stream_seq * 5000, 1000, 0, 0, 0, 0, status, (1,) * 5)


def test_telemetry_gaps_count_losses_in_the_window_not_one_flagged_before_it() -> None:
    """SAMPLE_OVERFLOW marks the batch after a lost one: on the window's first batch it is
    a loss before the window (no gap can show it), reported apart; inside the window a
    loss is a gap and a flag, both counted."""
    clean = [_batch(n) for n in range(10)]
    assert count_losses(clean) == (0, 0, False)
    flagged_first = [_batch(0, overflow=True), *clean[1:]]
    assert count_losses(flagged_first) == (0, 0, True)
    lost_inside = [*clean[:4], _batch(5, overflow=True), *(_batch(n) for n in range(6, 10))]
    assert count_losses(lost_inside) == (1, 1, False)
