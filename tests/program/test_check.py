"""``dthc-bridge check-program``: every dialect and form, as a user runs it before cutting.

The programs in ``tests/programs`` are ours, written in the forms real posts and table
owners use (SheetCam PlasmaC posts, hand-written NGC, FireControl-style relay programs, the
MASSO Fusion post, RosettaCNC G100). Each is checked here; one per dialect also runs end to
end in ``tests/e2e/test_real_programs.py``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.materials import MaterialStore
from dthc_bridge.program.check import CheckReport, CutReport, check_program

PROGRAMS = Path(__file__).parents[1] / "programs"
MATERIALS = PROGRAMS / "shop_material.cfg"
INCH_MATERIALS = PROGRAMS / "shop_material_inch.cfg"


def lines(name: str) -> list[str]:
    return (PROGRAMS / name).read_text(encoding="utf-8").splitlines()


def check(name: str, **kwargs: object) -> CheckReport:
    materials = kwargs.pop("materials", None)
    if isinstance(materials, Path):
        kwargs["materials"] = MaterialStore(materials).load()
    return check_program(lines(name), **kwargs)  # type: ignore[arg-type]


def only(report: CheckReport) -> CutReport:
    assert len(report.cuts) == 1, report.cuts
    return report.cuts[0]


# --------------------------------------------------------------------------- PlasmaC


def test_sheetcam_inch_post_with_a_material_from_an_inch_library() -> None:
    report = check("sheetcam_plasmac_inch.ngc", materials=INCH_MATERIALS, inch_materials=True)
    assert report.ok, report.refused
    assert report.dialect == "plasmac"
    assert [cut.line for cut in report.cuts] == [16, 25]
    for cut in report.cuts:
        assert (cut.material, cut.material_name) == (2, "1/4 mild steel 65A")
        assert cut.parameters == "material"
        assert cut.pierce_height_mm == pytest.approx(0.16 * 25.4)
        assert cut.pierce_delay_s == pytest.approx(0.6)
        assert cut.cut_height_mm == pytest.approx(0.06 * 25.4)
        assert cut.target_v == 128.0
        assert cut.feed_mm_min == pytest.approx(80 * 25.4)  # CUT_SPEED 80 in/min
        assert cut.thc
    # The G0 Z0.75 safe moves are stripped, as PlasmaC does, and said so.
    assert any("3 Z moves stripped" in w for w in report.warnings)


def test_m190_p_minus_1_returns_to_the_default_material_in_mm_on_an_inch_machine() -> None:
    # Material 0 is the daemon's default (mm); only library materials are in inches.
    report = check("sheetcam_plasmac_inch.ngc", materials=INCH_MATERIALS, inch_materials=True)
    assert not any("M190 P-1" in r["text"] for r in report.refused)


def test_a_metric_program_gets_an_inch_materials_feed_in_mm() -> None:
    report = check("plasmac_refusals.ngc", materials=INCH_MATERIALS, inch_materials=True)
    assert only(report).feed_mm_min == pytest.approx(160 * 25.4)


def test_material_change_and_magic_comment_material() -> None:
    report = check("plasmac_material_overcut.ngc", materials=MATERIALS)
    assert report.ok, report.refused
    first, second = report.cuts
    assert (first.material, first.feed_mm_min, first.pierce_delay_s) == (3, 3000.0, 0.3)
    assert second.material is not None
    assert second.material >= 1_000_000
    assert (second.feed_mm_min, second.pierce_delay_s) == (2500.0, 0.2)


def test_parametric_program_unrolls_loops_and_subroutines() -> None:
    report = check("plasmac_parametric.ngc")
    assert report.ok, report.refused
    # three slots from the repeat loop, one from the if branch: all start at the sub's M3
    assert len(report.cuts) == 4
    assert {cut.line for cut in report.cuts} == {10}
    assert {cut.material_name for cut in report.cuts} == {"scrap 3mm"}
    assert {cut.target_v for cut in report.cuts} == {None}  # no cv: auto voltage
    # #<keep-z-motion> = 1 at the top level holds inside the subroutine: nothing stripped.
    assert not any("stripped" in w for w in report.warnings)


def test_pierce_only_still_lists_every_pierce() -> None:
    report = check("plasmac_pierce_only.ngc", materials=INCH_MATERIALS, inch_materials=True)
    assert report.ok, report.refused
    assert [cut.line for cut in report.cuts] == [10, 15]


def test_refused_lines_are_listed_with_their_reasons_and_the_rest_still_checked() -> None:
    report = check("plasmac_refusals.ngc", materials=INCH_MATERIALS, inch_materials=True)
    assert not report.ok
    assert [(r["line"], r["text"]) for r in report.refused] == [
        (9, "M3 $1 S1 (scribe)"),
        (11, "M5 $1"),
        (12, "M64 P0"),
    ]
    assert "scribe is not on this board" in report.refused[0]["error"]
    assert "P2 (THC) and P3 (torch)" in report.refused[2]["error"]
    assert only(report).line == 13


def test_a_material_the_library_lacks_is_refused_and_the_rest_still_checked() -> None:
    report = check("sheetcam_plasmac_inch.ngc")  # no library given
    assert [r["line"] for r in report.refused] == [11]
    assert report.refused[0]["error"] == "M190 P2: no material 2"
    # The feed reads the material in force (the default, 3000 mm/min), as PlasmaC's pin does.
    assert [cut.parameters for cut in report.cuts] == ["default", "default"]
    assert [cut.feed_mm_min for cut in report.cuts] == [pytest.approx(3000.0)] * 2


def test_an_ngc_structure_error_names_what_the_user_wrote() -> None:
    report = check_program(["G21", "o100 endrepeat", "M2"], dialect=Dialect.PLASMAC)
    assert report.refused == [
        {"line": 2, "text": "o100 endrepeat", "error": report.refused[0]["error"]}
    ]
    assert "o100 endrepeat" in report.refused[0]["error"]
    assert "no open 'o100 repeat'" in report.refused[0]["error"]


def test_plasmac_without_t0_m6_starts_on_a_plasma_only_table_and_not_on_a_shared_one() -> None:
    """M3 $0 is PlasmaC's torch with no tool change: a plasma table's default starts it; a
    table with other tools (plasma_mode_at_start false) still wants T0 M6 first."""
    program = ["G21 G90", "G0 X5 Y5", "M3 $0 S1", "G1 X9", "M5 $0"]
    assert len(only_ok(check_program(program)).cuts) == 1
    report = check_program(program, plasma_mode_at_start=False)
    assert [r["line"] for r in report.refused] == [3]
    assert "T0 M6" in report.refused[0]["error"]
    assert "controller.plasma_mode_at_start = false" in report.refused[0]["error"]


def only_ok(report: CheckReport) -> CheckReport:
    assert report.ok, report.refused
    return report


def test_a_tool_change_on_a_plasma_only_table_is_a_note_not_a_refusal() -> None:
    """A 2008 SheetCam post's M06 T1 (its plasma tool): neither the scribe nor a reason to
    leave plasma mode."""
    for dialect in (Dialect.PLASMAC, Dialect.MASSO):
        report = only_ok(check_program(
            ["G21 G90", "M06 T1 F5840 (Plasma 80A 3mm)", "G0 X5 Y5", "M3", "G1 X9 F2000", "M5"],
            dialect=dialect,
        ))  # fmt: skip
        assert len(report.cuts) == 1
    shared = check_program(["G21", "T1 M6", "M3", "G1 X9 F2000", "M5"], dialect=Dialect.MASSO,
                           plasma_mode_at_start=False)  # fmt: skip
    assert [r["line"] for r in shared.refused] == [3]  # MASSO: T1 left plasma mode


# --------------------------------------------------------------------------- relay


def test_relay_program_reports_the_programs_own_heights_and_dwell() -> None:
    cut = only(check("relay_self_probe.nc"))
    assert (cut.sequence, cut.parameters) == ("relay", "program")
    assert cut.pierce_height_mm == 3.8  # its G0 Z3.8 before M03
    assert cut.pierce_delay_s == 0.4  # its G4 P0.4 (seconds in grbl)
    assert cut.cut_height_mm == 1.5  # its G1 Z1.5 after the dwell
    assert cut.thc  # switched on by H1 during the cut
    assert cut.feed_mm_min == 2800.0


def test_a_shops_own_torch_codes_are_mapped_and_reported_as_written() -> None:
    unmapped = check("firecontrol_relay.nc")
    assert not unmapped.ok  # no cut, and codes nobody knows: not "OK, 0 cuts"
    assert not unmapped.cuts
    errors = [r["error"] for r in unmapped.refused]
    assert errors[0].startswith("M10: not a code the daemon knows")
    assert "--code M10=M3 --code M11=M5" in errors[0]

    report = check("firecontrol_relay.nc", codes={"M10": "M3", "M11": "M5"})
    cut = only(report)
    assert cut.text == "M10 (torch on, this shop's post)"
    assert cut.pierce_height_mm == pytest.approx(0.15 * 25.4)  # G20: inches
    assert cut.cut_height_mm == pytest.approx(0.06 * 25.4)
    assert cut.pierce_delay_s == 0.5
    assert cut.feed_mm_min == pytest.approx(110 * 25.4)
    assert cut.thc
    assert not report.warnings


def test_a_relay_cut_with_no_z_known_has_no_pierce_height() -> None:
    """Touched off (probe, G92 Z), then lit where the probe left the torch."""
    program = ["G21", "G38.2 Z-40 F300", "G92 Z0", "M3", "G1 X10 F2000", "M5"]
    report = check_program(program, dialect=Dialect.RELAY)
    assert only(report).pierce_height_mm is None
    json.dumps(report.as_dict(), allow_nan=False)  # valid JSON: no NaN


# --------------------------------------------------------------------------- MASSO


def test_masso_g200_change_to_stop_after_pierce_midway() -> None:
    report = check("masso_s1_midway.nc")
    assert report.ok, report.refused
    assert report.dialect == "masso"
    assert [cut.parameters for cut in report.cuts] == ["G200", "G200"]
    assert [cut.target_v for cut in report.cuts] == [None, None]  # V0: auto voltage
    assert all(cut.thc for cut in report.cuts)  # M667 after M3


def test_masso_fusion_post_needs_plasma_mode_at_start() -> None:
    refused = check("masso_fusion.nc", plasma_mode_at_start=False)
    assert [r["line"] for r in refused.refused] == [5]
    assert "--plasma-mode-at-start" in refused.refused[0]["error"]

    report = check("masso_fusion.nc")  # the default: a plasma-only table
    cut = only(report)
    assert (cut.parameters, cut.sequence) == ("default", "automatic")
    assert cut.feed_mm_min == 2600.0
    assert cut.thc


def test_in_masso_hash_is_a_comment_and_in_plasmac_it_is_a_parameter() -> None:
    program = ["T112 M6", "G0 X1 # go", "M3", "G1 X5 F2000", "M5"]
    assert check_program(program).ok
    refused = check_program(program, dialect=Dialect.PLASMAC)
    assert [r["line"] for r in refused.refused] == [2]


# --------------------------------------------------------------------------- RosettaCNC


def test_rosetta_g100_p6_cut() -> None:
    report = check("rosetta_g100.ngc")
    assert report.dialect == "rosetta"
    cut = only(report)
    assert cut.parameters == "G100 P6"
    assert (cut.pierce_height_mm, cut.pierce_delay_s, cut.cut_height_mm) == (3.8, 0.4, 1.5)
    assert cut.target_v == 128.0  # G100 P5 A0 B128
    assert cut.thc  # G100 P7 A1
    assert not report.warnings


# --------------------------------------------------------------------------- dialects


@pytest.mark.parametrize(
    ("name", "dialect"),
    [
        ("sheetcam_plasmac_inch.ngc", "plasmac"),
        ("plasmac_parametric.ngc", "plasmac"),
        ("relay_self_probe.nc", "relay"),
        ("firecontrol_relay.nc", "relay"),
        ("masso_s1_midway.nc", "masso"),
        ("masso_fusion.nc", "masso"),
        ("rosetta_g100.ngc", "rosetta"),
    ],
)
def test_the_dialect_is_detected_and_the_report_says_why(name: str, dialect: str) -> None:
    report = check(name, materials=INCH_MATERIALS, inch_materials=True)
    assert report.dialect == dialect
    assert report.dialect_reason.startswith("found")


def test_a_given_dialect_is_used_as_given() -> None:
    report = check("relay_self_probe.nc", dialect=Dialect.RELAY)
    assert (report.dialect, report.dialect_reason) == ("relay", "given")


# --------------------------------------------------------------------------- command line


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "check-program", *args],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip


def test_cli_json_is_one_object_and_exit_status_is_0_when_nothing_is_refused() -> None:
    result = run_cli(
        str(PROGRAMS / "sheetcam_plasmac_inch.ngc"), "--materials", str(INCH_MATERIALS),
        "--inch-materials", "--json",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    assert {"ok", "cuts", "refused", "warnings", "dialect"} <= doc.keys()
    assert doc["ok"] is True
    assert doc["refused"] == []
    assert len(doc["cuts"]) == 2
    assert {"line", "material", "pierce_height_mm", "cut_height_mm", "target_v",
            "feed_mm_min", "anti_dive_percent"} <= doc["cuts"][0].keys()  # fmt: skip


def test_cli_exit_status_is_1_when_a_line_is_refused() -> None:
    result = run_cli(str(PROGRAMS / "plasmac_refusals.ngc"), "--json")
    assert result.returncode == 1
    doc = json.loads(result.stdout)
    assert doc["ok"] is False
    by_line = {refused["line"]: refused for refused in doc["refused"]}
    assert by_line[5]["error"] == "M190 P1: no material 1"  # no --materials given
    assert by_line[9]["text"] == "M3 $1 S1 (scribe)"


def test_cli_text_report_and_options() -> None:
    result = run_cli(
        str(PROGRAMS / "firecontrol_relay.nc"), "--dialect", "relay",
        "--code", "M10=M3", "--code", "M11=M5",
    )  # fmt: skip
    assert result.returncode == 0, result.stdout
    assert "dialect relay (given)" in result.stdout
    assert "cut 1 at line 8 (relay): the program's own heights; pierce 3.81 mm" in result.stdout
    assert result.stdout.rstrip().endswith("OK: 1 cut(s)")


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--dialect", "fanuc"], "'fanuc' is not a dialect"),
        (["--code", "H1"], "expected CODE=LINE"),
    ],
)
def test_cli_bad_options_name_what_the_user_wrote(args: list[str], says: str) -> None:
    result = run_cli(str(PROGRAMS / "relay_self_probe.nc"), *args)
    assert result.returncode == 2
    assert says in result.stderr


def test_cli_unreadable_files_exit_2_naming_them(tmp_path: Path) -> None:
    missing = tmp_path / "nope.ngc"
    result = run_cli(str(missing))
    assert result.returncode == 2
    assert "nope.ngc" in result.stdout

    bad = tmp_path / "bad.cfg"
    bad.write_text("[MATERIAL_NUMBER_1]\nNAME = x\n", encoding="utf-8")
    result = run_cli(str(PROGRAMS / "relay_self_probe.nc"), "--materials", str(bad))
    assert result.returncode == 2
    assert "bad.cfg" in result.stdout


def test_cli_config_checks_as_that_daemon_runs(tmp_path: Path) -> None:
    """The daemon's dialect, code table, library and plasma mode; options still win."""
    config = tmp_path / "config.toml"
    config.write_text(
        "[controller]\n"
        'dialect = "relay"\n'
        f'materials_file = "{INCH_MATERIALS}"\n'
        "materials_in_inches = true\n"
        'codes = { M10 = "M3", M11 = "M5" }\n',
        encoding="utf-8",
    )
    relay = run_cli(str(PROGRAMS / "firecontrol_relay.nc"), "--config", str(config), "--json")
    assert relay.returncode == 0, relay.stdout
    assert [cut["line"] for cut in json.loads(relay.stdout)["cuts"]] == [8]

    plain = tmp_path / "plain.nc"
    plain.write_text("G21\nG0 Z3\nM3\nG1 X10 F2000\nM5\n", encoding="utf-8")
    doc = json.loads(run_cli(str(plain), "--config", str(config), "--json").stdout)
    assert doc["dialect"] == "relay"
    assert "controller.dialect" in doc["dialect_reason"]

    sheet = run_cli(str(PROGRAMS / "sheetcam_plasmac_inch.ngc"), "--config", str(config),
                    "--json")  # fmt: skip
    assert sheet.returncode == 0, sheet.stdout
    assert json.loads(sheet.stdout)["cuts"][0]["material_name"] == "1/4 mild steel 65A"

    overridden = run_cli(
        str(PROGRAMS / "firecontrol_relay.nc"), "--config", str(config), "--code", "M10=M7",
        "--json",
    )  # fmt: skip
    assert json.loads(overridden.stdout)["cuts"] == []


def test_cli_bad_config_exits_2_naming_the_key(tmp_path: Path) -> None:
    config = tmp_path / "config.toml"
    config.write_text('[controller]\ncodes = { X = "M3" }\n', encoding="utf-8")
    result = run_cli(str(PROGRAMS / "relay_self_probe.nc"), "--config", str(config))
    assert result.returncode == 2
    assert "controller.codes" in result.stdout
