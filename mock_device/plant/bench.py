"""Plant step cost: ``python -m mock_device.plant.bench [scenario ...]``.

Fires the torch at cut height, runs the scenario's default program with a simple
proportional Z follower (a THC-like ``jog`` every step, as the board does) and prints the
mean wall time per ``Plant.step`` (best of 5 runs of 5000 steps).
"""

import sys
import time

from .arc import ArcState
from .plant import DEFAULT_DT_S, Plant
from .scenario import load_scenario


def _prepare(name: str) -> Plant:
    plant = Plant(load_scenario(name), seed=1)
    program = plant.scenario.default_program
    plant.gantry.feed_program([line for line in program[:2] if "G1" not in line])
    while not plant.gantry.idle:
        plant.step(DEFAULT_DT_S)
    plant.zaxis.move_to(plant.surface_z_mm + plant.scenario.material.cut_height_mm, 60.0)
    plant.set_torch(True)
    for _ in range(1000):
        plant.step(DEFAULT_DT_S)
    plant.load_default_program()
    return plant


def step_cost_us(name: str, steps: int = 5000, repeats: int = 5) -> float:
    """Best-of-``repeats`` mean µs per step while cutting the scenario's program."""
    best = float("inf")
    for _ in range(repeats):
        plant = _prepare(name)
        target_v = plant.scenario.material.cut_voltage_v
        start = time.perf_counter()
        for _ in range(steps):
            plant.zaxis.jog(0.5 * (target_v - plant.measured_voltage_v()))
            plant.step(DEFAULT_DT_S)
            plant.inputs()
        best = min(best, (time.perf_counter() - start) / steps * 1e6)
        if plant.arc_state is not ArcState.TRANSFERRED:
            print(f"warning: {name}: arc not transferred at the end of the run")
    return best


def main(argv: list[str]) -> None:
    """Print the step cost of each named scenario (default: flat_clean)."""
    for name in argv or ["flat_clean"]:
        print(f"{name}: {step_cost_us(name):.1f} us/step")


if __name__ == "__main__":
    main(sys.argv[1:])
