"""The emulator's serial protocol, without processes: banner, answers, $ commands, reports."""

from __future__ import annotations

import pytest

from dthc_tools.grbl_emu import EmulatorConfig, Flavor, GrblFirmware

from .emu_helpers import Emu


def test_banner_at_power_on_and_after_a_reset_per_flavor() -> None:
    """Classic grbl and grblHAL greet with their own welcome line, after a blank line."""
    classic = GrblFirmware(EmulatorConfig())
    assert classic.read() == b"\r\nGrbl 1.1f ['$' for help]\r\n"
    hal = GrblFirmware(EmulatorConfig(flavor=Flavor.GRBLHAL))
    assert hal.read() == b"\r\nGrblHAL 1.1f ['$' or '$HELP' for help]\r\n"
    classic.receive(b"\x18", 0.0)
    assert classic.read() == b"\r\nGrbl 1.1f ['$' for help]\r\n"


@pytest.mark.parametrize(
    ("flavor", "rx", "blocks", "expected"),
    [
        (Flavor.GRBL, 0, 0, ["[VER:1.1f.20170801:]", "[OPT:V,15,128]", "ok"]),
        (Flavor.GRBL, 256, 20, ["[VER:1.1f.20170801:]", "[OPT:V,20,256]", "ok"]),
        (
            Flavor.GRBLHAL,
            0,
            0,
            [
                "[VER:1.1f.20260801:]",
                "[OPT:VNML+,35,1024,3,0]",
                "[FIRMWARE:grblHAL]",
                "[DRIVER:emulated]",
                "ok",
            ],
        ),
    ],
)
def test_build_info_reports_the_planner_blocks_and_rx_buffer_it_was_given(
    flavor: Flavor, rx: int, blocks: int, expected: list[str]
) -> None:
    """``$I`` carries ``[OPT:...,blocks,rx]`` from the command line, as a sender reads it."""
    emu = Emu(EmulatorConfig(flavor=flavor, rx_buffer_bytes=rx, planner_blocks=blocks))
    assert emu.send("$I\n") == expected


def test_settings_listing_carries_the_motion_limits_from_the_command_line() -> None:
    """``$$``: $110/$111 max rate, $120/$121 acceleration, $130/$131 travel, then ok."""
    emu = Emu(EmulatorConfig(accel_mm_s2=900.0, max_rate_mm_min=8000.0, max_travel_mm=(600, 400)))
    lines = emu.send("$$\n")
    assert lines[-1] == "ok"
    settings = dict(line.split("=") for line in lines[:-1])
    assert settings["$110"] == settings["$111"] == "8000.000"
    assert settings["$120"] == settings["$121"] == "900.000"
    assert (settings["$130"], settings["$131"]) == ("600.000", "400.000")
    assert settings["$10"] == "3"  # MPos and buffer state
    assert settings["$11"] == "0.050"


