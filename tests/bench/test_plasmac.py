"""LinuxCNC's plasmac in closed loop with our plant: it is hosted, it holds height, it is
driven the way LinuxCNC drives it (the real-runtime proof is test_plasmac_halrun.py)."""

from __future__ import annotations

import pytest

from dthc_tools.bench.cuts import CutPlan, plan_cuts
from dthc_tools.bench.plasmac.component import PlasmacComponent
from dthc_tools.bench.plasmac.fetch import PlasmacUnavailable, Provisioned, provision
from dthc_tools.bench.plasmac.host import PlasmacHost, PlasmacSettings, run_plasmac
from dthc_tools.bench.plasmac.motion import OFFSET_AV_RATIO, Debounce, OffsetPlanner
from mock_device.plant import Plant, load_scenario


@pytest.fixture(scope="module")
def plasmac() -> Provisioned:
    """The component from Debian's linuxcnc-uspace (fetched with apt into the cache once)."""
    try:
        return provision()
    except PlasmacUnavailable as exc:
        pytest.skip(f"LinuxCNC's plasmac cannot be fetched here: {exc}")


def _plans(scenario: str, path_mm: float) -> tuple[CutPlan, ...]:
    return plan_cuts(load_scenario(scenario).default_program, max_path_mm=path_mm)


def test_the_component_registers_its_pins_with_their_defaults(plasmac: Provisioned) -> None:
    """Through the shim: 176 pins, the component's own defaults, outputs marked as such."""
    with PlasmacComponent(plasmac.component, plasmac.shim) as comp:
        assert len(comp.pins) > 150
        assert comp.pin("max-offset").value == 5
        assert comp.pin("target-samples").value == 6
        assert comp.pin("voidlock-slope").value == 500
        assert comp.pin("z-offset-counts").output
        assert not comp.pin("arc-voltage-in").output


def test_each_copy_has_its_own_state(plasmac: Provisioned) -> None:
    """plasmac keeps its state in globals: a second copy starts idle while the first cuts."""
    plant = Plant("flat_clean", seed=1)
    with PlasmacComponent(plasmac.component, plasmac.shim) as first:
        host = PlasmacHost(plant, first, PlasmacSettings())
        plan = _plans("flat_clean", 100)[0]
        host.running = True
        host.cutting_start = True
        plant.gantry.feed_line("G21 G90")
        plant.gantry.feed_line(plan.approach)
        assert host.run_until(lambda: host.state >= 2, 5.0)  # probing down
        with PlasmacComponent(plasmac.component, plasmac.shim) as second:
            second.pin("machine-is-on").value = 1
            second.run(10)
            assert second.pin("state-out").value == 0
        assert host.state >= 2


def test_on_a_flat_plate_plasmac_holds_the_cut_height(plasmac: Provisioned) -> None:
    """flat_clean: the cut completes, no pause, the height stays within 0.15 mm."""
    result = run_plasmac(plasmac, "flat_clean", 1, _plans("flat_clean", 250), PlasmacSettings())
    d = result.as_dict()
    assert d["cuts_completed"] == "1/1"
    assert d["pauses"] == 0
    assert isinstance(d["max_mm"], float)
    assert d["max_mm"] < 0.15
    assert d["dives"] == 0
    assert result.cutting_s > 2.0


def test_on_a_warped_sheet_the_thc_moves_z_and_disabling_it_costs_height(
    plasmac: Provisioned,
) -> None:
    """warped_sheet: plasmac's THC follows the plate (Z moves millimetres); with its THC
    disabled (``thc-enable`` 0) Z does not move and the error is several times larger."""
    plans = _plans("warped_sheet", 400)
    runs = {}
    for enabled in (True, False):
        plant = Plant("warped_sheet", seed=1)
        with PlasmacComponent(plasmac.component, plasmac.shim) as comp:
            host = PlasmacHost(
                plant, comp, PlasmacSettings(use_auto_volts=False, thc_enable=enabled)
            )
            plant.gantry.feed_line("G21 G90")
            for plan in plans:
                assert host.cut(plan, slow_percent=50.0) is None
            runs[enabled] = (host.thc_moved_mm, plant.truth.summary().cuts)
    moved_on, cuts_on = runs[True]
    moved_off, cuts_off = runs[False]
    assert moved_on > 1.0
    assert moved_off < 0.05  # the end of the move to cut height, nothing more
    rms_on = max(c.height_rms_error_mm for c in cuts_on)
    rms_off = max(c.height_rms_error_mm for c in cuts_off)
    assert rms_on < 0.35
    assert rms_off > 2 * rms_on


def test_auto_volts_take_the_target_from_the_arc(plasmac: Provisioned) -> None:
    """use-auto-volts: the target is the mean of 6 samples after the delay, not cut-volts."""
    plant = Plant("flat_clean", seed=2)
    with PlasmacComponent(plasmac.component, plasmac.shim) as comp:
        host = PlasmacHost(plant, comp, PlasmacSettings(use_auto_volts=True))
        plant.gantry.feed_line("G21 G90")
        plan = _plans("flat_clean", 150)[0]
        host.running = True
        plant.gantry.feed_line(plan.approach)
        host.run_until(lambda: plant.gantry.idle, 10.0)
        host.cutting_start = True
        for line in plan.lines:
            plant.gantry.feed_line(line)
        target = comp.pin("target-volts")
        assert host.run_until(lambda: target.value != 0.0, 10.0)
        material_v = plant.scenario.material.cut_voltage_v
        assert target.value != material_v
        assert abs(target.value - material_v) < 3.0


def test_the_offset_planner_lags_two_periods_and_keeps_its_limits() -> None:
    """LinuxCNC's external offsets: nothing for 2 periods, at most 0.9 x the axis' speed,
    lands on the target without overshoot."""
    planner = OffsetPlanner(60.0, 650.0, 0.001)
    planner.update(-10.0)
    planner.update(-10.0)
    assert planner.position_mm == 0.0
    fastest = 0.0
    lowest = 0.0
    for _ in range(2000):
        planner.update(-10.0)
        fastest = max(fastest, abs(planner.velocity_mm_s))
        lowest = min(lowest, planner.position_mm)
    assert planner.position_mm == pytest.approx(-10.0, abs=1e-9)
    assert fastest == pytest.approx(60.0 * OFFSET_AV_RATIO)
    assert lowest >= -10.0 - 1e-6


def test_dbounce_needs_five_steady_periods() -> None:
    """QtPlasmaC's dbounce: a 2-period bounce does not pass; 5 steady periods do."""
    db = Debounce(5)
    assert [db.update(v) for v in (True, True, False, False)] == [False] * 4
    assert [db.update(True) for _ in range(5)] == [False] * 4 + [True]
    assert db.update(False)  # one low period does not drop it


def test_the_flexing_sheet_lifts_under_a_held_torch() -> None:
    """flexing_sheet: 1.5 s after the first transfer the sheet lifts (up to 1 mm, 2.5 s
    period) wherever the torch is; before it, and without an arc, it stays put."""
    plant = Plant("flexing_sheet", seed=1)
    base = plant.surface_z_mm
    plant.zaxis.position_mm = base + 1.0
    plant.set_torch(True)
    plant.advance(1.0)
    assert plant.arc.transfers == 1
    assert plant.surface_z_mm == base
    plant.advance(1.7)  # 0.5 s into the flex (transfer after 0.15-0.5 s): lifted
    lifted = plant.surface_z_mm - base
    assert 0.2 < lifted <= 1.0
    assert plant.true_height_mm == pytest.approx(1.0 - lifted, abs=1e-9)
