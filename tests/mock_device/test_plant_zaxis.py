"""The Z axis: trapezoidal moves, jogs, stops and soft limits."""

import itertools

import pytest

from mock_device.plant import InputBit, Plant, ZAxis, ZState

from .plant_helpers import DT_S, quiet

VMAX = 60.0
AMAX = 650.0
STEP_MM = 0.005


def _axis(position_mm: float = 50.0) -> ZAxis:
    return ZAxis(max_velocity_mm_s=VMAX, accel_mm_s2=AMAX, position_mm=position_mm)


def _run(axis: ZAxis, max_s: float) -> list[tuple[float, float]]:
    """Step until idle; return (position, velocity) after every step."""
    out = []
    for _ in range(round(max_s / DT_S)):
        axis.step(DT_S)
        out.append((axis.position_mm, axis.velocity_mm_s))
        if axis.is_idle:
            break
    return out


def _check_limits(trace: list[tuple[float, float]], start_v: float = 0.0) -> None:
    velocities = [start_v] + [v for _, v in trace]
    assert max(abs(v) for v in velocities) <= VMAX + 1e-9
    for a, b in itertools.pairwise(velocities):
        assert abs(b - a) <= AMAX * DT_S * (1 + 1e-9)


@pytest.mark.parametrize(
    ("start", "target", "feed"),
    [(50.0, 90.0, 60.0), (50.0, 10.0, 60.0), (50.0, 50.3, 60.0), (20.0, 70.0, 25.0)],
)
def test_move_reaches_target_without_overshoot_within_vmax_and_amax(
    start: float, target: float, feed: float
) -> None:
    """move_to lands exactly on target, never beyond it by a step, never over vmax or amax."""
    axis = _axis(start)
    axis.move_to(target, feed)
    trace = _run(axis, 5.0)
    assert axis.state is ZState.IDLE
    assert axis.position_mm == pytest.approx(target, abs=1e-9)
    assert axis.velocity_mm_s == 0.0
    direction = 1.0 if target > start else -1.0
    assert max(direction * (p - target) for p, _ in trace) <= STEP_MM
    _check_limits(trace)
    assert max(abs(v) for _, v in trace) <= feed + 1e-9
    if abs(target - start) > 10.0:
        assert max(abs(v) for _, v in trace) == pytest.approx(min(feed, VMAX))


def test_move_time_matches_the_trapezoidal_profile() -> None:
    """A 40 mm move at 60 mm/s, 650 mm/s²: t = d/v + v/a, within two samples."""
    axis = _axis(10.0)
    axis.move_to(50.0, VMAX)
    trace = _run(axis, 5.0)
    expected_s = 40.0 / VMAX + VMAX / AMAX
    assert len(trace) * DT_S == pytest.approx(expected_s, abs=2 * DT_S)


def test_jog_ramps_to_velocity_and_stop_decelerates_at_the_accel_limit() -> None:
    """jog ramps at amax to the asked velocity (clamped to vmax); stop brakes at amax to idle."""
    axis = _axis(50.0)
    axis.jog(10.0)
    trace = [(axis.position_mm, axis.velocity_mm_s)]
    for _ in range(100):
        axis.step(DT_S)
        trace.append((axis.position_mm, axis.velocity_mm_s))
    assert axis.velocity_mm_s == pytest.approx(10.0)
    assert axis.state is ZState.JOGGING
    axis.stop()
    trace += _run(axis, 1.0)
    assert axis.is_idle
    assert axis.velocity_mm_s == 0.0
    _check_limits(trace)
    axis.jog(500.0)
    _check_limits(_run(axis, 0.5))
    assert axis.velocity_mm_s == pytest.approx(VMAX)


@pytest.mark.parametrize(("velocity", "limit"), [(-40.0, "min"), (40.0, "max")])
def test_jog_stops_at_the_soft_limit_and_raises_the_flag(velocity: float, limit: str) -> None:
    """A jog into a soft limit brakes in time, stops on it, never passes it, flags it."""
    axis = _axis(50.0)
    axis.jog(velocity)
    trace = []
    for _ in range(3000):
        axis.step(DT_S)
        trace.append((axis.position_mm, axis.velocity_mm_s))
    assert all(0.0 <= p <= 100.0 for p, _ in trace)
    expected = 0.0 if limit == "min" else 100.0
    assert axis.position_mm == pytest.approx(expected, abs=STEP_MM / 2)
    assert axis.limit_hit == limit
    _check_limits(trace)
    axis.jog(-velocity / 4)
    axis.step(DT_S)
    assert axis.limit_hit is None, "the flag clears as soon as the axis leaves the limit"


def test_move_beyond_a_soft_limit_is_clamped_to_it() -> None:
    """move_to below min_mm ends on min_mm with the min flag, not beyond."""
    axis = _axis(5.0)
    axis.move_to(-20.0, 30.0)
    trace = _run(axis, 2.0)
    assert min(p for p, _ in trace) >= 0.0
    assert axis.position_mm == 0.0
    assert axis.limit_hit == "min"


def test_plant_reports_z_limits_on_the_input_bits() -> None:
    """Z_LIMIT_MIN / Z_LIMIT_MAX input bits follow the axis' soft-limit switches."""
    plant = Plant(quiet(), seed=1)
    assert not plant.inputs() & (InputBit.Z_LIMIT_MIN | InputBit.Z_LIMIT_MAX)
    plant.zaxis.move_to(100.0, 60.0)
    plant.advance(2.0)
    assert plant.inputs() & InputBit.Z_LIMIT_MAX
    plant.zaxis.move_to(0.0, 60.0)
    plant.advance(3.0)
    bits = plant.inputs()
    assert bits & InputBit.Z_LIMIT_MIN
    assert not bits & InputBit.Z_LIMIT_MAX


def test_invalid_axis_commands_are_rejected() -> None:
    """A non-positive feed or inverted limits raise instead of doing something odd."""
    axis = _axis()
    with pytest.raises(ValueError, match="feed_mm_s"):
        axis.move_to(10.0, 0.0)
    with pytest.raises(ValueError, match="max_mm"):
        ZAxis(min_mm=10.0, max_mm=5.0)


def test_a_new_target_behind_a_fast_axis_brakes_reverses_and_lands() -> None:
    """Retargeting behind the motion: brake at amax, come back, land without jumps."""
    axis = _axis(20.0)
    axis.jog(VMAX)
    trace = [(axis.position_mm, axis.velocity_mm_s)]
    for _ in range(200):
        axis.step(DT_S)
        trace.append((axis.position_mm, axis.velocity_mm_s))
    target = axis.position_mm - 1.0
    axis.move_to(target, VMAX)
    trace += _run(axis, 3.0)
    assert axis.position_mm == pytest.approx(target)
    assert max(p for p, _ in trace) > target + 2.0, "it had to brake past the new target"
    _check_limits(trace)
    for (p0, v0), (p1, _) in itertools.pairwise(trace):
        assert abs(p1 - p0) <= (abs(v0) + AMAX * DT_S) * DT_S + 1e-12, "no position jumps"
