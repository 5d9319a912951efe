"""Z_HOME (protocol 1.3) on the firmware's own ELF on the emulated Mega 2560: the board boots
taking Z as 60 mm wherever the carriage stands; homed on its switch (the emulator's
Z_LIMIT_MAX at 102 mm), its Z is the carriage's, counted from the STEP pulses, and homing
again moves it by at most a step (the repeatability, printed)."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

import firmware_protocol as fp
from dthc_tools.emulated_board import EmulatedBoard, HarnessOptions, read_record
from firmware_protocol import HomeOutcome, StatusBit

from .frame_link import FrameLink

pytestmark = pytest.mark.slow

HOME_SWITCH_UM = 102_000  # the emulator's home switch, the firmware's DTHC_Z_HOME_UM
PARKED_UM = 100_000  # 2 mm (the backoff) under it
HOMING_WALL_S = 60.0  # the emulator runs slower than real time on a loaded machine


@pytest.fixture
def board(built: Path, tmp_path: Path) -> Iterator[EmulatedBoard]:
    options = HarnessOptions(record=tmp_path / "record.csv", stderr=tmp_path / "host.log")
    with EmulatedBoard(tmp_path / "board.pty", options) as emulated:
        yield emulated


def _home(link: FrameLink) -> fp.HomeResult:
    ack = link.expect(lambda s: fp.ZHome(s, 20_000, 2_000, 2_000, 300_000, 30_000), fp.Ack)
    deadline = time.monotonic() + HOMING_WALL_S
    while time.monotonic() < deadline:
        link.run_for(0.2)
        done = [r for r in link.reports(fp.HomeResult) if r.seq == ack.seq]
        if done:
            return done[0]
        link.expect(fp.Heartbeat, fp.Ack)  # the lease: the host is here
    raise AssertionError("no HOME_RESULT")


def test_the_firmware_homes_z_to_where_the_carriage_really_is(board: EmulatedBoard) -> None:
    """The carriage put at 45 mm by hand, the board still says 60: homed, the board's Z is
    the carriage's (a shift of -15 mm), parked 2 mm under the switch with HOMED set and
    nothing latched, never more than a few steps past the switch; a second homing moves Z
    by at most one step (5 um)."""
    assert board.command("z 45") == "ok"
    link = FrameLink(board.pty)
    try:
        info = link.hello()
        assert info.capabilities & fp.Capability.HOMING
        link.expect(lambda s: fp.SetLease(s, 2000), fp.Ack)
        before = link.status()
        assert before.z_um == 60_000
        assert not before.status & StatusBit.HOMED
        first = _home(link)
        assert first.result == HomeOutcome.HOMED
        assert first.shift_um == pytest.approx(-15_000, abs=10)
        status = link.status()
        assert status.status & StatusBit.HOMED
        assert status.faults == 0
        assert status.z_um == first.z_um == PARKED_UM
        assert board.status().z_um == pytest.approx(PARKED_UM, abs=5)  # the carriage
        second = _home(link)
        assert second.result == HomeOutcome.HOMED
        assert abs(second.shift_um) <= 5
    finally:
        link.request(fp.ZStop)
        link.close()
    assert board.options.record is not None
    highest = max(int(e.fields[0]) for e in read_record(board.options.record) if e.event == "z")
    assert highest - HOME_SWITCH_UM < 100  # the switch stops Z within a few steps
    print(json.dumps({"homing_shift_um": first.shift_um, "repeatability_um": second.shift_um,
                      "overrun_past_switch_um": highest - HOME_SWITCH_UM}))  # fmt: skip
