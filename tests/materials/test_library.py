"""The material type, the QtPlasmaC material-file format and the JSON form."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dthc_bridge.controller.commands import CutParams
from dthc_bridge.materials import (
    MATERIAL_KEYS,
    TEMPORARY_BASE,
    Material,
    MaterialError,
    format_material_file,
    material_from_dict,
    material_to_dict,
    parse_material_file,
)
from tests.materials.recipes import recipe

# A shop's library as a person might write it: comments, blank lines, ragged spacing,
# keys in any order, empty values, optional keys left out.
LIBRARY = """\
# Our plasma table, 45 A consumables
[MATERIAL_NUMBER_1]
NAME               = Mild steel 1.5 mm 45 A
KERF_WIDTH         = 1.2
THC                = 1
PIERCE_HEIGHT      = 3.8
PIERCE_DELAY       = 0.4
CUT_HEIGHT         = 1.5
CUT_SPEED          = 3000
CUT_AMPS           = 45
CUT_VOLTS          = 121

  # thicker plate: puddle jump
[MATERIAL_NUMBER_7]
CUT_SPEED=1400
PIERCE_HEIGHT=4.5
PIERCE_DELAY = 0.9
   CUT_HEIGHT = 1.8
PUDDLE_JUMP_HEIGHT = 150
PUDDLE_JUMP_DELAY = .2
PAUSE_AT_END = 0.5
GAS_PRESSURE = 5.5
CUT_MODE = 1
NAME =
CUT_VOLTS =
"""

MILD_1_5 = Material(
    1,
    name="Mild steel 1.5 mm 45 A",
    kerf_width=1.2,
    thc=True,
    pierce_height=3.8,
    pierce_delay_s=0.4,
    cut_height=1.5,
    cut_speed=3000,
    cut_amps=45,
    cut_volts=121,
)
PLATE_6 = Material(
    7,
    pierce_height=4.5,
    pierce_delay_s=0.9,
    puddle_jump_height_percent=150,
    puddle_jump_delay_s=0.2,
    cut_height=1.8,
    cut_speed=1400,
    pause_at_end_s=0.5,
    gas_pressure=5.5,
    cut_mode=1,
)


# --- the material file -------------------------------------------------------------------


def test_a_library_file_parses_with_comments_blank_lines_and_empty_values() -> None:
    """Keys in any order and spacing; an empty value and an absent key are the default."""
    assert parse_material_file(LIBRARY) == {1: MILD_1_5, 7: PLATE_6}


def test_absent_keys_default_to_zero_so_thc_is_off_unless_the_file_says_1() -> None:
    """As in QtPlasmaC every optional key defaults to 0: THC off, auto volts, no jump."""
    material = parse_material_file(
        "[MATERIAL_NUMBER_2]\nPIERCE_HEIGHT = 3\nPIERCE_DELAY = 0\n"
        "CUT_HEIGHT = 1\nCUT_SPEED = 2000\n"
    )[2]
    assert material == Material(2, pierce_height=3, pierce_delay_s=0, cut_height=1, cut_speed=2000)
    assert (material.thc, material.cut_volts, material.puddle_jump_height_percent) == (False, 0, 0)
    assert (material.name, material.cut_mode) == ("", 0)


def test_windows_line_endings_and_an_empty_file() -> None:
    assert parse_material_file(LIBRARY.replace("\n", "\r\n")) == {1: MILD_1_5, 7: PLATE_6}
    assert parse_material_file("") == {}
    assert parse_material_file("# nothing yet\n\n") == {}


def test_a_name_keeps_equals_signs_and_hashes() -> None:
    """Only whole lines are comments; the value is everything after the first ``=``."""
    text = format_material_file({3: recipe(3, name="SS 304 #2 finish, a=b")})
    assert parse_material_file(text)[3].name == "SS 304 #2 finish, a=b"


SECTION = "[MATERIAL_NUMBER_3]\n"
MANDATORY = "PIERCE_HEIGHT = 3.8\nPIERCE_DELAY = 0.4\nCUT_HEIGHT = 1.5\nCUT_SPEED = 3000\n"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            SECTION + "PIERCE_HEIGHT = 3.8\nPIERCE_DELAY = 0.4\nCUT_SPEED = 3000\n",
            "line 1 [MATERIAL_NUMBER_3] CUT_HEIGHT: required, missing",
        ),
        (
            SECTION + MANDATORY.replace("CUT_SPEED = 3000", "CUT_SPEED ="),
            "line 5 [MATERIAL_NUMBER_3] CUT_SPEED: required, missing",
        ),
        (
            "# c\n\n" + SECTION + MANDATORY.replace("1.5", "1,5"),
            "line 6 [MATERIAL_NUMBER_3] CUT_HEIGHT: '1,5' is not a number",
        ),
        (
            SECTION + MANDATORY + "CUT_VOLTS = nan\n",
            "line 6 [MATERIAL_NUMBER_3] CUT_VOLTS: 'nan' is not a number",
        ),
        (
            SECTION + MANDATORY + "THC = 2\n",
            "line 6 [MATERIAL_NUMBER_3] THC: must be 0 (off) or 1 (on), got '2'",
        ),
        (
            SECTION + MANDATORY + "CUT_MODE = 1.5\n",
            "line 6 [MATERIAL_NUMBER_3] CUT_MODE: '1.5' is not a whole number",
        ),
        (
            SECTION + MANDATORY + "CUT_MODE = 4\n",
            "line 6 [MATERIAL_NUMBER_3] CUT_MODE: must be 0 (not set), 1, 2 or 3, got 4",
        ),
        (
            SECTION + MANDATORY.replace("PIERCE_HEIGHT = 3.8", "PIERCE_HEIGHT = 0"),
            "line 2 [MATERIAL_NUMBER_3] PIERCE_HEIGHT: must be more than 0, got 0",
        ),
        (
            SECTION + MANDATORY + "KERF_WIDTH = -1\n",
            "line 6 [MATERIAL_NUMBER_3] KERF_WIDTH: must be 0 or more, got -1",
        ),
        (
            SECTION + MANDATORY + "NAME = bell\x07\n",
            "line 6 [MATERIAL_NUMBER_3] NAME: must be one line of printable text, got 'bell\\x07'",
        ),
        (
            SECTION + MANDATORY + "TORCH_HEIGHT = 3\n",
            "line 6 [MATERIAL_NUMBER_3] TORCH_HEIGHT: unknown key; QtPlasmaC's keys are "
            + ", ".join(MATERIAL_KEYS),
        ),
        (
            SECTION + "cut_height = 1.5\n",
            "line 2 [MATERIAL_NUMBER_3] cut_height: unknown key; QtPlasmaC's keys are "
            + ", ".join(MATERIAL_KEYS),
        ),
        (
            SECTION + MANDATORY + "CUT_HEIGHT = 1.6\n",
            "line 6 [MATERIAL_NUMBER_3] CUT_HEIGHT: already given at line 4",
        ),
        (
            SECTION + MANDATORY + "\n" + SECTION + MANDATORY,
            "line 7 [MATERIAL_NUMBER_3]: material 3 is already defined at line 1",
        ),
        (
            "PIERCE_HEIGHT = 3.8\n" + SECTION,
            "line 1 PIERCE_HEIGHT: comes before the first [MATERIAL_NUMBER_<n>]",
        ),
        (
            "[MATERIAL_3]\n" + MANDATORY,
            "line 1 [MATERIAL_3]: unknown section; expected [MATERIAL_NUMBER_<n>]",
        ),
        (
            SECTION + MANDATORY + "CUT_SPEED 3000\n",
            "line 6: expected KEY = value, got 'CUT_SPEED 3000'",
        ),
        (
            "[MATERIAL_NUMBER_0]\n" + MANDATORY,
            "line 1 [MATERIAL_NUMBER_0]: material 0 is the default material; "
            "it is set in the daemon's settings",
        ),
        (
            "[MATERIAL_NUMBER_1000000]\n" + MANDATORY,
            "line 1 [MATERIAL_NUMBER_1000000]: numbers from 1000000 up are reserved for "
            "temporary materials",
        ),
    ],
)
def test_a_bad_file_is_refused_naming_the_line_section_and_key_as_written(
    text: str, message: str
) -> None:
    """A typo never silently cuts with a default."""
    with pytest.raises(MaterialError) as info:
        parse_material_file(text)
    assert str(info.value) == message


def test_the_error_names_the_section_as_written() -> None:
    with pytest.raises(MaterialError) as info:
        parse_material_file("[MATERIAL_NUMBER_007]\nPIERCE_HEIGHT = x\n")
    assert info.value.where == "line 2 [MATERIAL_NUMBER_007] PIERCE_HEIGHT"
    assert info.value.reason == "'x' is not a number"


def test_the_file_is_written_sorted_with_every_key_and_a_header() -> None:
    """QtPlasmaC's layout: a section per material, every key, THC as 0/1, no '.0'."""
    text = format_material_file({7: PLATE_6, 1: MILD_1_5})
    assert text.startswith("# ")
    assert text.index("[MATERIAL_NUMBER_1]") < text.index("[MATERIAL_NUMBER_7]")
    section = text[text.index("[MATERIAL_NUMBER_1]") :].split("\n\n")[0].splitlines()
    assert [line.split("=")[0].strip() for line in section[1:]] == list(MATERIAL_KEYS)
    assert "THC                = 1" in section
    assert "CUT_SPEED          = 3000" in section
    assert "PIERCE_DELAY       = 0.4" in section
    assert parse_material_file(text) == {1: MILD_1_5, 7: PLATE_6}


