"""Z_HOME on the mock board (protocol 1.3, PROTOCOL.md §6.1): the reference firmware's
homing on the plant's home switch, 2 mm above the soft limits.

A board whose firmware takes Z as 60 mm at power-on while the carriage stands elsewhere
reports a wrong Z until it homes; homed, its Z is the plant's, and homing again moves it by
no more than the switch's repeatability."""

from __future__ import annotations

import pytest

import firmware_protocol as fp
from firmware_protocol import HomeOutcome, InputMask, StatusBit
from mock_device.board_logic import BoardIdentity
from mock_device.sim import SimulatedBoard
from mock_device.sim_host import SimHost

HOME = fp.ZHome(0, 30_000, 2_000, 2_000, 200_000, 20_000)


def _home(host: SimHost, command: fp.ZHome = HOME, ms: int = 20_000) -> fp.HomeResult:
    ack = host.request(command)
    assert isinstance(ack, fp.Ack), ack
    for _ in range(ms // 50):
        host.keep_alive_for(50)
        done = [m for m in host.of_type(fp.HomeResult) if m.seq == ack.seq]
        if done:
            return done[0]
    raise AssertionError(f"no HOME_RESULT within {ms} ms")


def _status(host: SimHost) -> fp.Status:
    reply = host.request(fp.Query(0, fp.QueryWhat.STATUS))
    assert isinstance(reply, fp.Status)
    return reply


def test_homing_makes_the_boards_z_the_plants() -> None:
    """The carriage stands at 40 mm, the board boots believing 60 (its constant): homed,
    its Z is the plant's to a step, parked 2 mm below the switch, HOMED set, nothing
    latched; a second homing shifts Z by at most a step (the repeatability)."""
    identity = BoardIdentity(boot_z_mm=60.0)
    board = SimulatedBoard("flat_clean", seed=3, identity=identity)
    board.plant.zaxis.position_mm = 40.0
    board.reboot()  # power-on with the carriage at 40 mm
    host = SimHost(board)
    info = host.open_session()
    assert info.capabilities & fp.Capability.HOMING
    assert info.proto_minor >= 3
    zaxis = board.plant.zaxis
    before = _status(host)
    assert before.z_um == 60_000
    assert not before.status & StatusBit.HOMED
    result = _home(host)
    assert result.result == HomeOutcome.HOMED
    assert result.shift_um == pytest.approx(-20_000, abs=10)
    after = _status(host)
    assert after.status & StatusBit.HOMED
    assert after.faults == 0
    assert after.z_um == zaxis.max_mm * 1000 == result.z_um
    assert zaxis.position_mm * 1000 == pytest.approx(after.z_um, abs=5)
    assert not board.firmware.inputs & InputMask.Z_LIMIT_MAX
    again = _home(host)
    assert again.result == HomeOutcome.HOMED
    assert abs(again.shift_um) <= 5


def test_a_reboot_forgets_the_home_and_a_missing_switch_is_not_found() -> None:
    """A board reset clears HOMED (its count starts again from its constant); a switch that
    never closes (held open) ends homing NOT_FOUND after max travel, unhomed."""
    board = SimulatedBoard("flat_clean", seed=4, identity=BoardIdentity(boot_z_mm=60.0))
    host = SimHost(board)
    host.open_session()
    assert _home(host).result == HomeOutcome.HOMED
    board.reboot()
    host.open_session()
    assert not _status(host).status & StatusBit.HOMED
    board.plant.force_input(InputMask.Z_LIMIT_MAX, False)
    result = _home(host, fp.ZHome(0, 30_000, 2_000, 2_000, 5_000, 20_000))
    assert result.result == HomeOutcome.NOT_FOUND
    assert not _status(host).status & StatusBit.HOMED


def test_a_board_of_protocol_1_2_has_no_homing_and_refuses_z_home_with_unknown_type() -> None:
    """A board announcing 1.2 (PROTOCOL.md §7): HELLO_INFO without the HOMING capability,
    and Z_HOME answered as a type it never heard of, NAK UNKNOWN_TYPE, Z still."""
    board = SimulatedBoard("flat_clean", seed=5, identity=BoardIdentity(proto_minor=2))
    host = SimHost(board)
    info = host.open_session()
    assert info.proto_minor == 2
    assert not info.capabilities & fp.Capability.HOMING
    before = board.plant.zaxis.position_mm
    nak = host.request(HOME)
    assert isinstance(nak, fp.Nak)
    assert nak.code == fp.NakCode.UNKNOWN_TYPE
    host.pump(100)
    assert board.plant.zaxis.position_mm == before
    assert board.plant.zaxis.is_idle
