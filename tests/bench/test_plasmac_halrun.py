"""Proof that the in-process plasmac is LinuxCNC's runtime's: the same inputs into the real
``rtapi_app`` (through ``halrun``, ``streamer`` and ``sampler``) give the same outputs,
period by period, on every output pin; shifted by one period they do not.

Needs LinuxCNC installed (``dthc-bridge bench control --install-linuxcnc``); skipped where
``halrun`` is not."""

from __future__ import annotations

import pytest

from dthc_tools.bench.cuts import plan_cuts
from dthc_tools.bench.plasmac.component import PlasmacComponent
from dthc_tools.bench.plasmac.fetch import PlasmacUnavailable, provision
from dthc_tools.bench.plasmac.halrun import halrun_available, replay_recording
from dthc_tools.bench.plasmac.host import PlasmacHost, PlasmacSettings
from mock_device.plant import Plant, load_scenario

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        not halrun_available(),
        reason="LinuxCNC's halrun is not installed (dthc-bridge bench control --install-linuxcnc)",
    ),
]


@pytest.mark.timeout(300)
def test_a_recorded_run_replays_identically_in_linuxcnc() -> None:
    """warped_sheet, 150 mm and a slow-down: probing, pierce, THC moving Z, corner lock,
    M5 and the end of the job; every period's outputs match, and the one-period shift
    mismatches in hundreds of periods (the check can fail)."""
    try:
        plasmac = provision()
    except PlasmacUnavailable as exc:
        pytest.skip(f"plasmac cannot be fetched: {exc}")
    plant = Plant("warped_sheet", seed=3)
    with PlasmacComponent(plasmac.component, plasmac.shim) as comp:
        host = PlasmacHost(plant, comp, PlasmacSettings(use_auto_volts=True), record=True)
        plant.gantry.feed_line("G21 G90")
        for plan in plan_cuts(load_scenario("warped_sheet").default_program, max_path_mm=150):
            assert host.cut(plan, slow_percent=50.0) is None
        host.end_job()
        types = {name: pin.type for name, pin in comp.pins.items()}
    rec = host.recording
    assert rec is not None
    aligned, shifted = replay_recording(rec.inputs, rec.rows_in, rec.outputs, rec.rows_out, types)
    print(
        f"halrun replay: {aligned.matching} of {aligned.periods} periods identical on "
        f"{len(rec.outputs)} output pins; shifted by one: {shifted.matching} of "
        f"{shifted.periods}, mismatches per pin {shifted.mismatching_pins}"
    )
    assert aligned.periods == len(rec.rows_out) > 3000
    assert aligned.mismatching_pins == {}
    assert aligned.identical
    assert shifted.periods - shifted.matching > 300
