"""The arc model: voltage vs height, start transient, arc OK, arc loss, slow-down, kerfs."""

import dataclasses
import itertools
import statistics

import pytest

from mock_device.plant import ArcEnd, ArcState, InputBit, Plant, load_scenario
from mock_device.plant.scenario import VoidSpec

from .plant_helpers import DT_S, fire, goto_xy, quiet, run_until, set_height


def test_voltage_rises_with_height_at_the_scenario_slope() -> None:
    """At standstill, v = v_cut + full-stop rise + slope * (h - cut height), noise averaging out."""
    scenario = load_scenario("flat_clean")
    plant = Plant(scenario, seed=3)
    goto_xy(plant, 100.0, 100.0)
    fire(plant)
    plant.advance(1.5)  # let the start transient die out
    true_v: dict[float, float] = {}
    mean_measured: dict[float, float] = {}
    for h in (1.5, 2.5, 3.5, 4.5):
        set_height(plant, h, feed_mm_s=5.0)
        plant.advance(0.3)
        samples = []
        for _ in range(400):
            plant.step(DT_S)
            samples.append(plant.measured_voltage_v())
        true_v[h] = plant.arc_voltage_v
        mean_measured[h] = statistics.fmean(samples)
    material = scenario.material
    expected_at_cut = material.cut_voltage_v + scenario.arc.rise_v
    assert true_v[1.5] == pytest.approx(expected_at_cut, abs=0.01)
    slope = (true_v[4.5] - true_v[1.5]) / 3.0
    assert slope == pytest.approx(material.slope_v_per_mm, abs=0.01)
    measured_slope = (mean_measured[4.5] - mean_measured[1.5]) / 3.0
    assert measured_slope == pytest.approx(material.slope_v_per_mm, abs=0.1)


def test_start_transient_overshoots_then_settles_within_settle_time() -> None:
    """Right after transfer the voltage overshoots by overshoot_v; 95 % is gone at settle_s."""
    scenario = quiet()
    plant = Plant(scenario, seed=4)
    goto_xy(plant, 100.0, 100.0)
    t_transfer = fire(plant)
    steady = scenario.material.cut_voltage_v + scenario.arc.rise_v
    overshoot = scenario.arc.overshoot_v
    assert plant.arc_voltage_v - steady == pytest.approx(overshoot, rel=0.05)
    run_until(plant, lambda p: p.t_s >= t_transfer + scenario.arc.settle_s, 2.0)
    excess = plant.arc_voltage_v - steady
    assert 0.0 < excess <= 0.05 * overshoot + 0.01
    plant.advance(scenario.arc.settle_s)
    assert plant.arc_voltage_v - steady < 0.005 * overshoot


@pytest.mark.parametrize("seed", range(12))
def test_pilot_transfer_and_arc_ok_timing_follow_the_scenario_ranges(seed: int) -> None:
    """Transfer 0.15-0.5 s after torch on; arc OK closes 5-15 ms later, bouncing ≤ 3 ms."""
    plant = Plant(quiet(), seed=seed)
    goto_xy(plant, 100.0, 100.0)
    set_height(plant, 1.5)
    plant.set_torch(True)
    t_on = plant.t_s
    t_transfer = run_until(plant, lambda p: p.arc_state is ArcState.TRANSFERRED, 1.0)
    assert 0.15 <= t_transfer - t_on <= 0.5 + DT_S
    levels: list[tuple[float, bool]] = []
    for _ in range(40):
        plant.step(DT_S)
        levels.append((plant.t_s, bool(plant.inputs() & InputBit.ARC_OK)))
    first_close = next(t for t, ok in levels if ok)
    last_change = max(
        t for (t, ok), (_, prev) in zip(levels[1:], levels, strict=False) if ok != prev
    )
    delay_ms = (first_close - t_transfer) * 1000.0
    assert 5.0 - 1.0 <= delay_ms <= 15.0 + 1.0
    assert delay_ms == pytest.approx(plant.arc.arc_ok_delay_s * 1000.0, abs=1.0 + 1e-6)
    assert (last_change - first_close) * 1000.0 <= 3.0 + 1.0
    assert levels[-1][1]


def test_arc_ok_bounce_shows_up_for_some_seeds() -> None:
    """With a bounce window of up to 3 ms some starts chatter: ARC_OK reopens once closed."""
    bounced = 0
    for seed in range(20):
        plant = Plant(quiet(), seed=seed)
        fire(plant)
        seen: list[bool] = []
        for _ in range(25):
            plant.step(DT_S)
            seen.append(plant.arc_ok)
        first = seen.index(True)
        if not all(seen[first:]):
            bounced += 1
    assert bounced >= 3


