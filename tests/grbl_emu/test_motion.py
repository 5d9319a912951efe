"""Motion as a sender sees it: planner flow, holds, resets, alarms, overrides, dwells, jogs."""

from __future__ import annotations

import pytest

from dthc_tools.grbl_emu import EmulatorConfig, Flavor

from .emu_helpers import Emu


def test_a_move_runs_then_ends_idle_at_its_target_with_fs_the_programmed_feed() -> None:
    """``Run`` with ``FS`` at the programmed feed (not the measured speed), then ``Idle``."""
    emu = Emu()
    assert emu.send("G1 X60 Y80 F3000\n") == ["ok"]
    emu.run(0.01)
    fields = emu.fields()
    assert fields["state"] == "Run"
    assert fields["FS"] == "3000,0"  # already, while the table is still accelerating
    assert fields["Bf"] == "14,128"
    emu.run_until("Idle", 3.0)
    fields = emu.fields()
    assert fields["MPos"] == "60.000,80.000,0.000"
    assert fields["FS"] == "0,0"
    assert fields["Bf"] == "15,128"


def test_feed_hold_decelerates_holds_and_cycle_start_resumes() -> None:
    """``!``: Hold:1 (FS 0) while slowing, Hold:0 (FS the feed) at rest; ``~``: Run again."""
    emu = Emu()
    emu.send("G1 X200 F6000\n")
    emu.run(0.5)
    emu.send("!")
    emu.run(0.005)
    fields = emu.fields()
    assert fields["state"] == "Hold:1"
    assert fields["FS"].startswith("0,")
    assert emu.send("~") == []  # a hold still decelerating ignores cycle start
    emu.run_until("Hold:0", 0.5)
    x_held, _ = emu.position()
    assert emu.fields()["FS"] == "6000,0"
    emu.run(0.3)
    assert emu.position()[0] == x_held  # nothing moves in a hold
    emu.send("~")
    emu.run(0.05)
    assert emu.fields()["state"] == "Run"
    emu.run_until("Idle", 3.0)
    assert emu.position() == (200.0, 0.0)


def test_feed_hold_while_idle_holds_queued_lines_until_cycle_start() -> None:
    """Lines sent in a hold are planned but wait for ``~``."""
    emu = Emu()
    emu.send("!")
    assert emu.fields()["state"] == "Hold:0"
    assert emu.send("G0 X10\n") == ["ok"]
    emu.run(0.2)
    assert emu.position() == (0.0, 0.0)
    emu.send("~")
    emu.run_until("Idle", 1.0)
    assert emu.position() == (10.0, 0.0)


def test_reset_while_moving_alarms_3_and_locks_out_gcode_until_unlock() -> None:
    """0x18 mid-move: ALARM:3, banner, unlock hint; G-code gets error:9 until ``$X``."""
    emu = Emu()
    emu.send("G1 X100 F3000\nG1 Y100\n")
    emu.run(0.3)
    assert emu.send(b"\x18") == [
        "ALARM:3",
        "Grbl 1.1f ['$' for help]",
        "[MSG:'$H'|'$X' to unlock]",
    ]
    x_stop, _ = emu.position()
    assert 0.0 < x_stop < 100.0
    assert emu.fields()["state"] == "Alarm"
    assert emu.send("G0 X0\n") == ["error:9"]
    assert emu.send("$G\n")[-1] == "ok"  # $ commands still work
    emu.run(0.3)
    assert emu.position()[0] == x_stop  # the planner was flushed
    assert emu.send("$X\n") == ["[MSG:Caution: Unlocked]", "ok"]
    assert emu.send("G0 X0\n") == ["ok"]
    emu.run_until("Idle", 1.0)
    assert emu.position() == (0.0, 0.0)


def test_reset_after_a_completed_hold_keeps_position_without_alarm() -> None:
    """The safe way to abort: ``!``, wait for Hold:0, then 0x18: no alarm."""
    emu = Emu()
    emu.send("G1 X100 F3000\n")
    emu.run(0.3)
    emu.send("!")
    emu.run_until("Hold:0", 0.5)
    assert emu.send(b"\x18") == ["Grbl 1.1f ['$' for help]"]
    assert emu.fields()["state"] == "Idle"