def test_temporaries_and_thickness_are_not_written() -> None:
    """Program-defined materials live for the program; thickness has no key in the file."""
    temporary = recipe(TEMPORARY_BASE + 3)
    assert temporary.temporary
    assert not MILD_1_5.temporary
    thick = recipe(2, thickness=6.0)
    text = format_material_file({2: thick, temporary.number: temporary})
    assert "MATERIAL_NUMBER_1000003" not in text
    assert parse_material_file(text) == {2: recipe(2)}


@pytest.mark.parametrize(
    ("materials", "message"),
    [
        ({0: recipe(0)}, "material 0: is the default material; it is set in the daemon's settings"),
        ({4: recipe(5)}, "material 4: is numbered 5"),
    ],
)
def test_what_the_file_cannot_hold_is_refused(materials: dict[int, Material], message: str) -> None:
    with pytest.raises(MaterialError) as info:
        format_material_file(materials)
    assert str(info.value) == message


finite = {"allow_nan": False, "allow_infinity": False}
positive = st.floats(min_value=0, exclude_min=True, **finite)  # type: ignore[arg-type]
non_negative = st.floats(min_value=0, **finite)  # type: ignore[arg-type]
names = st.text(st.characters(codec="utf-8", categories=("L", "N", "P", "S")) | st.just(" "))


