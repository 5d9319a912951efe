"""The floating head: float switch, ohmic contact per surface condition, breakaway."""

import dataclasses

import pytest

from mock_device.plant import InputBit, Plant, Scenario
from mock_device.plant.scenario import FaultSpec, SurfaceCondition, SurfaceSpec

from .plant_helpers import DT_S, fire, goto_xy, quiet, run_until, set_height


def _with_surface(condition: SurfaceCondition) -> Scenario:
    base = quiet()
    return dataclasses.replace(base, surface=dataclasses.replace(base.surface, condition=condition))


def _probe_down(plant: Plant, until_compression_mm: float) -> list[tuple[float, float, int]]:
    """Creep down at 1 mm/s from 2 mm above the plate; return (gap, compression, inputs)."""
    goto_xy(plant, 100.0, 100.0)
    set_height(plant, 2.0)
    plant.zaxis.jog(-1.0)
    trace: list[tuple[float, float, int]] = []
    while plant.head.compression_mm < until_compression_mm:
        plant.step(DT_S)
        gap = plant.carriage_z_mm - plant.surface_z_mm
        trace.append((gap, plant.head.compression_mm, plant.inputs()))
    plant.zaxis.stop()
    return trace


def test_float_switch_closes_at_float_travel_after_contact_and_opens_with_hysteresis() -> None:
    """FLOAT closes once the head has slid float_travel_mm; it reopens 0.1 mm lower."""
    scenario = quiet("painted_plate")
    plant = Plant(scenario, seed=1)
    trace = _probe_down(plant, 2.0)
    travel = scenario.torch.float_travel_mm
    first = next(c for _, c, bits in trace if bits & InputBit.FLOAT)
    assert travel <= first <= travel + 0.002
    assert all(not bits & InputBit.FLOAT for _, c, bits in trace if c < travel)
    run_until(plant, lambda p: p.zaxis.is_idle, 1.0)
    plant.zaxis.jog(0.5)
    up: list[tuple[float, bool]] = []
    while plant.head.compression_mm > 1.0:
        plant.step(DT_S)
        up.append((plant.head.compression_mm, bool(plant.inputs() & InputBit.FLOAT)))
    plant.zaxis.stop()
    settled_open = next(c for i, (c, _) in enumerate(up) if all(not closed for _, closed in up[i:]))
    release = travel - scenario.torch.float_hysteresis_mm
    assert release - 0.01 <= settled_open < release
    assert all(closed for c, closed in up if c >= release + 0.01)


def test_float_switch_bounces_for_a_few_ms_after_it_changes() -> None:
    """Right after closing, the float contact chatters for at most float_bounce_ms."""
    bounce_seen = False
    for seed in range(6):
        plant = Plant(quiet("painted_plate"), seed=seed)
        trace = _probe_down(plant, 1.5 + 0.05)
        bits = [bool(b & InputBit.FLOAT) for _, _, b in trace]
        first = bits.index(True)
        tail = bits[first:]
        assert all(tail[3:]), "settled after the bounce window"
        bounce_seen |= not all(tail)
    assert bounce_seen


def test_ohmic_contact_on_clean_plate_only_when_touching_and_enabled() -> None:
    """Clean plate: OHMIC exactly when the tip touches and sensing is on."""
    plant = Plant(_with_surface("clean"), seed=2)
    plant.set_ohmic_sense(True)
    trace = _probe_down(plant, 0.3)
    for gap, _, bits in trace:
        assert bool(bits & InputBit.OHMIC) == (gap <= 0.0)
    plant.set_ohmic_sense(False)
    plant.step(DT_S)
    assert plant.head.touching
    assert not plant.inputs() & InputBit.OHMIC


def test_painted_plate_never_shows_ohmic_contact_but_the_float_works() -> None:
    """Painted plate: no OHMIC however deep the torch presses; FLOAT still closes."""
    plant = Plant(quiet("painted_plate"), seed=3)
    plant.set_ohmic_sense(True)
    trace = _probe_down(plant, 2.0)
    assert not any(bits & InputBit.OHMIC for _, _, bits in trace)
    assert trace[-1][2] & InputBit.FLOAT


def test_rusty_plate_contact_chatters_while_touching() -> None:
    """Rusty plate: while touching, OHMIC is seen on about the configured share of samples."""
    scenario = _with_surface("rusty")
    plant = Plant(scenario, seed=4)
    plant.set_ohmic_sense(True)
    goto_xy(plant, 100.0, 100.0)
    set_height(plant, -0.5)
    seen = []
    for _ in range(2000):
        plant.step(DT_S)
        seen.append(bool(plant.inputs() & InputBit.OHMIC))
    share = sum(seen) / len(seen)
    assert share == pytest.approx(scenario.surface.rusty_contact_probability, abs=0.05)


def test_wet_plate_shows_contact_before_touch() -> None:
    """Wet plate: the water film gives (chattering) contact up to wet_film_mm above the plate."""
    scenario = _with_surface("wet")
    plant = Plant(scenario, seed=5)
    plant.set_ohmic_sense(True)
    trace = _probe_down(plant, 0.1)
    film = scenario.surface.wet_film_mm
    early = [gap for gap, _, bits in trace if bits & InputBit.OHMIC and gap > 0.0]
    assert early, "contact seen before the tip touched"
    assert max(early) <= film
    assert all(bits & InputBit.OHMIC for gap, _, bits in trace if gap <= 0.0)


def test_breakaway_latches_until_reset_with_the_head_back_in_range() -> None:
    """Pressing past max_float_mm trips BREAKAWAY; it stays until reset, and only in range."""
    scenario = _with_surface("clean")
    plant = Plant(scenario, seed=6)
    trace = _probe_down(plant, scenario.torch.max_float_mm + 0.2)
    assert trace[-1][2] & InputBit.BREAKAWAY
    assert not any(bits & InputBit.BREAKAWAY for _, c, bits in trace if c < 6.0)
    run_until(plant, lambda p: p.zaxis.is_idle, 1.0)
    assert plant.reset_breakaway(), "still compressed beyond max float: stays tripped"
    set_height(plant, 5.0)
    assert plant.inputs() & InputBit.BREAKAWAY, "latched after the head came back"
    assert not plant.reset_breakaway()
    plant.step(DT_S)
    assert not plant.inputs() & InputBit.BREAKAWAY


def test_injected_breakaway_trips_at_the_set_time_after_transfer() -> None:
    """faults.breakaway_at_s trips the breakaway mid-cut without any contact."""
    scenario = dataclasses.replace(quiet(), faults=FaultSpec(breakaway_at_s=0.25))
    plant = Plant(scenario, seed=7)
    t_transfer = fire(plant)
    t_trip = run_until(plant, lambda p: bool(p.inputs() & InputBit.BREAKAWAY), 1.0)
    assert t_trip - t_transfer == pytest.approx(0.25, abs=1.5 * DT_S)
    assert plant.true_height_mm > 0.0
    assert not plant.reset_breakaway()


def test_surface_spec_rejects_unknown_condition_at_construction_of_a_scenario() -> None:
    """The surface condition is a closed set (a typo cannot silently mean 'clean')."""
    from mock_device.plant import ScenarioError, scenario_from_dict

    with pytest.raises(ScenarioError, match=r"surface\.condition"):
        scenario_from_dict({"surface": {"condition": "greasy"}})
    assert SurfaceSpec().condition == "clean"
