"""Each behaviour the emulator models, pinned to grbl 1.1's documented protocol.

Sources (gnea/grbl, the grbl 1.1 repository):
- ``doc/markdown/interface.md``: responses (``ok``, ``error:X``), the start-up message, the
  ``$`` help, feedback messages, status report construction and fields;
- ``doc/markdown/realtime_cmds.md``: the real-time bytes;
- ``doc/script/stream.py``: character counting against ``RX_BUFFER_SIZE = 128``, sending
  only while ``sum(c_line) < RX_BUFFER_SIZE - 1``.
Each test quotes the sentence it holds the emulator to. What the emulator does not model
(and where it knowingly differs) is listed in ``dthc_tools/grbl_emu/README.md``.
"""

from __future__ import annotations

import re

from .emu_helpers import Emu

BANNER = "Grbl 1.1f ['$' for help]"


def test_a_recognised_line_is_ok_and_an_empty_line_too() -> None:
    """interface.md: "Grbl will then respond either if it recognized the command with an
    `ok` line"; "If an empty line with only a return is sent to Grbl, it considers it a
    valid line and will return an `ok` too"."""
    emu = Emu()
    assert emu.send("G21 G90\n") == ["ok"]
    assert emu.send("\n") == ["ok"]


def test_a_refused_line_is_error_with_the_documented_number() -> None:
    """interface.md's error table: 1 "Letter was not found", 2 "Numeric value format is not
    valid or missing an expected value", 3 "'$' system command was not recognized", 20
    "Unsupported or invalid g-code command", 22 "Feed rate has not yet been set"; "did not
    execute anything inside that message"."""
    emu = Emu()
    assert emu.send("1\n") == ["error:1"]
    assert emu.send("$J X1\n") == ["error:3"]  # a jog without its '='
    assert emu.send("$Z\n") == ["error:2"]  # grbl reads $<letter> as a setting number
    assert emu.send("G5 X1\n") == ["error:20"]
    assert emu.send("G1 X1\n") == ["error:22"]
    assert emu.position() == (0.0, 0.0)  # nothing of the refused lines ran


def test_the_start_up_message_comes_at_power_on_and_after_every_reset() -> None:
    """interface.md: "`Grbl X.Xx ['$' for help]` ... always prints upon startup and after a
    reset"; realtime_cmds.md: 0x18 "Immediately halts and resets Grbl"."""
    emu = Emu()
    emu.fw = type(emu.fw)(emu.fw.config, now_s=0.0)
    assert emu.lines() == [BANNER]
    assert emu.send(b"\x18") == [BANNER]


def test_a_status_report_is_chevrons_pipes_state_then_position() -> None:
    """interface.md: "`< >` Chevrons uniquely enclose reports"; "`|` Pipe delimiters
    separate data fields"; "The first (Machine State) and second (Current Position) data
    fields are always included"; "Three position values are given in the order of X, Y,
    and Z"; "`Bf:15,128`. The first value is the number of available blocks in the planner
    buffer and the second is number of available bytes in the serial RX buffer"; "Valid
    states types: `Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep`"."""
    emu = Emu()
    emu.send("G1 X2 Y1 F600\n")
    emu.run(0.05)
    moving = emu.status()
    emu.run_until("Idle", 5.0)
    idle = emu.status()
    for report in (moving, idle):
        assert re.fullmatch(
            r"<[A-Za-z]+(:\d)?\|[MW]Pos:(-?\d+\.\d{3},){2}-?\d+\.\d{3}(\|[A-Za-z]+:[^|>]*)*>",
            report,
        )
    assert moving.startswith("<Run|")
    assert idle.startswith("<Idle|MPos:2.000,1.000,0.000|")
    assert emu.fields()["Bf"] == "15,128"  # idle: every block and byte free


def test_work_position_is_machine_position_less_the_work_offset() -> None:
    """interface.md: "Machine position and work position are related by this simple equation
    per axis: `WPos = MPos - WCO`"; WCO appears "In the first report after a reset"."""
    emu = Emu()
    emu.send("G92 X10 Y5\n")
    fields = emu.fields()
    assert fields["MPos"] == "0.000,0.000,0.000"
    assert fields["WCO"] == "-10.000,-5.000,0.000"
    emu.send(b"\x18")
    emu.lines()
    assert "WCO" in emu.fields()  # the first report after a reset


def test_a_question_mark_never_enters_the_buffer_and_needs_no_line_end() -> None:
    """interface.md: "the '?' character is intercepted and never enters the serial buffer.
    It's never a part of the stream and can be sent at any time"; realtime_cmds.md: "Does not
    require a line feed or carraige return after them"."""
    emu = Emu()
    answers = emu.send(b"G21?G90\n")
    assert answers[0].startswith("<Idle|")
    assert answers[1:] == ["ok"]  # one line: G21G90