def materials(numbers: st.SearchStrategy[int]) -> st.SearchStrategy[Material]:
    return st.builds(
        Material,
        number=numbers,
        name=names,
        kerf_width=non_negative,
        thc=st.booleans(),
        pierce_height=positive,
        pierce_delay_s=non_negative,
        puddle_jump_height_percent=non_negative,
        puddle_jump_delay_s=non_negative,
        cut_height=positive,
        cut_speed=positive,
        cut_amps=non_negative,
        cut_volts=non_negative,
        pause_at_end_s=non_negative,
        gas_pressure=non_negative,
        cut_mode=st.integers(0, 3),
    )


library_numbers = st.integers(1, TEMPORARY_BASE - 1)
libraries = st.lists(materials(library_numbers), max_size=6).map(
    lambda ms: {m.number: m for m in ms}
)


@given(libraries, st.lists(materials(st.integers(TEMPORARY_BASE, 2 * TEMPORARY_BASE))))
def test_a_written_library_reads_back_equal_without_its_temporaries(
    library: dict[int, Material], temporaries: list[Material]
) -> None:
    """parse(format(m)) == m: every value survives exactly (repr round-trips floats)."""
    both = library | {m.number: m for m in temporaries}
    assert parse_material_file(format_material_file(both)) == library


# --- the material itself -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"pierce_height": 0}, "pierce_height: must be more than 0, got 0"),
        ({"cut_height": -1.5}, "cut_height: must be more than 0, got -1.5"),
        ({"cut_speed": float("inf")}, "cut_speed: must be a finite number, got inf"),
        ({"pierce_delay_s": -0.1}, "pierce_delay_s: must be 0 or more, got -0.1"),
        ({"cut_volts": "121"}, "cut_volts: must be a number, got '121'"),
        ({"cut_amps": True}, "cut_amps: must be a number, got True"),
        ({"thc": 1}, "thc: must be true or false, got 1"),
        ({"cut_mode": 1.0}, "cut_mode: must be 0 (not set), 1, 2 or 3, got 1.0"),
        ({"name": "two\nlines"}, "name: must be one line of printable text, got 'two\\nlines'"),
        ({"name": 5}, "name: must be text, got 5"),
    ],
)
def test_a_material_validates_on_construction_naming_the_attribute(
    changes: dict[str, object], message: str
) -> None:
    with pytest.raises(MaterialError) as info:
        recipe(3, **changes)
    assert str(info.value) == message


