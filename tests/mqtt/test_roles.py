"""docs/DESIGN.md invariant 8 for each request that can light the torch, energise its
ohmic circuit or move Z: only the sender's user may publish it; the panel's reach those
through the sender (which refuses the idle tools while its program runs)."""

from __future__ import annotations

import pytest

from dthc_bridge.mqtt.roles import PANEL_REQUESTS, REQUESTS, Role, grants

TORCH_OR_Z = (
    "gcode", "cycle_start", "rearm", "torch_up", "torch_down", "height_override", "thc",
    "thc_hold", "ohmic_test", "probe_test", "jog_z", "motion", "program_start",
)  # fmt: skip


@pytest.mark.parametrize("name", TORCH_OR_Z)
def test_a_request_that_lights_the_torch_or_moves_z_is_the_senders_alone(name: str) -> None:
    assert REQUESTS[name] is True
    assert name not in PANEL_REQUESTS
    panel = {(g.access, g.leaf) for g in grants(Role.PANEL)}
    assert ("write", f"request/{name}") not in panel
    assert not any(leaf == "request/#" for _, leaf in panel)


def test_the_panels_own_requests_choose_or_count_but_move_nothing() -> None:
    assert {"material_select", "consumables_reset", "abort", "status"} <= PANEL_REQUESTS