def test_parser_state_and_parameters() -> None:
    """``$G`` shows the modal state (it follows the lines); ``$#`` the offsets."""
    emu = Emu()
    assert emu.send("$G\n") == ["[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]
    assert emu.send("G91 G1 F1500\nG55\n$G\n")[-2:] == [
        "[GC:G1 G55 G17 G21 G91 G94 M5 M9 T0 F1500 S0]",
        "ok",
    ]
    lines = emu.send("$#\n")
    assert lines[0] == "[G54:0.000,0.000,0.000]"
    assert "[G92:0.000,0.000,0.000]" in lines
    assert lines[-1] == "ok"


@pytest.mark.parametrize(
    ("line", "code"),
    [
        ("1G0", 1),  # no letter
        ("G1 X", 2),  # no number
        ("G1 X1.2.3", 1),  # the second point starts a word without a letter
        ("$X1", 3),  # $ statement not recognised
        ("$100", 3),  # a setting without '='
        ("G1 F-10 X1", 4),  # negative feed
        ("$H", 5),  # homing not enabled
        ("G38.9 X1", 20),  # unsupported command
        ("G90.1", 20),  # grbl has only G91.1 (incremental IJK arcs)
        ("M7", 20),  # no mist coolant on classic grbl
        ("G0 G1 X1", 24),  # two motion commands both wanting the axis words...
        ("G17 G18", 21),  # ...two commands of one modal group
        ("G1 X10", 22),  # no feed rate yet
        ("G1.5 X1", 23),  # not an integer command
        ("G0 X1 X2", 25),  # repeated word
        ("G92", 26),  # G92 needs axis words
        ("N10000000 G0 X1", 27),  # line number out of range
        ("G4", 28),  # dwell without P
        ("G53 G2 X1 I1 F100", 30),  # G53 with an arc
        ("G80 X1", 31),  # axis words with G80
        ("G2 Z1 I1 F100", 32),  # no axis word in the plane
        ("G2 X0 Y20 I100 J0 F100", 33),  # radii differ
        ("G2 X100 R10 F100", 34),  # radius too short to reach
        ("G2 X10 F100", 35),  # no I or J
        ("G0 X1 I5", 36),  # I unused
        ("T300", 38),  # tool number
        ("A10", 20),  # no A axis
    ],
)
def test_refused_lines_get_grbls_error_numbers(line: str, code: int) -> None:
    """Each refusal carries the number grbl 1.1 documents for it."""
    emu = Emu()
    assert emu.send(line + "\n") == [f"error:{code}"]


def test_line_longer_than_the_line_buffer_is_error_11_and_spaces_do_not_count() -> None:
    """Classic grbl keeps 79 characters after removing blanks and comments: more is error:11."""
    emu = Emu()
    body = "G1F1000X1." + "0" * 69  # 79 characters
    assert len(body) == 79
    assert emu.send(body + "\n") == ["ok"]
    assert emu.send(body + "Y\n") == ["error:11"]
    spaced = " ".join(body) + " (a comment that does not count) ; nor this"
    assert emu.send(spaced + "\n") == ["ok"]
    hal = Emu(EmulatorConfig(flavor=Flavor.GRBLHAL))
    assert hal.send(body + "0" * 100 + "\n") == ["ok"]


def test_crlf_is_two_line_ends_on_classic_grbl_and_one_on_grblhal() -> None:
    """A sender ending lines with CR LF gets two answers from classic grbl (it counts one)."""
    assert Emu().send("G21\r\n") == ["ok", "ok"]
    assert Emu(EmulatorConfig(flavor=Flavor.GRBLHAL)).send("G21\r\n") == ["ok"]
    assert Emu(EmulatorConfig(flavor=Flavor.GRBLHAL)).send("\n\n") == ["ok", "ok"]


def test_status_report_fields_when_idle() -> None:
    """``<Idle|MPos:x,y,z|Bf:blocks,rx|FS:feed,speed|...|Ov:100,100,100>``, 3 decimals."""
    emu = Emu()
    report = emu.status()
    assert report.startswith("<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0|")
    assert report.endswith("|Ov:100,100,100>")
    # WCO comes with the first report after a reset, then every tenth.
    reports = [emu.status() for _ in range(20)]
    assert ["WCO:" in r for r in reports].count(True) == 2
    assert "WCO:" not in reports[0]


def test_wpos_reporting_subtracts_the_work_offset() -> None:
    """``--report wpos``: WPos = MPos - WCO; G92 changes WCO at once."""
    emu = Emu(EmulatorConfig(report_wpos=True))
    assert emu.send("G0 X10 Y5\n") == ["ok"]
    emu.run(0.5)
    assert emu.send("G92 X0 Y0\n") == ["ok"]
    fields = emu.fields()
    assert fields["WPos"] == "0.000,0.000,0.000"
    assert fields["WCO"] == "10.000,5.000,0.000"


def test_dollar_commands_follow_grbls_state_rules() -> None:
    """``$$`` is refused while moving (error:8); ``$G`` is always served; help lists commands."""
    emu = Emu()
    assert emu.send("$\n")[0].startswith("[HLP:$$ $# $G $I")
    emu.send("G1 X100 F3000\n")
    emu.run(0.1)
    assert emu.send("$$\n") == ["error:8"]
    assert emu.send("$I\n") == ["error:8"]
    assert emu.send("$G\n")[-1] == "ok"


def test_setting_writes_are_checked_and_change_what_is_reported() -> None:
    """``$13=1`` reports inches; unknown settings and negative values are refused."""
    emu = Emu()
    assert emu.send("$13=1\n") == ["ok"]
    emu.send("G0 X25.4\n")
    emu.run(1.0)
    assert emu.fields()["MPos"] == "1.0000,0.0000,0.0000"
    assert emu.send("$999=1\n") == ["error:3"]
    assert emu.send("$120=-5\n") == ["error:4"]
    assert emu.send("$120=abc\n") == ["error:2"]


def test_check_mode_parses_without_moving_and_resets_on_exit() -> None:
    """``$C``: lines are answered but nothing moves; leaving it resets (banner)."""
    emu = Emu()
    assert emu.send("$C\n") == ["[MSG:Enabled]", "ok"]
    assert emu.send("G1 X50 F1000\nG4 P10\n") == ["ok", "ok"]
    assert emu.fields()["state"] == "Check"
    emu.run(0.2)
    assert emu.position() == (0.0, 0.0)
    assert emu.send("$C\n") == ["[MSG:Disabled]", "ok", "Grbl 1.1f ['$' for help]"]
    assert emu.fields()["state"] == "Idle"


def test_z_and_spindle_words_are_accepted_like_grbl_and_counted() -> None:
    """This table's Z and torch belong to another board: the words are counted for tests."""
    emu = Emu()
    assert emu.send("G0 Z5\nM3 S1000\nG1 X1 Z-1 F1000\nM5\nM30\n") == ["ok"] * 4
    assert emu.run(0.5) == ["[MSG:Pgm End]", "ok"]
    assert emu.fw.stats.z_words_received == 2
    assert emu.fw.stats.spindle_words_received == 3  # M3, S1000, M5; M30 is not one
    assert emu.fields()["MPos"].endswith(",-1.000")


def test_spindle_speed_shows_in_fs_only_while_the_spindle_is_on() -> None:
    """``FS:feed,speed``: the speed is the programmed S while M3/M4 is active."""
    emu = Emu()
    emu.send("S1200 M3\n")
    assert emu.fields()["FS"] == "0,1200"
    emu.send("M5\n")
    assert emu.fields()["FS"] == "0,0"


def test_startup_lines_are_checked_stored_and_run_after_a_reset() -> None:
    """``$N0=line``: refused if it does not parse; run (``>line:ok``) after each reset."""
    emu = Emu()
    assert emu.send("$N0=G1X\n") == ["error:2"]
    assert emu.send("$N0=G20 G91\n") == ["ok"]
    assert emu.send("$N\n") == ["$N0=G20G91", "$N1=", "ok"]
    assert emu.send("$G\n")[0].startswith("[GC:G0 G54 G17 G21 G90")  # stored, not run
    assert emu.send(b"\x18") == ["Grbl 1.1f ['$' for help]", ">G20G91:ok"]
    assert emu.send("$G\n")[0].startswith("[GC:G0 G54 G17 G20 G91")


def test_build_info_text_and_restoring_defaults() -> None:
    """``$I=text`` shows in ``[VER:]``; ``$RST=*`` restores everything and resets."""
    emu = Emu()
    assert emu.send("$I=TABLE1\n$110=5000\n") == ["ok", "ok"]
    assert emu.send("$I\n")[0] == "[VER:1.1f.20170801:TABLE1]"
    assert emu.send("$RST=*\n") == [
        "[MSG:Restoring defaults]",
        "ok",
        "Grbl 1.1f ['$' for help]",
    ]
    assert emu.send("$I\n")[0] == "[VER:1.1f.20170801:]"
    assert "$110=10000.000" in emu.send("$$\n")
