"""Forms real posts write that were refused (issue 31): HAL pins the daemon answers, a
nested comment and a Rosetta millisecond pierce delay refused in words a user can act on,
every refusal quoting the whole line as written."""

from __future__ import annotations

from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.materials import Material
from dthc_bridge.program.check import check_program
from dthc_bridge.program.plan import READABLE_PINS, detect_dialect
from tests.controller.test_sequence import ready

KERF_MATERIAL = Material(3, name="mild 3mm", kerf_width=1.2, pierce_height=3.8,
                         pierce_delay_s=0.4, cut_height=1.5, cut_speed=2400.0)  # fmt: skip


@pytest.mark.parametrize("pin", ["qtplasmac.kerf_width-f", "plasmac_run.kerf-width-f"])
def test_the_kerf_width_pins_read_the_material_in_force_in_the_programs_units(pin: str) -> None:
    """Today's QtPlasmaC pin and the 2019 PlasmaC one: G20 reads inches."""
    program = ["G20 G90", "M190 P3", "M66 P3 L3 Q1", f"#<kerf> = #<_hal[{pin}]>",
               "G0 X[1 + #<kerf>] Y1", "M3 $0 S1", "G1 X3 F#<_hal[plasmac.cut-feed-rate]>",
               "M5 $0"]  # fmt: skip
    report = check_program(program, dialect=Dialect.PLASMAC, materials={3: KERF_MATERIAL})
    assert report.ok, report.refused
    assert report.cuts[0].feed_mm_min == pytest.approx(2400.0)  # read in inch/min, run as mm


def test_the_float_switch_travel_pin_reads_the_configuration() -> None:
    """A SheetCam tube post's G92 Z[25.0 - #<_hal[plasmac.float-switch-travel]>]."""
    program = ["G21 G90", "#<keep-z-motion> = 1", "G38.2 Z-30 F300",
               "G92 Z[25.0 - #<_hal[plasmac.float-switch-travel]>]", "G0 Z3.8", "M3 $0 S1",
               "G1 X10 F2000", "M5 $0"]  # fmt: skip
    report = check_program(program, dialect=Dialect.PLASMAC)
    assert report.ok, report.refused


def test_an_unknown_pin_is_refused_naming_it_and_the_readable_ones() -> None:
    report = check_program(["G21", "#<x> = #<_hal[plasmac.arc-voltage-out]>", "M3", "M5"],
                           dialect=Dialect.PLASMAC)  # fmt: skip
    refused = report.refused[0]
    assert refused["text"] == "#<x> = #<_hal[plasmac.arc-voltage-out]>"  # the whole line
    assert "'plasmac.arc-voltage-out' is not one the daemon answers" in refused["error"]
    assert all(pin in refused["error"] for pin in READABLE_PINS)


@pytest.mark.parametrize("dialect", [Dialect.PLASMAC, Dialect.MASSO, Dialect.RELAY])
def test_a_nested_comment_is_called_one_and_the_whole_line_is_quoted(dialect: Dialect) -> None:
    line = '(*** FIXED: Pierce height 0.12" (was 0.15") ***)'
    report = check_program(["G20", line, "M3", "G1 X1 F100", "M5"], dialect=dialect)
    refused = report.refused[0]
    assert refused["line"] == 2
    assert refused["text"] == line
    assert "a comment inside a comment" in refused["error"]
    assert "nested parentheses" in refused["error"]


def test_a_rosetta_pierce_delay_in_milliseconds_names_its_word_unit_and_the_fix() -> None:
    line = "G100 P6 A1000 B-5 C300 D3.8 E400 F3 H1.5"
    report = check_program(["G21", line, "G1 X1 F100", "M5"], dialect=Dialect.ROSETTA)
    refused = report.refused[0]
    assert refused["text"] == line
    assert refused["error"] == (
        "G100 P6 E: pierce delay 400 s is out of range 0..10 (seconds); 400 looks like "
        "milliseconds: E0.4 is 0.4 s"
    )
    good = line.replace("E400", "E0.4")
    for bad, word in (("D30", "G100 P6 D"), ("H12", "G100 P6 H"), ("C5000", "G100 P6 C")):
        wrong = good.replace({"D": "D3.8", "H": "H1.5", "C": "C300"}[bad[0]], bad)
        error = check_program(["G21", wrong, "M5"], dialect=Dialect.ROSETTA).refused[0]["error"]
        assert error.startswith(f"{word}: "), error