def test_soft_limit_stops_under_control_then_alarms_2_until_reset_and_unlock() -> None:
    """A target beyond $130/$131: the table decelerates, ALARM:2, nothing served but reset."""
    emu = Emu(EmulatorConfig(max_travel_mm=(300.0, 300.0)))
    emu.send("G1 X200 F6000\n")
    emu.run(0.5)
    assert emu.send("G1 X400\n") == []  # no answer: the line is lost with the alarm
    assert emu.fields()["state"] == "Hold:1"
    assert emu.run(0.5) == ["ALARM:2", "[MSG:Reset to continue]"]
    assert emu.send(b"?") == []  # classic grbl serves nothing but a reset now
    assert emu.send("$X\n") == []
    assert emu.send(b"\x18") == ["Grbl 1.1f ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]
    assert emu.fields()["state"] == "Alarm"
    x, _ = emu.position()
    assert 0.0 < x < 300.0
    assert emu.send("$X\n") == ["[MSG:Caution: Unlocked]", "ok"]
    assert emu.fw.stats.alarms == {2: 1}


def test_soft_limit_on_grblhal_still_answers_status() -> None:
    """grblHAL answers ``?`` in the limit alarm; a target beyond travel alarms at once if idle."""
    emu = Emu(EmulatorConfig(flavor=Flavor.GRBLHAL, max_travel_mm=(100.0, 100.0)))
    assert emu.send("G0 X-1\n") == ["ALARM:2", "[MSG:Reset to continue]"]
    assert emu.fields()["state"] == "Alarm"


def test_arcs_are_checked_against_travel_by_their_bulge() -> None:
    """An arc whose end points are inside but whose bulge leaves the travel alarms."""
    emu = Emu(EmulatorConfig(max_travel_mm=(100.0, 100.0)))
    emu.send("G0 X50 Y10\n")
    emu.run_until("Idle", 1.0)
    emu.send("G2 X50 Y30 I0 J10 F1000\n")  # bulges to x 60: inside
    assert emu.run(3.0) == ["ok"]
    emu.run_until("Idle", 5.0)
    emu.send("G0 X10 Y50\n")
    emu.run_until("Idle", 1.0)
    assert emu.send("G3 X10 Y10 I0 J-20 F1000\n") == ["ALARM:2", "[MSG:Reset to continue]"]


def test_lines_back_up_in_the_rx_buffer_when_the_planner_is_full() -> None:
    """With the planner full the parser stops: no ok, the next lines wait in the RX buffer."""
    emu = Emu(EmulatorConfig(planner_blocks=4))
    lines = [f"G1 X{10 * (i + 1)} F600\n" for i in range(6)]
    answers = emu.send("".join(lines))
    assert answers == ["ok"] * 4  # four blocks planned, the fifth line waits
    fields = emu.fields()
    assert fields["Bf"] == f"0,{128 - len(lines[5])}"  # the 5th line left RX, the 6th is there
    emu.run_until("Idle", 15.0)
    assert emu.fw.stats.ok == 6


def test_an_arc_is_answered_once_its_chords_fit_in_the_planner() -> None:
    """An arc is many planner blocks: its ok comes when the last chords are planned."""
    emu = Emu()
    emu.send("G0 X30 Y30\n")
    assert emu.send("G2 X30 Y30 I20 J0 F3000\n") == []  # a full circle: ~250 chords
    assert emu.fields()["Bf"].startswith("0,")
    t = 0.0
    while not emu.run(0.01):
        t += 0.01
        assert t < 5.0
    assert emu.fields()["state"] == "Run"  # ok before the arc ends
    emu.run_until("Idle", 1.0)


def test_dwell_answers_after_the_planner_empties_and_the_time_passes() -> None:
    """``G4 P0.5``: its ok marks motion complete plus half a second (grbl: P in seconds)."""
    emu = Emu()
    assert emu.send("G1 X50 F6000\nG4 P0.5\n") == ["ok"]
    t_motion = emu.run_until("Idle", 2.0)
    waited = 0.0
    while not emu.run(0.01):
        waited += 0.01
    assert 0.45 <= waited <= 0.52
    assert t_motion > 0.4


def test_program_pause_m0_waits_for_cycle_start() -> None:
    """``M0`` holds after the motion; its ok comes with ``~``."""
    emu = Emu()
    emu.send("G0 X5\nM0\n")
    emu.run(0.5)
    assert emu.fields()["state"] == "Hold:0"
    assert emu.send("~") == ["ok"]
    assert emu.fields()["state"] == "Idle"


def test_feed_override_changes_the_reported_ov_and_the_time_a_move_takes() -> None:
    """0x91 +10 %, 0x92 -10 %: queued motion is re-timed at once; Ov shows it."""

    def duration(*override: bytes) -> float:
        emu = Emu()
        for byte in override:
            emu.send(byte)
        emu.send("G1 X150 F3000\n")
        return emu.run_until("Idle", 20.0)

    emu = Emu()
    for _ in range(5):
        emu.send(b"\x92")
    assert emu.fields()["Ov"] == "50,100,100"
    for _ in range(20):
        emu.send(b"\x91")
    assert emu.fields()["Ov"] == "200,100,100"  # clamped
    emu.send(b"\x90\x94\x94")
    assert emu.fields()["Ov"] == "98,100,100"
    plain = duration()
    half = duration(*[b"\x92"] * 5)
    assert half == pytest.approx(2 * plain, rel=0.05)


def test_feed_override_applies_to_a_move_already_running() -> None:
    """Slowing down mid-move: FS shows the new speed and the move takes longer."""
    emu = Emu()
    emu.send("G1 X200 F6000\n")
    emu.run(0.5)
    for _ in range(5):
        emu.send(b"\x92")
    emu.run(0.3)
    assert emu.fields()["FS"] == "3000,0"
    emu.run_until("Idle", 10.0)
    assert emu.t > 200 / 100 + 0.9


def test_rapid_override_slows_rapids_only() -> None:
    """0x97: rapids at 25 %; Ov's second value."""
    emu = Emu()
    emu.send(b"\x97")
    assert emu.fields()["Ov"] == "100,25,100"
    emu.send("G0 X100\n")
    emu.run(0.5)
    assert emu.fields()["FS"] == "2500,0"


def test_jog_runs_and_jog_cancel_stops_it_and_flushes() -> None:
    """``$J=``: state Jog; 0x85 decelerates and drops the rest; the parser follows."""
    emu = Emu()
    assert emu.send("$J=G91 X100 F3000\n") == ["ok"]
    emu.run(0.2)
    assert emu.fields()["state"] == "Jog"
    assert emu.send("G0 X0\n") == ["error:9"]
    emu.send(b"\x85")
    emu.run_until("Idle", 1.0)
    x, _ = emu.position()
    assert 0.0 < x < 100.0
    assert emu.send("$J=X5000 F1000\n") == ["error:15"]  # beyond travel
    assert emu.send("$J=G1 X5 F1000\n") == ["error:16"]  # G1 is not allowed in a jog
    assert emu.send("$J=G91 X1\n") == ["error:22"]  # jog needs F


def test_homing_when_enabled_goes_to_machine_zero_and_unlocks() -> None:
    """``$22=1`` then ``$H``: state Home, rapid to X0 Y0, ok, alarm cleared."""
    emu = Emu()
    emu.send("G0 X30 Y40\n")
    emu.run_until("Idle", 2.0)
    emu.send(b"\x18")
    emu.send("$22=1\n")
    assert emu.send("$H\n") == []
    assert emu.fields()["state"] == "Home"
    while not emu.run(0.01):
        pass
    assert emu.position() == (0.0, 0.0)
    assert emu.fields()["state"] == "Idle"


def test_grblhal_reports_the_executing_line_number() -> None:
    """grblHAL (OPT N) adds ``Ln:`` while a numbered block runs; classic grbl does not."""
    hal = Emu(EmulatorConfig(flavor=Flavor.GRBLHAL))
    hal.send("N120 G1 X50 F3000\n")
    hal.run(0.1)
    assert hal.fields()["Ln"] == "120"
    classic = Emu()
    classic.send("N120 G1 X50 F3000\n")
    classic.run(0.1)
    assert "Ln" not in classic.fields()


def test_work_offsets_move_the_program_not_the_machine() -> None:
    """G10 L20 / G92 / G54-G59 shift the targets; MPos stays machine coordinates."""
    emu = Emu()
    emu.send("G0 X10 Y10\n")
    emu.run_until("Idle", 1.0)
    assert emu.send("G10 L20 P1 X0 Y0\nG0 X5 Y5\n") == ["ok", "ok"]
    emu.run_until("Idle", 1.0)
    assert emu.position() == (15.0, 15.0)
    assert emu.send("G55 G0 X1 Y1\n") == ["ok"]  # G55 is still at zero
    emu.run_until("Idle", 1.0)
    assert emu.position() == (1.0, 1.0)
    assert emu.send("G28 G91 X2\n") == ["ok"]  # via X+2, then X home (G28 is at zero)
    emu.run_until("Idle", 1.0)
    assert emu.position() == (0.0, 1.0)
