"""check-program and the machine agree in every dialect (issue 31): each program in
tests/programs, with its shop's options, checked with ``--dialect`` each of masso,
plasmac, rosetta and relay (and detected), then run with the same dialect and options by
the reference sender against the daemon's controller service over the simulated board, in
simulated time (dthc_tools/sim/program.py: the demo's parts without the broker and the
processes; the real-time stack runs the detected dialect, tests/e2e/test_check_agrees*).

A program the check calls runnable in a dialect runs every cut it listed, one row each, no
fault and no safety violation; one it refuses stops at the line it refused first. Run
forced into a dialect not its own, a program is either run or refused by the check for
what the machine would stumble on (a relay M3 with no touch-off before it, a probe in a
PlasmaC program whose Z moves are stripped)."""

from __future__ import annotations

from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.program.check import check_program
from dthc_tools.demo.summary import summarize
from dthc_tools.sim.program import run_program

from ..program_shop import NC_NAMES, NGC_NAMES, assert_agree, shop_run

DIALECTS = [None, *Dialect]


@pytest.mark.parametrize("dialect", DIALECTS, ids=lambda d: str(d or "detected"))
@pytest.mark.parametrize("name", NC_NAMES + NGC_NAMES)
def test_check_program_and_the_machine_agree(
    name: str, dialect: Dialect | None, tmp_path: Path
) -> None:
    run = shop_run(name, tmp_path)
    check = run.check(dialect)
    result = run_program(run.lines, tmp_path, settings=run.settings(), dialect=dialect,
                         codes=run.codes)  # fmt: skip
    assert_agree(check, result.report, summarize(result, 50.0))


def test_forced_into_the_relay_dialect_a_program_that_does_not_touch_off_is_refused(
    tmp_path: Path,
) -> None:
    """In relay M3 is a bare torch relay: with no probe and Z origin before it the torch
    would fire at whatever height Z is. The check refuses it at that line, naming it, and
    the sender stops there with nothing lit; with the touch-off it runs."""
    lines = ["G21 G90", "G0 X10 Y10", "G0 Z3", "M3 (plasma on)", "G1 X60 F2000", "M5", "M30"]
    refused = check_program(lines, dialect=Dialect.RELAY)
    assert not refused.ok
    assert refused.refused[0]["line"] == 4
    assert refused.refused[0]["text"] == "M3 (plasma on)"
    assert "has not touched off" in refused.refused[0]["error"]
    result = run_program(lines, tmp_path, dialect=Dialect.RELAY)
    assert result.report.error_line == 4
    assert result.mock_exit["cuts"] == []
    touched = [*lines[:2], "G38.2 Z-40 F300", "G92 Z0", *lines[2:]]
    assert check_program(touched, dialect=Dialect.RELAY).ok
    ran = run_program(touched, tmp_path, dialect=Dialect.RELAY)
    assert ran.report.ok, ran.report.error
    assert len(ran.mock_exit["cuts"]) == 1


def test_a_probe_in_a_plasmac_program_whose_z_moves_are_stripped_is_refused(
    tmp_path: Path,
) -> None:
    """PlasmaC strips Z moves: after the program's own probe the torch would sit on the
    work, where M3 refuses to start. The check says so at the probe; with
    #<keep-z-motion> = 1 the program's own Z moves lift it and the cut runs."""
    body = ["G0 X30 Y30", "G38.2 Z-40 F300", "G92 Z0", "G0 Z3.8", "M3 $0 S1",
            "G1 X130 F2800", "M5 $0", "M30"]  # fmt: skip
    stripped = ["G21 G90", *body]
    refused = check_program(stripped, dialect=Dialect.PLASMAC)
    assert refused.refused[0]["line"] == 3
    assert refused.refused[0]["error"].startswith("G38.2: a PlasmaC program's Z moves")
    assert "#<keep-z-motion> = 1" in refused.refused[0]["error"]
    result = run_program(stripped, tmp_path, dialect=Dialect.PLASMAC)
    assert result.report.error_line == 3
    kept = ["G21 G90", "#<keep-z-motion> = 1", *body]
    assert check_program(kept, dialect=Dialect.PLASMAC).ok
    ran = run_program(kept, tmp_path, dialect=Dialect.PLASMAC)
    assert ran.report.ok, ran.report.error
    assert len(ran.mock_exit["cuts"]) == 1
