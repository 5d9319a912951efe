"""The mock runs the firmware's C board logic (firmware/board/) as a library on the plant:
what the plant gives it (XY speed, current) reaches the wire through the C, and two boards
in one process keep their own state."""

from __future__ import annotations

import firmware_protocol as fp
from firmware_protocol import Capability
from mock_device.board_logic import BoardIdentity
from mock_device.sim import SimulatedBoard
from mock_device.sim_host import SimHost


def _host(identity: BoardIdentity | None = None) -> SimHost:
    host = SimHost(SimulatedBoard("flat_clean", seed=3, identity=identity))
    host.open_session()
    return host


def test_samples_carry_the_gantrys_xy_speed_through_the_c_board() -> None:
    """The gantry at 50 mm/s: the C board's XY speed input (hal_xy_speed_dmm_s) puts it in
    every batch, in 0.1 mm/s; standing still, 0."""
    host = _host()
    host.pump(20)
    assert {b.xy_speed_dmm_s for b in host.of_type(fp.Samples)} == {0}
    host.board.plant.gantry.feed_line("G1 X300 F3000")
    mark = len(host.received)
    host.keep_alive_for(1500)
    speeds = [m.xy_speed_dmm_s for m in host.received[mark:] if isinstance(m, fp.Samples)]
    assert max(speeds) == 500
    assert host.board.plant.xy_speed_mm_s * 10 == speeds[-1]


def test_a_board_without_the_speed_input_reports_it_unknown() -> None:
    """Without capability XY_SPEED (``--no-xy-speed``) the same C says 0xFFFF."""
    caps = BoardIdentity().capabilities & ~Capability.XY_SPEED
    host = _host(BoardIdentity(capabilities=caps))
    host.board.plant.gantry.feed_line("G1 X300 F3000")
    host.keep_alive_for(300)
    assert {b.xy_speed_dmm_s for b in host.of_type(fp.Samples)} == {fp.XY_SPEED_UNKNOWN}


def test_set_current_reaches_the_plant_and_status() -> None:
    """SET_CURRENT (capability CURRENT_OUT): the board's current output drives the cutter's
    set point in the plant, and STATUS reports it."""
    host = _host()
    assert isinstance(host.request(fp.SetCurrent(0, 650)), fp.Ack)
    assert host.board.plant.arc.current_a == 65.0
    status = host.request(fp.Query(0, fp.QueryWhat.STATUS))
    assert isinstance(status, fp.Status)
    assert status.current_da == 650


def test_two_boards_in_one_process_keep_their_own_state() -> None:
    """Each board loads its own copy of the library: one's session, lease and faults are not
    the other's."""
    a = _host()
    b = SimHost(SimulatedBoard("flat_clean", seed=4))
    assert a.board.firmware.session
    assert not b.board.firmware.session
    a.request(fp.OhmicSense(0, True))
    a.pump(300)  # a's lease runs out in use: latched
    assert a.board.firmware.faults
    assert b.board.firmware.faults == 0
    assert a.board.firmware.boot_id != b.board.firmware.boot_id
