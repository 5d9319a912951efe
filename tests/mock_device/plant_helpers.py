"""Helpers shared by the plant tests: quiet scenarios and small driving routines."""

import dataclasses
from collections.abc import Callable

from mock_device.plant import ArcState, Plant, Scenario, load_scenario
from mock_device.plant.scenario import NoiseSpec

DT_S = 0.001


def quiet(name: str = "flat_clean") -> Scenario:
    """A bundled scenario with the measurement noise switched off."""
    return dataclasses.replace(load_scenario(name), noise=NoiseSpec(sigma_v=0.0))


def run_until(plant: Plant, done: Callable[[Plant], bool], timeout_s: float) -> float:
    """Step until ``done(plant)``; return the simulated time; fail after ``timeout_s``."""
    end = plant.t_s + timeout_s
    while not done(plant):
        if plant.t_s >= end:
            raise AssertionError(f"condition not reached within {timeout_s} s")
        plant.step(DT_S)
    return plant.t_s


def goto_xy(plant: Plant, x_mm: float, y_mm: float) -> None:
    """Rapid the gantry to (x, y) and wait until it stands still there."""
    plant.gantry.feed_line(f"G0 X{x_mm} Y{y_mm}")
    run_until(plant, lambda p: p.gantry.idle, 60.0)


def set_height(plant: Plant, height_mm: float, feed_mm_s: float = 60.0) -> None:
    """Move Z so the tip is ``height_mm`` above the plate under it; wait until there."""
    plant.zaxis.move_to(plant.surface_z_mm + height_mm, feed_mm_s)
    run_until(plant, lambda p: p.zaxis.is_idle, 10.0)


def fire(plant: Plant, height_mm: float | None = None) -> float:
    """Set the cut height (material's by default), torch on, wait for transfer; return t."""
    h = plant.scenario.material.cut_height_mm if height_mm is None else height_mm
    set_height(plant, h)
    plant.set_torch(True)
    return run_until(plant, lambda p: p.arc_state is ArcState.TRANSFERRED, 1.0)