def test_arc_is_lost_above_the_standoff_limit_and_torch_off_gives_zero_volts() -> None:
    """Raising the torch past lose_above_height_mm loses the arc: open-circuit, arc OK opens."""
    scenario = quiet()
    plant = Plant(scenario, seed=5)
    goto_xy(plant, 100.0, 100.0)
    fire(plant)
    plant.advance(0.2)
    assert plant.arc_ok
    plant.zaxis.jog(5.0)
    run_until(plant, lambda p: p.arc_state is not ArcState.TRANSFERRED, 2.0)
    limit = scenario.arc.lose_above_height_mm
    assert limit < plant.true_height_mm <= limit + 0.01
    assert plant.arc_state is ArcState.LOST
    assert plant.arc.end_reason is ArcEnd.TOO_HIGH
    plant.zaxis.stop()
    plant.advance(0.005)
    assert not plant.arc_ok
    assert plant.measured_voltage_v() == pytest.approx(scenario.arc.open_circuit_v)
    plant.zaxis.move_to(plant.carriage_z_mm - 4.0, 20.0)
    plant.advance(0.5)
    assert plant.arc_state is ArcState.LOST, "a lost arc does not re-fire by itself"
    plant.set_torch(False)
    plant.step(DT_S)
    assert plant.measured_voltage_v() == 0.0
    assert plant.arc_state is ArcState.OFF


def test_torch_off_drops_the_voltage_within_one_sample() -> None:
    """Switching the torch off mid-cut: 0 V on the very next sample, arc OK opens."""
    plant = Plant(load_scenario("flat_clean"), seed=6)
    fire(plant)
    plant.advance(0.1)
    assert plant.measured_voltage_v() > 100.0
    plant.set_torch(False)
    plant.step(DT_S)
    assert plant.measured_voltage_v() == 0.0
    assert plant.arc_voltage_v == 0.0
    assert plant.arc.end_reason is ArcEnd.TORCH_OFF
    plant.advance(0.005)
    assert not plant.arc_ok


def test_pilot_that_cannot_transfer_times_out() -> None:
    """Fired 10 mm above the plate the pilot reads open-circuit, then the cutter gives up."""
    scenario = quiet()
    plant = Plant(scenario, seed=7)
    goto_xy(plant, 100.0, 100.0)
    set_height(plant, 10.0)
    plant.set_torch(True)
    t_on = plant.t_s
    plant.advance(1.0)
    assert plant.arc_state is ArcState.PILOT
    assert plant.measured_voltage_v() == pytest.approx(scenario.arc.open_circuit_v)
    t_end = run_until(plant, lambda p: p.arc_state is ArcState.NO_TRANSFER, 3.0)
    assert t_end - t_on == pytest.approx(scenario.arc.pilot_timeout_s, abs=2 * DT_S)
    assert plant.arc.end_reason is ArcEnd.NO_TRANSFER
    plant.step(DT_S)
    assert plant.measured_voltage_v() == 0.0
    assert not plant.arc_ok


def test_arc_is_lost_over_a_wide_void_but_survives_a_narrow_slot() -> None:
    """A 3 mm slot only raises the voltage; a 20 mm void kills the arc after void_lose_ms."""
    base = quiet()
    scenario = dataclasses.replace(
        base,
        voids=(VoidSpec(150.0, 0.0, 153.0, 300.0), VoidSpec(250.0, 0.0, 270.0, 300.0)),
    )
    plant = Plant(scenario, seed=8)
    goto_xy(plant, 100.0, 100.0)
    fire(plant)
    plant.gantry.feed_line("G1 X400 Y100 F5500")
    run_until(plant, lambda p: p.gantry.x_mm > 160.0, 5.0)
    assert plant.arc_state is ArcState.TRANSFERRED
    entered = run_until(plant, lambda p: p.gantry.x_mm >= 250.0, 5.0)
    lost = run_until(plant, lambda p: p.arc_state is not ArcState.TRANSFERRED, 1.0)
    assert plant.arc.end_reason is ArcEnd.VOID
    assert (lost - entered) * 1000.0 == pytest.approx(scenario.arc.void_lose_ms, abs=1.5)


def test_corner_slowdown_raises_the_voltage() -> None:
    """At a 90° corner the gantry slows down and the arc voltage at fixed height rises."""
    scenario = quiet()
    plant = Plant(scenario, seed=9)
    goto_xy(plant, 50.0, 50.0)
    fire(plant)
    plant.advance(1.0)
    plant.gantry.feed_program(["G1 X250 Y50 F5500", "G1 X250 Y250", "G1 X50 Y250"])
    trace: list[tuple[float, float, float, float]] = []
    while not plant.gantry.idle:
        plant.step(DT_S)
        g = plant.gantry
        trace.append((g.x_mm, g.y_mm, plant.xy_speed_mm_s, plant.arc_voltage_v))
    v_cut = scenario.material.cut_voltage_v
    mid = [v for x, y, _, v in trace if 140.0 < x < 160.0 and y == 50.0]
    assert max(mid) == pytest.approx(v_cut, abs=0.05), "full feed: no rise"
    for cx, cy in ((250.0, 50.0), (250.0, 250.0)):
        near = [(s, v) for x, y, s, v in trace if abs(x - cx) < 10.0 and abs(y - cy) < 10.0]
        assert min(s for s, _ in near) < 20.0
        assert max(v for _, v in near) - v_cut > 3.0


