"""The XY gantry: G-code parsing, junction slow-down, look-ahead, arcs, feed hold."""

import itertools
import math

import pytest

from mock_device.plant import Gantry, GcodeError

from .plant_helpers import DT_S

ACCEL = 1500.0


def _run(gantry: Gantry, max_s: float = 60.0) -> list[tuple[float, float, float, float]]:
    """Step until idle; return (x, y, speed, requested feed) after every step."""
    out = []
    for _ in range(round(max_s / DT_S)):
        gantry.step(DT_S)
        out.append((gantry.x_mm, gantry.y_mm, gantry.speed_mm_s, gantry.requested_feed_mm_s))
        if gantry.idle:
            return out
    raise AssertionError("gantry did not finish")


def _assert_accel_limited(trace: list[tuple[float, float, float, float]]) -> None:
    speeds = [0.0] + [s for _, _, s, _ in trace]
    for a, b in itertools.pairwise(speeds):
        assert abs(b - a) <= ACCEL * DT_S * (1 + 1e-9)


def test_square_slows_at_each_corner_and_reaches_full_feed_on_the_sides() -> None:
    """A 200 mm square at 3000 mm/min: ~junction speed at corners, 50 mm/s on the sides."""
    gantry = Gantry(accel_mm_s2=ACCEL, junction_deviation_mm=0.05)
    gantry.feed_program(["G90 G1 X200 Y0 F3000", "G1 X200 Y200", "G1 X0 Y200", "G1 X0 Y0"])
    trace = _run(gantry)
    _assert_accel_limited(trace)
    feed = 3000.0 / 60.0
    assert max(s for *_, s, _ in trace) <= feed + 1e-9
    junction = gantry.junction_speed_mm_s(1.0, 0.0, 0.0, 1.0)
    assert junction == pytest.approx(
        math.sqrt(ACCEL * 0.05 * (1 / math.sqrt(2)) / (1 - 1 / math.sqrt(2)))
    )
    for cx, cy in ((200.0, 0.0), (200.0, 200.0), (0.0, 200.0)):
        near = [s for x, y, s, _ in trace if math.hypot(x - cx, y - cy) < 5.0]
        assert min(near) <= junction + ACCEL * DT_S
        assert min(near) < 0.3 * feed
    for mx, my in ((100.0, 0.0), (200.0, 100.0), (100.0, 200.0), (0.0, 100.0)):
        mid = [s for x, y, s, _ in trace if math.hypot(x - mx, y - my) < 2.0]
        assert min(mid) == pytest.approx(feed)
    assert gantry.position_mm == (0.0, 0.0)


def test_collinear_segments_do_not_slow_at_the_joins() -> None:
    """A 200 mm line fed as 40 pieces of 5 mm runs at full feed across every join."""
    gantry = Gantry(accel_mm_s2=ACCEL)
    gantry.feed_program([f"G1 X{5 * i} Y0 F3000" for i in range(1, 41)])
    assert gantry.queue_len == 40
    trace = _run(gantry)
    _assert_accel_limited(trace)
    cruise = [s for x, _, s, _ in trace if 10.0 < x < 190.0]
    assert min(cruise) == pytest.approx(50.0)
    assert gantry.x_mm == pytest.approx(200.0)


def test_look_ahead_starts_braking_in_time_across_short_segments() -> None:
    """Short segments before a reversal: deceleration starts segments earlier, within amax."""
    gantry = Gantry(accel_mm_s2=ACCEL)
    lines = [f"G1 X{0.5 * i} Y0 F6000" for i in range(1, 201)] + ["G1 X0 Y0"]
    gantry.feed_program(lines)
    trace = _run(gantry)
    _assert_accel_limited(trace)
    at_turn = [s for x, _, s, _ in trace if x > 99.9]
    assert min(at_turn) < ACCEL * DT_S * 2, "a reversal comes to (almost) a stop"
    assert max(s for *_, s, _ in trace) == pytest.approx(100.0)


def test_requested_feed_is_the_programmed_feed_of_the_running_move() -> None:
    """requested_feed_mm_s is F of the move being run, the rapid rate for G0, 0 when idle."""
    gantry = Gantry(rapid_mm_min=12000.0)
    gantry.feed_program(["G0 X50", "G1 X100 F1200", "G1 X150 F2400"])
    trace = _run(gantry)
    feeds = {round(f, 6) for x, _, _, f in trace if x not in (50.0, 100.0, 150.0)}
    assert feeds >= {200.0, 20.0, 40.0}
    assert gantry.requested_feed_mm_s == 0.0
    assert gantry.idle


