"""PlasmaC's height override: the cut height raised or lowered on the fly in 0.1 mm steps,
within half the cut height, as a change of the THC's target voltage; reset when the next
program starts. Every request answered; a refused one changes nothing."""

from __future__ import annotations

from typing import Any

import pytest

from dthc_bridge.controller.commands import CutParams
from dthc_bridge.service import ControllerService
from tests.daemon.test_material_requests import service_for

SLOPE = 7.5  # V/mm, ThcConfig.slope_v_per_mm


@pytest.fixture
async def service() -> ControllerService:
    service = await service_for(None)
    service.sequence.set_params(CutParams(cut_height_mm=1.5, cut_voltage_v=118.0))
    return service


async def test_steps_move_the_target_voltage_through_the_thc_slope(
    service: ControllerService,
) -> None:
    sequence = service.sequence
    sequence.base_v = 118.0  # a cut at height
    for _ in range(5):
        result = await service.execute_request("height_override", {"mm": 0.1})
        assert result.ok, result.error
    assert result.data["height_override_mm"] == 0.5
    assert sequence.thc.target_v == pytest.approx(118.0 + 0.5 * SLOPE)
    assert service.snapshot()["height_override_mm"] == 0.5
    result = await service.execute_request("height_override", {"mm": -0.3})
    assert result.data["height_override_mm"] == 0.2
    assert sequence.thc.target_v == pytest.approx(118.0 + 0.2 * SLOPE)
    assert (await service.execute_request("height_override", {"reset": True})).ok
    assert sequence.thc.target_v == pytest.approx(118.0)


async def test_the_next_cut_takes_the_override_and_the_next_program_drops_it(
    service: ControllerService,
) -> None:
    """Before a cut (no target yet) the override waits for the cut's own target: its fixed
    G200 V voltage plus the override's volts."""
    sequence = service.sequence
    await service.execute_request("height_override", {"mm": -0.4})
    assert sequence.thc.target_v is None
    assert sequence._override_v() == pytest.approx(-0.4 * SLOPE)
    assert (await service.execute_request("program_start", {})).ok
    assert sequence.height_override_mm == 0.0
    assert sequence._override_v() == 0.0


async def test_the_end_of_the_program_resets_the_override(service: ControllerService) -> None:
    sequence = service.sequence
    sequence.base_v = 118.0
    await service.execute_request("height_override", {"mm": 0.3})
    result = await service.execute_request("program_end", {})
    assert result.ok, result.error
    assert result.data == {"height_override_mm": 0.0}
    assert sequence.height_override_mm == 0.0
    assert sequence.thc.target_v == pytest.approx(118.0)


@pytest.mark.parametrize(
    ("args", "error"),
    [
        ({"mm": 0.05}, "height_override mm: 0.05 is not a step of 0.1 mm"),
        ({"mm": 2}, "height_override mm: 2 is more than 1 mm"),
        ({"mm": 0}, "height_override mm: 0 is not a step of 0.1 mm"),
        ({"mm": "up"}, "height_override mm: 'up' is not a number"),
        ({}, "height_override mm: required argument is missing"),
        ({"reset": False}, "height_override reset: False is not true"),
        ({"mm": 0.1, "reset": True}, "height_override mm: give a step or reset, not both"),
        ({"mm": 0.1, "by": 1}, "height_override by: unknown argument"),
    ],
)
async def test_a_bad_height_override_names_it_and_changes_nothing(
    service: ControllerService, args: dict[str, Any], error: str
) -> None:
    result = await service.execute_request("height_override", args)
    assert not result.ok
    assert error in result.error
    assert service.sequence.height_override_mm == 0.0


async def test_the_override_stays_within_half_the_cut_height(service: ControllerService) -> None:
    for _ in range(7):  # 0.7 mm: half of 1.5 is 0.75
        assert (await service.execute_request("height_override", {"mm": 0.1})).ok
    refused = await service.execute_request("height_override", {"mm": 0.1})
    assert refused.error == ("height_override mm: +0.8 mm is beyond half the cut height (±0.75 mm)")
    assert service.sequence.height_override_mm == 0.7