def test_feed_hold_then_cycle_start() -> None:
    """realtime_cmds.md: `!` "If in motion, the machine will decelerate to a stop and then
    be suspended"; `~` "Resumes a feed hold"; interface.md: "`Hold:0` Hold complete. Ready
    to resume." "`Hold:1` Hold in-progress"."""
    emu = Emu()
    emu.send("G1 X50 F3000\n")
    emu.run(0.3)
    emu.send(b"!")
    assert emu.fields()["state"] == "Hold:1"
    emu.run_until("Hold:0", 2.0)
    x_held, _ = emu.position()
    emu.run(0.5)
    assert emu.position()[0] == x_held
    emu.send(b"~")
    emu.run_until("Idle", 5.0)
    assert emu.position() == (50.0, 0.0)


def test_overrides_by_their_bytes_within_the_documented_range() -> None:
    """realtime_cmds.md: 0x91 "Increase 10%", "Feed override value can not be ... greater
    than 200%", 0x90 "Set 100% of programmed rate"; 0x96 "Set to 50% of rapid rate", 0x97
    "Set to 25%", 0x95 "Set to 100%"; interface.md: "`Ov:100,100,100` indicates current
    override values in percent of programmed values for feed, rapids, and spindle speed"."""
    emu = Emu()
    assert emu.fields()["Ov"] == "100,100,100"
    emu.send(b"\x91" * 15)
    assert emu.fields()["Ov"] == "200,100,100"
    emu.send(b"\x90\x96")
    assert emu.fields()["Ov"] == "100,50,100"
    emu.send(b"\x97")
    assert emu.fields()["Ov"] == "100,25,100"
    emu.send(b"\x95")
    assert emu.fields()["Ov"] == "100,100,100"


def test_reset_while_moving_raises_alarm_3_and_locks_g_code_until_unlock() -> None:
    """realtime_cmds.md: "If reset while in motion, Grbl will throw an alarm"; interface.md:
    ALARM 3 "Reset while in motion"; error 9 "G-code locked out during alarm"; `$X` gives
    "`[MSG:Caution: Unlocked]` ... An 'ok' still appears immediately after"."""
    emu = Emu()
    emu.send("G1 X50 F3000\n")
    emu.run(0.2)
    answers = emu.send(b"\x18")
    assert answers[0] == "ALARM:3"
    assert BANNER in answers
    assert emu.send("G0 X1\n") == ["error:9"]
    assert emu.send("$X\n") == ["[MSG:Caution: Unlocked]", "ok"]
    assert emu.send("G0 X1\n") == ["ok"]


def test_dollar_commands_answer_as_documented() -> None:
    """interface.md: `$` gives "`[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~
    ! ? ctrl-x]`"; `$G` "`[GC:` ... followed by a separate `ok`"; `$#` "[G54:] ... [TLO:]
    and [PRB:]" then `ok`; `$I` "`[VER:]` and `[OPT:]` ... followed by an `ok`"; `$N`
    "`$N0=` `$N1=` `ok`"; `$C` "`[MSG:Enabled]`" / "`[MSG:Disabled]` ... Grbl is
    automatically reset afterwards"; `$$` "`$x=val` ... completes with an `ok`"; error 8
    "'$' command cannot be used unless Grbl is IDLE"."""
    emu = Emu()
    assert emu.send("$\n") == [
        "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]",
        "ok",
    ]
    gc, ok = emu.send("$G\n")
    assert re.fullmatch(r"\[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0\]", gc)
    assert ok == "ok"
    params = emu.send("$#\n")
    assert [p.split(":")[0] for p in params[:-1]] == [
        "[G54", "[G55", "[G56", "[G57", "[G58", "[G59", "[G28", "[G30", "[G92", "[TLO",
        "[PRB",
    ]  # fmt: skip
    assert params[-1] == "ok"
    ver, opt, ok = emu.send("$I\n")
    assert re.fullmatch(r"\[VER:1\.1f\.\d{8}:.*\]", ver)
    assert opt.startswith("[OPT:")
    assert ok == "ok"
    assert emu.send("$N\n") == ["$N0=", "$N1=", "ok"]
    assert emu.send("$C\n") == ["[MSG:Enabled]", "ok"]
    assert emu.send("$C\n") == ["[MSG:Disabled]", "ok", BANNER]
    settings = emu.send("$$\n")
    assert settings[-1] == "ok"
    assert all(re.fullmatch(r"\$\d+=[-\d.]+", line) for line in settings[:-1])
    assert {"$110", "$120", "$130"} <= {line.split("=")[0] for line in settings}
    emu.send("G1 X50 F3000\n")
    emu.run(0.1)
    assert emu.send("$$\n") == ["error:8"]


def test_the_rx_buffer_holds_127_bytes_and_loses_the_128th() -> None:
    """stream.py counts every line's characters (newline included) against
    ``RX_BUFFER_SIZE = 128`` and sends only while ``sum(c_line) < RX_BUFFER_SIZE - 1``:
    127 unanswered bytes fit while the controller is busy; a byte more is lost. Bf's second
    value is the bytes still free (interface.md)."""
    emu = Emu()
    emu.send("G4 P5\n")  # the parser waits on the dwell: what follows stays in the buffer
    emu.run(0.1)
    data = ("G0 X1 Y1     \n" * 10)[:127]
    emu.send(data)
    assert emu.fw.stats.rx_overflow == 0
    assert emu.fields()["Bf"] == "15,1"
    emu.send(b"G")
    assert emu.fw.stats.rx_overflow == 1