def test_the_relay_dialect_is_detected_only_when_the_program_handles_z_itself() -> None:
    """A probe and its own Z origin: relay; a probe alone is a probe, not a relay program."""
    both, why = detect_dialect(["G21", "G38.2 Z-20 F100", "G92 Z0", "M3", "M5"])
    assert both is Dialect.RELAY
    assert "handles Z itself" in why
    probe_only, _ = detect_dialect(["G21", "G38.2 Z-20 F100", "G0 Z3", "M3", "M5"])
    assert probe_only is not Dialect.RELAY


TUBE = (Path(__file__).parents[1] / "programs" / "sheetcam_tube_plasmac.ngc").read_text()


def test_a_tube_programs_temporary_material_with_only_a_pierce_delay_is_accepted() -> None:
    """QtPlasmaC's filter: with #<tube-cut> = 1 an o=0 material may give only pd; pierce
    height, cut height and feed are 0 (the program probes, sets Z and feeds itself). The
    cut starts where the program put the torch, after the material's pierce delay."""
    report = check_program(TUBE.splitlines())
    assert report.ok, report.refused
    cut = report.cuts[0]
    assert (cut.sequence, cut.parameters) == ("relay", "program")
    assert cut.pierce_delay_s == 0.5
    assert cut.pierce_height_mm == 3.8  # its own G0 Z3.8
    assert not report.warnings


def test_without_tube_cut_a_material_without_its_heights_is_still_refused() -> None:
    lines = [line for line in TUBE.splitlines() if "tube-cut" not in line]
    refused = check_program(lines).refused[0]
    assert refused["text"] == "(o=0, pd=0.5)"
    assert "ph: required" in refused["error"]


def test_a_tube_cut_waits_its_pierce_delay_before_xy_moves() -> None:
    """On the closed loop: M3 is answered only after the arc transferred and pd passed."""
    loop = ready()
    defined = loop.complete(  # as the plan sends it: QtPlasmaC's defaults filled in
        loop.service.execute_gcode("(o=0, pd=0.5, ph=0, ch=0, fr=0)", dialect=Dialect.PLASMAC)
    )
    assert defined.ok, defined.error
    assert loop.gcode("G38.2 Z-50 F300").ok
    assert loop.gcode("G92 Z-1.5").ok
    assert loop.gcode("G0 Z3.8").ok
    before = loop.now
    reply = loop.m3()
    assert reply.ok, reply.error
    assert loop.sequence.cut is not None
    assert loop.sequence.cut.relay
    assert loop.sequence.cut.arc_ok_since is not None
    assert loop.now - loop.sequence.cut.arc_ok_since >= 0.5  # the pierce delay, then M3
    assert loop.now - before >= 0.5


def test_a_zero_origin_where_a_probe_down_stopped_is_warned_once_and_an_offset_is_not() -> None:
    """A generic grbl post: G38.2 then G92 Z0. On a float switch Z0 is then the switch's
    travel below the surface and every height lower by it (the demo cut at 0 mm): the check
    says so, once; with the offset written, or after a Z move, it says nothing."""
    body = ["G21 G90", "G38.2 Z-30 F250", "G92 Z0", "G0 Z3.5", "M3", "G1 X50 F2000", "M5"]
    warned = check_program(body, dialect=Dialect.RELAY)
    assert warned.ok
    said = [w for w in warned.warnings if "Z0 set where the probe stopped" in w]
    assert len(said) == 1
    assert said[0].startswith("line 3:")
    offset = check_program([*body[:2], "G92 Z-1.5", *body[3:]], dialect=Dialect.RELAY)
    assert not [w for w in offset.warnings if "probe stopped" in w]
    moved = check_program([*body[:2], "G0 Z5", "G92 Z0", *body[3:]], dialect=Dialect.RELAY)
    assert not [w for w in moved.warnings if "probe stopped" in w]
