"""The sender's XY speed as the anti-dive input (``motion`` request) and the operator's THC
hold (``thc_hold``): for tables whose board has no XY speed input (a grbl machine)."""

from __future__ import annotations

from typing import Any

import pytest

import firmware_protocol as fp
from dthc_bridge.board import Batch, batch_from_wire
from dthc_bridge.controller.sequence import CutSequence
from dthc_bridge.controller.thc import Lock, ThcController
from dthc_bridge.events import ControllerEvent
from dthc_bridge.service import HOST_SPEED_STALE_S, ControllerService, feed_samples
from tests.daemon.test_material_requests import service_for


def batch(t_s: float, xy_dmm_s: int = fp.XY_SPEED_UNKNOWN) -> Batch:
    return batch_from_wire(fp.Samples(0, 0, 0, 1000, 1500, 0, 0, xy_dmm_s, 0, (11800,) * 10), t_s)


@pytest.fixture
async def service() -> ControllerService:
    return await service_for(None)


async def test_motion_is_used_when_the_board_reports_no_speed(service: ControllerService) -> None:
    result = await service.execute_request(
        "motion", {"xy_speed_mm_s": 12.5, "feed_mm_min": 1500, "state": "Run"}
    )
    assert result.ok, result.error
    assert result.data == {"used": True}
    now = service.now
    assert service._host_speed_now(now) == 12.5
    assert service._requested_feed_mm_s == pytest.approx(25.0)
    assert service._host_speed_now(now + HOST_SPEED_STALE_S + 0.01) is None


@pytest.mark.parametrize(
    ("args", "error"),
    [
        ({}, "motion xy_speed_mm_s: required argument is missing"),
        ({"xy_speed_mm_s": -1}, "motion xy_speed_mm_s"),
        ({"xy_speed_mm_s": True}, "motion xy_speed_mm_s: True is not a number"),
        ({"xy_speed_mm_s": "fast"}, "motion xy_speed_mm_s: 'fast' is not a number"),
        ({"xy_speed_mm_s": 1e9}, "motion xy_speed_mm_s"),
        ({"xy_speed_mm_s": 10, "feed_mm_min": 0}, "motion feed_mm_min: 0 must be > 0"),
        ({"xy_speed_mm_s": 10, "state": 3}, "motion state: 3 is not a string"),
        ({"xy_speed_mm_s": 10, "speed": 3}, "motion speed: unknown argument"),
    ],
)
async def test_a_bad_motion_request_names_it_and_changes_nothing(
    service: ControllerService, args: dict[str, Any], error: str
) -> None:
    result = await service.execute_request("motion", args)
    assert not result.ok
    assert error in result.error
    assert service._host_speed is None
    assert service._requested_feed_mm_s is None


def test_the_host_speed_feeds_the_anti_dive_only_without_a_board_speed() -> None:
    sequence = CutSequence()
    thc = sequence.thc
    feed_samples(sequence, batch(1.0), 25.0, host_speed_mm_s=25.0)
    feed_samples(sequence, batch(1.15), 25.0, host_speed_mm_s=25.0)  # at speed 0.15 s
    assert Lock.NO_SPEED not in thc.locks(1.15)
    assert not thc._s.velocity_locked
    feed_samples(sequence, batch(1.16), 25.0, host_speed_mm_s=10.0)  # a corner: 40 %
    assert thc._s.velocity_locked
    # The board's own speed wins over the host's.
    xy = feed_samples(sequence, batch(1.17, xy_dmm_s=250), 25.0, host_speed_mm_s=10.0)
    assert xy == 25.0
    # No speed at all: locked as unknown.
    feed_samples(sequence, batch(1.3), 25.0, host_speed_mm_s=None)
    assert Lock.NO_SPEED in thc.locks(1.3)


async def test_thc_hold_locks_until_released_and_a_new_cut_starts_released(
    service: ControllerService,
) -> None:
    thc = service.sequence.thc
    result = await service.execute_request("thc_hold", {"on": True})
    assert result.ok
    assert result.data == {"thc_held": True, "cut_ended": False}
    assert Lock.HELD in thc.locks(0.0)
    assert (await service.execute_request("thc_hold", {"on": False})).ok
    assert Lock.HELD not in thc.locks(0.0)
    refused = await service.execute_request("thc_hold", {"on": "yes"})
    assert refused.error == "thc_hold on: 'yes' is not true or false"
    assert (await service.execute_request("thc_hold", {"on": True})).ok
    thc.reset()  # what the sequence does when the next cut starts
    assert Lock.HELD not in thc.locks(0.0)


def test_a_held_thc_commands_no_z_motion() -> None:
    """At speed with the voltage 8 V low the THC moves Z; held, it does not."""
    outputs = []
    for held in (False, True):
        thc = ThcController()
        thc.frozen = False
        thc.target_v = 118.0
        thc.observe_speed(25.0, 25.0, 0.0)
        thc.observe_speed(25.0, 25.0, 0.2)
        thc.held = held
        outputs.append(thc.update([110.0] * 10, 0.001, 0.2, 0.01))
    free, held_output = outputs
    assert free.velocity_mm_s != 0.0
    assert held_output.velocity_mm_s == 0.0
    assert Lock.HELD in held_output.locks


async def test_the_operators_thc_switch_turns_the_thc_on_and_off(
    service: ControllerService,
) -> None:
    """``thc`` {on}: a panel's THC on/off, as M667 / M666 without a program line."""
    assert (await service.execute_request("thc", {"on": True})).ok
    assert service.sequence.thc_enabled
    assert (await service.execute_request("thc", {"on": False})).ok
    assert not service.sequence.thc_enabled
    refused = await service.execute_request("thc", {"on": 1})
    assert refused.error == "thc on: 1 is not true or false"
    assert not service.sequence.thc_enabled


async def test_each_change_of_the_sequence_state_is_an_event_at_its_board_time(
    service: ControllerService,
) -> None:
    """What a panel's cut history is built from: ``sequence`` {state, previous, error}."""
    seen: list[ControllerEvent] = []
    service.add_event_listener(seen.append)
    service.pump()
    assert seen == []  # no change, no event
    service.sequence.abort("stopped by the operator")  # idle -> nothing to abort
    service.sequence._fault("arc lost")
    service.pump()
    payloads = [e.as_payload() for e in seen if e.type == "sequence"]
    assert payloads == [
        {"t": 0.0, "type": "sequence", "state": "faulted", "previous": "idle", "error": "arc lost"}
    ]