def test_arcs_are_chords_no_longer_than_half_a_mm_and_end_on_the_end_point() -> None:
    """G2 full circle and a G3 quarter: chords ≤ 0.5 mm on the circle, exact end points."""
    gantry = Gantry()
    gantry.feed_line("G1 X10 Y0 F3000")
    chords = gantry.feed_line("G2 X10 Y0 I10 J0")  # full circle about (20, 0), r = 10
    assert chords == math.ceil(2 * math.pi * 10 / 0.5)
    trace = _run(gantry)
    on_ring = [math.hypot(x - 20.0, y) for x, y, _, _ in trace if x > 10.0]
    assert len(on_ring) > 1000
    sagitta = 10.0 * (1 - math.cos(0.5 / 20.0))
    assert all(10.0 - sagitta - 1e-9 <= r <= 10.0 + 1e-9 for r in on_ring)
    assert max(y for _, y, _, _ in trace) == pytest.approx(10.0, abs=sagitta)
    assert gantry.position_mm == pytest.approx((10.0, 0.0))
    gantry.feed_line("G3 X20 Y10 I0 J10")  # quarter about (10, 10), counter-clockwise
    _run(gantry)
    assert gantry.position_mm == pytest.approx((20.0, 10.0))


def test_small_circle_speed_is_capped_by_centripetal_acceleration() -> None:
    """A 5 mm radius hole at 6000 mm/min runs at most sqrt(a·r), not at the full feed."""
    gantry = Gantry(accel_mm_s2=ACCEL)
    gantry.feed_line("G1 X5 Y0 F6000")
    gantry.feed_line("G3 X5 Y0 I-5 J0")
    trace = _run(gantry)
    on_circle = [s for x, y, s, _ in trace if math.hypot(x, y) > 4.9 and y != 0.0]
    assert max(on_circle) <= math.sqrt(ACCEL * 5.0) + 1e-9


def test_relative_and_inch_modes() -> None:
    """G91 moves are relative; G20 scales coordinates and feed by 25.4."""
    gantry = Gantry()
    gantry.feed_program(["G91", "G1 X10 Y5 F1000", "G1 X10 Y5"])
    _run(gantry)
    assert gantry.position_mm == pytest.approx((20.0, 10.0))
    gantry.feed_program(["G90 G20", "G1 X1 Y1 F10"])
    trace = _run(gantry)
    assert gantry.position_mm == pytest.approx((25.4, 25.4))
    assert max(f for *_, f in trace) == pytest.approx(254.0 / 60.0)


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("G1 X10", "no feed rate"),
        ("G1 X10 X20 F100", "given twice"),
        ("G2 X10 Y10 F100", "arc without I or J"),
        ("G2 X10 Y10 R5 F100", "R-form"),
        ("G1 X1O F100", "unparseable"),
        ("G18", "XY plane"),
    ],
)
def test_bad_lines_raise_and_change_nothing(line: str, reason: str) -> None:
    """A line the planner cannot run raises GcodeError naming why and queues nothing."""
    gantry = Gantry()
    with pytest.raises(GcodeError, match=reason):
        gantry.feed_line(line)
    assert gantry.idle
    assert gantry.feed_line("X5 Y5 ; comment (G0 modal by default)") == 1


def test_non_motion_words_are_ignored() -> None:
    """M, S, T, N, Z and comments do not move XY or raise."""
    gantry = Gantry()
    assert gantry.feed_line("N10 M3 S1 T2 (plasma on) Z5") == 0
    assert gantry.feed_line("G4 P0.5") == 0
    assert gantry.idle


def test_feed_hold_decelerates_to_a_stop_and_resume_finishes_the_move() -> None:
    """hold brakes at amax to standstill on the path; resume completes to the end point."""
    gantry = Gantry(accel_mm_s2=ACCEL)
    gantry.feed_line("G1 X300 Y0 F6000")
    for _ in range(1000):
        gantry.step(DT_S)
    assert gantry.speed_mm_s == pytest.approx(100.0)
    gantry.hold()
    speeds = [100.0]
    for _ in range(200):
        gantry.step(DT_S)
        speeds.append(gantry.speed_mm_s)
    assert gantry.speed_mm_s == 0.0
    assert not gantry.idle
    for a, b in itertools.pairwise(speeds):
        assert a - b <= ACCEL * DT_S * (1 + 1e-9)
    x_held = gantry.x_mm
    gantry.step(DT_S)
    assert gantry.x_mm == x_held
    gantry.resume()
    _run(gantry)
    assert gantry.position_mm == pytest.approx((300.0, 0.0))


def test_clear_aborts_the_program_where_the_gantry_stands() -> None:
    """clear drops every queued move; the next move starts from the current position."""
    gantry = Gantry()
    gantry.feed_program(["G1 X100 F3000", "G1 Y100"])
    for _ in range(500):
        gantry.step(DT_S)
    gantry.clear()
    assert gantry.idle
    x = gantry.x_mm
    gantry.feed_line("G91 G1 Y10")
    _run(gantry)
    assert gantry.position_mm == pytest.approx((x, 10.0))
