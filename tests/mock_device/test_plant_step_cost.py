"""Step cost of the plant on the flat scenario (printed, not asserted: CI machines vary)."""

import time

from mock_device.plant import ArcState, Plant, load_scenario

from .plant_helpers import DT_S, fire, goto_xy


def test_step_cost_is_printed_for_a_cut_on_the_flat_scenario() -> None:
    """A 2 s cut with the arc on, the gantry moving and Z jogged every step: µs per step."""
    plant = Plant(load_scenario("flat_clean"), seed=1)
    goto_xy(plant, 50.0, 50.0)
    fire(plant)
    plant.load_default_program()
    steps = 2000
    start = time.perf_counter()
    for _ in range(steps):
        plant.zaxis.jog(0.1 * (125.0 - plant.measured_voltage_v()))
        plant.step(DT_S)
        plant.inputs()
    elapsed = time.perf_counter() - start
    print(f"\nplant step cost: {elapsed / steps * 1e6:.1f} µs/step (flat_clean, cutting)")
    assert plant.arc_state is ArcState.TRANSFERRED
    assert plant.xy_speed_mm_s > 0.0