def test_kerf_crossing_produces_a_fast_voltage_spike() -> None:
    """Crossing an old kerf raises the voltage at several hundred V/s (≥ 300 V/s)."""
    scenario = quiet("kerf_crossing")
    plant = Plant(scenario, seed=10)
    goto_xy(plant, 50.0, 100.0)
    fire(plant)
    plant.advance(1.0)
    plant.gantry.feed_line("G1 X200 Y100 F5500")
    volts: list[float] = []
    xs: list[float] = []
    while not plant.gantry.idle:
        plant.step(DT_S)
        volts.append(plant.arc_voltage_v)
        xs.append(plant.gantry.x_mm)
    slopes = [(b - a) / DT_S for a, b in itertools.pairwise(volts)]
    around = [s for s, x in zip(slopes, xs[1:], strict=True) if 145.0 < x < 160.0]
    assert max(around) >= 300.0
    away = [s for s, x in zip(slopes, xs[1:], strict=True) if 100.0 < x < 140.0]
    assert max(abs(s) for s in away) < 1.0
    peak = max(v for v, x in zip(volts, xs, strict=True) if 145.0 < x < 160.0)
    assert peak - scenario.material.cut_voltage_v > 5.0


def test_arc_lost_midcut_scenario_loses_the_arc_at_the_set_time() -> None:
    """faults.arc_lost_at_s after the first transfer the arc goes, mid-cut."""
    scenario = load_scenario("arc_lost_midcut")
    assert scenario.faults.arc_lost_at_s is not None
    plant = Plant(scenario, seed=11)
    goto_xy(plant, 50.0, 100.0)
    t_transfer = fire(plant)
    plant.gantry.feed_line("G1 X450 Y100 F5500")
    t_lost = run_until(plant, lambda p: p.arc_state is not ArcState.TRANSFERRED, 5.0)
    assert t_lost - t_transfer == pytest.approx(scenario.faults.arc_lost_at_s, abs=1.5 * DT_S)
    assert plant.arc.end_reason is ArcEnd.INJECTED
    assert plant.xy_speed_mm_s > 0.0, "lost in the middle of the cut"


def test_arc_transferred_above_the_standoff_limit_survives_until_brought_into_range() -> None:
    """A pilot transferring at 7.8 mm keeps its arc there; once below 7 mm the limit applies."""
    base = quiet()
    scenario = dataclasses.replace(base, arc=dataclasses.replace(base.arc, overshoot_v=0.0))
    plant = Plant(scenario, seed=12)
    goto_xy(plant, 100.0, 100.0)
    fire(plant, 7.8)
    plant.advance(0.2)
    assert plant.arc_state is ArcState.TRANSFERRED
    set_height(plant, 1.5)
    plant.zaxis.jog(5.0)
    run_until(plant, lambda p: p.arc_state is not ArcState.TRANSFERRED, 2.0)
    assert plant.true_height_mm == pytest.approx(scenario.arc.lose_above_height_mm, abs=0.01)


def test_cutter_current_shifts_the_voltage_by_the_configured_volts_per_amp() -> None:
    """set_current_a moves the arc voltage by current_v_per_a x (I - nominal)."""
    base = quiet()
    scenario = dataclasses.replace(base, arc=dataclasses.replace(base.arc, current_v_per_a=-0.2))
    plant = Plant(scenario, seed=13)
    fire(plant)
    plant.advance(1.5)
    before = plant.arc_voltage_v
    plant.set_current_a(scenario.arc.nominal_current_a + 20.0)
    plant.step(DT_S)
    assert plant.arc_voltage_v - before == pytest.approx(-4.0, abs=1e-6)


@pytest.mark.parametrize(
    ("feed_mm_min", "rise_fraction"),
    [(5500.0, 0.0), (2750.0, 0.5), (7000.0, 0.0)],
    ids=["material_feed", "half_feed", "faster_than_material"],
)
def test_a_slower_programmed_feed_raises_the_voltage_as_a_slow_down_does(
    feed_mm_min: float, rise_fraction: float
) -> None:
    """The rise is measured against the material's cut feed, not the programmed feed: a
    hole or velocity reduction programmed at half the cut feed settles half the full-stop
    rise above the cut voltage; the cut feed or faster gives none."""
    scenario = quiet()
    assert scenario.material.cut_feed_mm_min == 5500.0
    plant = Plant(scenario, seed=9)
    goto_xy(plant, 50.0, 50.0)
    fire(plant)
    plant.advance(1.0)
    plant.gantry.feed_line(f"G1 X1000 Y50 F{feed_mm_min:g}")
    run_until(plant, lambda p: p.gantry.x_mm > 400.0, 30.0)
    assert plant.xy_speed_mm_s == pytest.approx(feed_mm_min / 60.0, rel=1e-6)
    rise = plant.arc_voltage_v - scenario.material.cut_voltage_v
    assert rise == pytest.approx(rise_fraction * scenario.arc.rise_v, abs=0.05)