def test_material_numbers_are_whole_and_not_negative() -> None:
    with pytest.raises(MaterialError, match=r"^number: must be a whole number 0 or more, got -1$"):
        recipe(-1)
    assert recipe(0).number == 0  # the default material is a material like any other


def test_numbers_are_normalised_so_equal_recipes_compare_equal() -> None:
    material = recipe(3, name="  Alu 2 mm  ", cut_amps=45)
    assert material == recipe(3, name="Alu 2 mm", cut_amps=45.0)
    assert isinstance(material.cut_amps, float)


def test_a_material_becomes_the_controllers_cut_parameters() -> None:
    """Delay s -> ms, volts 0 -> auto, machine settings from the caller."""
    params = MILD_1_5.as_cut_params(touch_feed_mm_min=250, ohmic=True, anti_dive_percent=80)
    assert params == CutParams(
        touch_feed_mm_min=250,
        pierce_height_mm=3.8,
        pierce_delay_ms=400,
        cut_height_mm=1.5,
        cut_voltage_v=121,
        anti_dive_percent=80,
        ohmic=True,
    )
    auto = PLATE_6.as_cut_params(touch_feed_mm_min=250, ohmic=False, anti_dive_percent=90)
    assert auto.cut_voltage_v is None


def test_an_inch_material_is_converted_to_mm() -> None:
    inch = Material(
        4, pierce_height=0.15, pierce_delay_s=0.5, cut_height=0.06, cut_speed=120, cut_volts=118
    )
    params = inch.as_cut_params(touch_feed_mm_min=250, ohmic=False, anti_dive_percent=90, inch=True)
    assert params.pierce_height_mm == pytest.approx(3.81)
    assert params.cut_height_mm == pytest.approx(1.524)
    assert params.pierce_delay_ms == pytest.approx(500)


@pytest.mark.parametrize(
    ("material", "inch", "message"),
    [
        (
            recipe(3, cut_height=12),
            False,
            "material 3 cut_height: 12 mm is outside the controller's range "
            "(12 is out of range 0.2..10 mm)",
        ),
        (
            recipe(3),
            True,
            "material 3 pierce_height: 3.8 in is outside the controller's range "
            "(96.52 is out of range 0.5..25 mm)",
        ),
        (
            recipe(3, pierce_delay_s=20),
            False,
            "material 3 pierce_delay_s: 20 s is outside the controller's range "
            "(20000 is out of range 0..10000 ms)",
        ),
        (
            recipe(3, cut_volts=30),
            False,
            "material 3 cut_volts: 30 V is outside the controller's range "
            "(30 is out of range 50..300 V)",
        ),
    ],
)
def test_a_value_the_controller_refuses_is_named_by_the_materials_attribute(
    material: Material, inch: bool, message: str
) -> None:
    with pytest.raises(MaterialError) as info:
        material.as_cut_params(touch_feed_mm_min=250, ohmic=False, anti_dive_percent=90, inch=inch)
    assert str(info.value) == message


