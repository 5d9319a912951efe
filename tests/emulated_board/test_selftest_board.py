"""The emulated-board harness against its own self-test program (not the firmware): every
wire the firmware will use, proven on a program whose behaviour is known.

One board (Mega 2560, noise off) is shared by the module's tests; each test sets the state
it needs (Z, plate, forced inputs) first.
"""

from __future__ import annotations

import itertools
import statistics
import time
from pathlib import Path

import pytest

from dthc_tools.emulated_board import EmulatedBoard, frames, read_record

from .serial_line import LineClient

pytestmark = pytest.mark.slow

Board = tuple[EmulatedBoard, LineClient, Path]
STEP_UM = 5  # pins.h: 200 steps/mm
ADC_REF_MV = 5000
DIVIDER = 50


def counts(mv: float) -> int:
    """What simavr's 10-bit ADC reads for ``mv`` millivolts against AVcc."""
    return int(round(mv) * 1023 // ADC_REF_MV)


def test_pty_round_trip_echoes_every_byte_within_a_few_ms(selftest_board: Board) -> None:
    """Lines written to the pty come back exactly; the median round trip of a 12-byte
    line (1 Mbaud in the MCU, paced to real time) stays far below the daemon's 20 ms."""
    _, client, _ = selftest_board
    rtts = []
    for i in range(100):
        text = f"E{i:03d}-abcdefgh"
        t0 = time.monotonic()
        assert client.ask(text) == text
        rtts.append((time.monotonic() - t0) * 1000)
    assert statistics.median(rtts) < 5.0, rtts


def test_long_bursts_reach_the_mcu_without_a_lost_byte(selftest_board: Board) -> None:
    """A 10-line burst (340 bytes, over five times simavr's 64-byte receive FIFO) written
    at once arrives whole: the host holds bytes back instead of overrunning the receiver.
    (Longer bursts may overrun the self-test program's own 128-byte ring: its polled echo
    spends instructions between bytes.)"""
    _, client, _ = selftest_board
    lines = [f"E{i:02d}" + "x" * 30 for i in range(10)]
    client.write("".join(line + "\n" for line in lines).encode())
    got = [client.read_line().decode() for _ in lines]
    assert got == lines


def test_step_counting_is_exact_in_both_directions(selftest_board: Board) -> None:
    """STEP rising edges move Z one step each, up while DIR is HIGH, down while LOW."""
    board, client, _ = selftest_board
    board.command("z 60")
    assert client.ask("U400") == "S400"
    assert board.status().z_um == 60_000 + 400 * STEP_UM
    assert client.ask("D1000") == "S1000"
    assert board.status().z_um == 60_000 + (400 - 1000) * STEP_UM


@pytest.mark.parametrize("volts", [50.0, 125.0, 249.5])
def test_adc_reads_the_injected_arc_voltage_through_the_divider(
    selftest_board: Board, volts: float
) -> None:
    """With the relay on and the arc not transferred (the tip 40 mm up), the ADC reads the
    open-circuit voltage divided 1:50: 1000/2500/4990 mV -> 204/511/1020 counts."""
    board, client, _ = selftest_board
    board.command("z 60")
    board.command(f"model ocv-v {volts}")
    assert client.ask("T1") == "T1"
    try:
        assert client.ask("A") == f"A{counts(volts / DIVIDER * 1000)}"
    finally:
        client.ask("T0")
        board.command("model ocv-v 250")


def test_arc_transfers_near_the_plate_and_reads_cut_voltage(selftest_board: Board) -> None:
    """At cut height (1.5 mm over the plate) the pilot transfers after the arc-OK delay:
    ARC_OK goes active and the ADC reads the cut voltage (116 V -> 2320 mV -> 474)."""
    board, client, _ = selftest_board
    board.command("plate 20")
    board.command("z 21.5")
    client.ask("T1")
    try:
        deadline = time.monotonic() + 2.0
        while board.status().arc != "transferred":
            assert time.monotonic() < deadline, board.status()
            time.sleep(0.02)
        assert int(client.ask("I")[1:], 16) & 1  # ARC_OK active
        assert client.ask("A") == f"A{counts(116 / DIVIDER * 1000)}"
        board.command("z 35")  # 15 mm over the plate: the arc is lost
        assert client.ask("A") == f"A{counts(250 / DIVIDER * 1000)}"
        assert board.status().arc == "lost"
        assert not int(client.ask("I")[1:], 16) & 1
    finally:
        client.ask("T0")
    assert board.status().arc == "off"


def test_warp_moves_the_plate_under_the_cutting_torch(selftest_board: Board) -> None:
    """``warp 1 0.2``: while the arc is transferred the plate's surface swings ±1 mm over
    0.2 s, so at a fixed Z the arc voltage swings about ±7.5 V around the cut voltage."""
    board, client, _ = selftest_board
    board.command("plate 20")
    board.command("z 21.5")
    board.command("warp 1 0.2")
    client.ask("T1")
    try:
        deadline = time.monotonic() + 2.0
        while board.status().arc != "transferred":
            assert time.monotonic() < deadline
            time.sleep(0.01)
        volts = []
        for _ in range(40):
            volts.append(int(client.ask("A")[1:]) * 5000 / 1023 * DIVIDER / 1000)
            time.sleep(0.006)
    finally:
        client.ask("T0")
        board.command("warp 0 0")
        board.command("z 60")
    assert max(volts) - min(volts) > 12.0, volts
    assert 112.0 < statistics.mean(volts) < 120.0, volts


@pytest.mark.parametrize(
    ("name", "bit"),
    [("breakaway", 3), ("thc_up", 4), ("thc_down", 5), ("estop", 6), ("z_limit_min", 7),
     ("z_limit_max", 8), ("arc_ok", 0)],
)  # fmt: skip
def test_forced_inputs_reach_the_mcu_active_low(selftest_board: Board, name: str, bit: int) -> None:
    """``set NAME 1`` pulls the pin LOW (active), ``0`` leaves it HIGH, ``auto`` gives it
    back to the model; the MCU reads exactly that bit (Z_LIMIT_MAX shares PORTC with the
    outputs the program keeps writing)."""
    board, client, _ = selftest_board
    board.command("z 60")
    assert client.ask("I") == "I0"
    board.set_input(name, True)
    assert client.ask("T1") == "T1"  # a PORTC write must not lift a forced input
    client.ask("T0")
    assert client.ask("I") == f"I{1 << bit:x}"
    assert board.status().inputs[name]
    board.set_input(name, None)
    assert client.ask("I") == "I0"


def test_float_and_ohmic_follow_z_the_plate_and_ohmic_enable(selftest_board: Board) -> None:
    """OHMIC: the tip at or below the plate while ohmic sensing is enabled; FLOAT: the
    carriage 1.5 mm (the float travel) below the touch point."""
    board, client, _ = selftest_board
    board.command("plate 20")
    board.command("z 20.5")
    assert client.ask("I") == "I0"
    board.command("z 20")
    assert client.ask("I") == "I0"  # touching, but ohmic sensing is off
    assert client.ask("O1") == "O1"
    assert client.ask("I") == "I2"
    board.command("z 18.6")
    assert client.ask("I") == "I2"
    board.command("z 18.5")
    assert client.ask("I") == "I6"
    assert client.ask("O0") == "O0"
    assert client.ask("I") == "I4"
    board.command("plate 10")
    assert client.ask("I") == "I0"
    board.command("plate 20")
    board.command("z 60")


def test_probe_style_steps_close_the_float_switch_at_the_step_it_happens(
    selftest_board: Board,
) -> None:
    """Stepping down onto the plate: the float input turns active at the first step at or
    below plate - 1.5 mm (inputs are re-evaluated at each step, not per slice)."""
    board, client, _ = selftest_board
    board.command("plate 20")
    board.command("z 19")
    assert client.ask("D99") == "S99"  # 19.000 -> 18.505
    assert client.ask("I") == "I0"
    assert client.ask("D1") == "S1"  # 18.500
    assert client.ask("I") == "I4"
    board.command("z 60")


def test_an_input_copied_to_an_output_shows_in_status_and_record(selftest_board: Board) -> None:
    """In copy mode the program drives the torch output from ESTOP: the forced input goes
    in, the relay pin comes out, and the record holds the relay's edges."""
    board, client, tmp = selftest_board
    board.command("z 60")
    assert client.ask("C1") == "C1"
    try:
        board.set_input("estop", True)
        time.sleep(0.05)
        assert board.status().torch
        board.set_input("estop", False)
        time.sleep(0.05)
        assert not board.status().torch
    finally:
        client.ask("C0")
        board.set_input("estop", None)
    torch = [e.fields[0] for e in read_record(tmp / "record.csv") if e.event == "torch"]
    assert torch[-2:] == ["1", "0"]


def test_record_names_host_and_board_frames_by_type_and_seq(selftest_board: Board) -> None:
    """A host frame's delimiter delivered to the UART and a board frame's delimiter written
    by the MCU are both recorded with the frame's type and seq (COBS-decoded)."""
    _, client, tmp = selftest_board
    hello = bytes.fromhex("04 01 01 01 07 D4 C3 B2 A1 4B DD 00")  # PROTOCOL.md §9
    client.write(b"\x00" + hello + b"F\n")  # a lone delimiter first ends the text before
    assert client.read_line() == bytes.fromhex("00 09 80 04 34 12 ED 5E 45 F8 00") + b"F"
    time.sleep(0.05)
    events = read_record(tmp / "record.csv")
    host = frames(events, "host_frame")
    board = frames(events, "board_frame")
    assert (host[-1].type_, host[-1].seq, host[-1].encoded_len) == (0x01, 1, 11)
    assert (board[-1].type_, board[-1].seq, board[-1].encoded_len) == (0x80, 4, 9)
    assert host[-1].t_us < board[-1].t_us
    zs = [e for e in events if e.event == "z"]
    gaps = [b.t_us - a.t_us for a, b in itertools.pairwise(zs)]
    assert max(gaps) <= 10_100


def test_simulated_time_is_paced_to_the_wall_clock(selftest_board: Board) -> None:
    """Over one second, simulated time advances with the wall clock (within 5 %)."""
    board, _, _ = selftest_board
    t0_wall, t0_sim = time.monotonic(), board.status().t_us
    time.sleep(1.0)
    t1_wall, t1_sim = time.monotonic(), board.status().t_us
    ratio = (t1_sim - t0_sim) / 1e6 / (t1_wall - t0_wall)
    assert 0.95 < ratio < 1.05, ratio


def test_control_channel_answers_every_line_and_names_bad_commands(
    selftest_board: Board,
) -> None:
    """Unknown commands and bad arguments get ``error: ...`` naming the problem."""
    board, _, _ = selftest_board
    assert board.command("warp 0 0") == "ok"
    for line, error in [
        ("xyz", "error: unknown command 'xyz'"),
        ("set nothing 1", "error: unknown input 'nothing'"),
        ("set estop maybe", "error: set: level 'maybe' is not 1, 0 or auto"),
        ("model bogus 1", "error: unknown model key 'bogus'"),
    ]:
        with pytest.raises(Exception, match=error):
            board.command(line)


def test_sigusr2_resets_the_mcu_as_its_reset_pin_and_keeps_z(selftest_board: Board) -> None:
    """SIGUSR2: the program restarts (its banner again) with MCUSR = EXTRF (0x02), the
    relay drops, and the physical Z is where it was."""
    board, client, tmp = selftest_board
    board.command("z 42")
    client.ask("T1")
    board.reboot()
    assert client.read_line(2.0) == b"BOOT 2"
    status = board.status()
    assert status.z_um == 42_000
    assert not status.torch
    assert client.ask("R") == "R2"
    events = read_record(tmp / "record.csv")
    assert any(e.event == "reboot" and e.fields == ("external_reset",) for e in events)


def test_a_timer_tick_raised_while_masked_fires_when_unmasked(selftest_board: Board) -> None:
    """As on the AVR, a compare match whose interrupt is masked for a moment is taken when
    the mask is lifted: 20 rounds of 1.2 ms masked + 0.3 ms unmasked count about 30 ticks of
    1 ms (plain simavr lost them and waited a 32.8 ms timer wrap: 0 or 1)."""
    _, client, _ = selftest_board
    reply = client.ask("K")
    assert reply.startswith("K")
    assert 28 <= int(reply[1:]) <= 31, reply


def test_a_watchdog_reset_keeps_the_inputs_and_z(selftest_board: Board) -> None:
    """The program lets its watchdog bite: it restarts with MCUSR = WDRF (0x08), and the
    host re-drives the pins simavr cleared, so inputs read as the model says (none active,
    the forced one active) and Z is where it was."""
    board, client, tmp = selftest_board
    board.command("z 42")
    board.set_input("breakaway", True)
    try:
        assert client.ask("W") == "W"
        assert client.read_line(2.0) == b"BOOT 8"
        assert client.ask("I") == "I8"
        assert board.status().z_um == 42_000
    finally:
        board.set_input("breakaway", None)
    events = read_record(tmp / "record.csv")
    assert any(e.event == "reboot" and e.fields == ("internal",) for e in events)