def test_a_bad_machine_setting_is_named_as_such() -> None:
    with pytest.raises(MaterialError) as info:
        MILD_1_5.as_cut_params(touch_feed_mm_min=250, ohmic=False, anti_dive_percent=150)
    assert str(info.value) == "anti_dive_percent: 150 is out of range 0..100 %"


# --- the JSON form (MQTT) ----------------------------------------------------------------


def test_the_json_form_has_snake_case_keys_and_survives_json() -> None:
    data = material_to_dict(MILD_1_5)
    assert data == {
        "name": "Mild steel 1.5 mm 45 A",
        "kerf_width": 1.2,
        "thc": True,
        "pierce_height": 3.8,
        "pierce_delay": 0.4,
        "puddle_jump_height": 0.0,
        "puddle_jump_delay": 0.0,
        "cut_height": 1.5,
        "cut_speed": 3000.0,
        "cut_amps": 45.0,
        "cut_volts": 121.0,
        "pause_at_end": 0.0,
        "gas_pressure": 0.0,
        "cut_mode": 0,
    }
    assert material_from_dict(1, json.loads(json.dumps(data))) == MILD_1_5


def test_a_json_material_needs_only_the_mandatory_four_and_takes_0_1_for_thc() -> None:
    data = {"pierce_height": 3.8, "pierce_delay": 0.4, "cut_height": 1.5, "cut_speed": 3000}
    assert material_from_dict(2, data) == recipe(2)
    assert material_from_dict(2, data | {"thc": 1, "cut_mode": 2.0}) == recipe(
        2, thc=True, cut_mode=2
    )


@given(materials(st.integers(0, 2 * TEMPORARY_BASE)))
def test_the_json_form_round_trips(material: Material) -> None:
    data = json.loads(json.dumps(material_to_dict(material)))
    assert material_from_dict(material.number, data) == material


JSON_KEYS = (
    "name, kerf_width, thc, pierce_height, pierce_delay, puddle_jump_height, puddle_jump_delay,"
    " cut_height, cut_speed, cut_amps, cut_volts, pause_at_end, gas_pressure, cut_mode"
)
MANDATORY_JSON = {"pierce_height": 3.8, "pierce_delay": 0.4, "cut_height": 1.5, "cut_speed": 3000}


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (
            {"pierce_height": 3.8, "pierce_delay": 0.4, "cut_height": 1.5},
            "cut_speed: required, missing",
        ),
        (
            MANDATORY_JSON | {"speed": 1},
            "speed: unknown key; the keys are " + JSON_KEYS,
        ),
        (
            MANDATORY_JSON | {"pierce_delay_s": 1},
            "pierce_delay_s: unknown key; the keys are " + JSON_KEYS,
        ),
        (MANDATORY_JSON | {"pierce_delay": "0.4"}, "pierce_delay: must be a number, got '0.4'"),
        (MANDATORY_JSON | {"pause_at_end": -1}, "pause_at_end: must be 0 or more, got -1"),
        (MANDATORY_JSON | {"thc": "yes"}, "thc: must be true or false, got 'yes'"),
        (MANDATORY_JSON | {"thc": 2}, "thc: must be true or false, got 2"),
        (MANDATORY_JSON | {"cut_mode": 1.5}, "cut_mode: must be 0 (not set), 1, 2 or 3, got 1.5"),
        (MANDATORY_JSON | {"name": None}, "name: must be text, got None"),
        (MANDATORY_JSON | {"cut_volts": None}, "cut_volts: must be a number, got None"),
    ],
)
def test_a_bad_json_material_names_the_key(data: dict[str, object], message: str) -> None:
    with pytest.raises(MaterialError) as info:
        material_from_dict(3, data)
    assert str(info.value) == message
