"""Program magic comments and the program-time material table (M190 P<n>)."""

from __future__ import annotations

import pytest

from dthc_bridge.materials import (
    MAGIC_KEYS,
    TEMPORARY_BASE,
    MagicMaterial,
    Material,
    MaterialError,
    MaterialTable,
    parse_magic_comment,
)
from tests.materials.recipes import recipe


def magic(text: str) -> MagicMaterial:
    parsed = parse_magic_comment(text)
    assert parsed is not None
    return parsed


# --- parsing -----------------------------------------------------------------------------


def test_a_full_magic_comment_sets_every_key() -> None:
    parsed = magic(
        "o=2, nu=12, na=Mild steel 1.5 mm 45 A, mt=1.5, kw=1.2, th=1, ph=3.8, pd=0.4, jh=150,"
        " jd=0.2, ch=1.5, fr=3000, ca=45, cv=121, pe=0.5, gp=5.5, cm=1"
    )
    assert parsed == MagicMaterial(
        2,
        Material(
            12,
            name="Mild steel 1.5 mm 45 A",
            thickness=1.5,
            kerf_width=1.2,
            thc=True,
            pierce_height=3.8,
            pierce_delay_s=0.4,
            puddle_jump_height_percent=150,
            puddle_jump_delay_s=0.2,
            cut_height=1.5,
            cut_speed=3000,
            cut_amps=45,
            cut_volts=121,
            pause_at_end_s=0.5,
            gas_pressure=5.5,
            cut_mode=1,
        ),
    )


def test_option_0_needs_no_number_and_gets_a_temporary_placeholder() -> None:
    """The number comes from the table when applied; ``nu`` is ignored for option 0."""
    parsed = magic("o=0, ph=3.1, pd=0.1, ch=0.75, fr=3000")
    assert parsed.option == 0
    assert parsed.material == recipe(
        TEMPORARY_BASE, pierce_height=3.1, pierce_delay_s=0.1, cut_height=0.75
    )
    assert magic("o=0,nu=5,ph=3.1,pd=0.1,ch=0.75,fr=3000").material.number == TEMPORARY_BASE


def test_blanks_around_pairs_and_a_trailing_comma_are_tolerated() -> None:
    assert magic("  o=1 ,nu=3,ph=3.8, pd=0.4 , ch=1.5,fr=3000, ") == MagicMaterial(1, recipe(3))


def test_an_empty_value_is_absent() -> None:
    assert magic("o=1, nu=3, na=, cv=, ph=3.8, pd=0.4, ch=1.5, fr=3000").material == recipe(3)


@pytest.mark.parametrize(
    "text", ["", "Plasma: mild steel", " O=0, ph=3", "o = 0, ph=3", "pierce o=0", "(o=0, ph=3)"]
)
def test_other_comments_are_not_magic(text: str) -> None:
    assert parse_magic_comment(text) is None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("o=0, pd=0.4, ch=1.5, fr=3000", "ph: required for a material"),
        ("o=0, ph=3.8, pd=0.4, ch=1.5", "fr: required for a material"),
        ("o=0, ph=3.8, pd=, ch=1.5, fr=3000", "pd: required for a material"),
        ("o=1, ph=3.8, pd=0.4, ch=1.5, fr=3000", "nu: required for option 1"),
        ("o=2, nu=, ph=3.8, pd=0.4, ch=1.5, fr=3000", "nu: required for option 2"),
        (
            "o=0, xx=1, ph=3.8, pd=0.4, ch=1.5, fr=3000",
            "xx: unknown key; the keys are " + ", ".join(MAGIC_KEYS),
        ),
        ("o=3, nu=1, ph=3.8, pd=0.4, ch=1.5, fr=3000", "o=3: option must be 0, 1 or 2"),
        ("o=, ph=3.8, pd=0.4, ch=1.5, fr=3000", "o=: option must be 0, 1 or 2"),
        ("o=1.0, nu=1, ph=3.8, pd=0.4, ch=1.5, fr=3000", "o=1.0: option must be 0, 1 or 2"),
        ("o=0, ph=3.8, ph=4, pd=0.4, ch=1.5, fr=3000", "ph: given twice"),
        ("o=0, ph=3.8, pd 0.4, ch=1.5, fr=3000", "pd 0.4: expected key=value"),
        ("o=0, ph=3,8, pd=0.4, ch=1.5, fr=3000", "8: expected key=value"),
        ("o=0, ph=3.8mm, pd=0.4, ch=1.5, fr=3000", "ph: '3.8mm' is not a number"),
        ("o=0, ph=0, pd=0.4, ch=1.5, fr=3000", "ph: must be more than 0, got 0"),
        ("o=0, ph=3.8, pd=-1, ch=1.5, fr=3000", "pd: must be 0 or more, got -1"),
        ("o=0, ph=3.8, pd=0.4, ch=1.5, fr=3000, th=2", "th: must be 0 (off) or 1 (on), got '2'"),
        ("o=0, ph=3.8, pd=0.4, ch=1.5, fr=3000, cm=7", "cm: must be 0 (not set), 1, 2 or 3, got 7"),
        ("o=0, ph=3.8, pd=0.4, ch=1.5, fr=3000, mt=-2", "mt: must be 0 or more, got -2"),
        ("o=1, nu=x, ph=3.8, pd=0.4, ch=1.5, fr=3000", "nu: 'x' is not a number"),
        (
            "o=1, nu=0, ph=3.8, pd=0.4, ch=1.5, fr=3000",
            "nu: must be 1 to 999999, got 0 (0 is the default material, higher numbers are "
            "temporary)",
        ),
        (
            "o=2, nu=1000000, ph=3.8, pd=0.4, ch=1.5, fr=3000",
            "nu: must be 1 to 999999, got 1000000 (0 is the default material, higher numbers "
            "are temporary)",
        ),
    ],
)
def test_a_bad_magic_comment_names_the_key(text: str, message: str) -> None:
    with pytest.raises(MaterialError) as info:
        parse_magic_comment(text)
    assert str(info.value) == message


def test_a_hand_made_magic_material_is_checked_too() -> None:
    with pytest.raises(MaterialError, match=r"^o=4: option must be 0, 1 or 2$"):
        MagicMaterial(4, recipe(3))
    with pytest.raises(MaterialError, match=r"^nu: must be 1 to 999999 for option 2$"):
        MagicMaterial(2, recipe(TEMPORARY_BASE))


# --- the table a program selects from ----------------------------------------------------

LIBRARY = {1: recipe(1, name="Mild 1.5"), 7: recipe(7, name="Plate 6", cut_speed=1400.0)}
DEFAULT = recipe(0, name="settings default", cut_speed=2500.0)


def table(initial: int = 0) -> MaterialTable:
    return MaterialTable(LIBRARY, DEFAULT, initial=initial)


def test_the_initial_material_is_in_force_and_m190_selects() -> None:
    t = table(initial=7)
    assert (t.initial, t.selected_number, t.selected) == (7, 7, LIBRARY[7])
    assert t.select(1) == LIBRARY[1]
    assert t.selected == LIBRARY[1]


def test_material_0_is_the_default_from_the_settings_unless_the_table_has_one() -> None:
    assert table().select(0) == DEFAULT
    own = recipe(0, name="table's own")
    assert MaterialTable({0: own}, DEFAULT).select(0) == own


def test_m190_p_minus_1_returns_to_the_material_before_the_program() -> None:
    t = table(initial=1)
    t.select(7)
    assert t.select(-1) == LIBRARY[1]
    t.select(0)
    assert t.revert() == LIBRARY[1]
    assert t.selected_number == 1


@pytest.mark.parametrize(
    ("number", "message"), [(5, "M190 P5: no material 5"), (-2, "M190 P-2: no material -2")]
)
def test_selecting_an_unknown_material_is_an_error_and_changes_nothing(
    number: int, message: str
) -> None:
    t = table(initial=1)
    with pytest.raises(MaterialError) as info:
        t.select(number)
    assert str(info.value) == message
    assert t.selected_number == 1


def test_without_a_default_material_0_is_unknown() -> None:
    with pytest.raises(MaterialError, match=r"^M190 P0: no material 0$"):
        MaterialTable(LIBRARY, initial=1).select(0)
    with pytest.raises(MaterialError, match=r"^initial material 0: no material 0$"):
        MaterialTable(LIBRARY)


def test_option_0_defines_numbered_temporaries_and_puts_each_in_force() -> None:
    """Choice: a program's temporary default is the material it cuts with, at once."""
    t = table(initial=1)
    first = t.apply(magic("o=0, ph=3.1, pd=0.1, ch=0.75, fr=3000"))
    assert first.number == TEMPORARY_BASE
    assert t.selected == first
    second = t.apply(magic("o=0, na=second, ph=4, pd=0.2, ch=1, fr=2000"))
    assert second.number == TEMPORARY_BASE + 1
    assert t.selected == second
    assert t.select(TEMPORARY_BASE) == first  # still selectable by number
    assert t.select(-1) == LIBRARY[1]
    assert t.changes == {}  # nothing for the library file


def test_temporary_numbers_continue_after_those_already_in_the_table() -> None:
    t = MaterialTable({TEMPORARY_BASE + 4: recipe(TEMPORARY_BASE + 4)}, DEFAULT)
    assert t.apply(magic("o=0, ph=3.1, pd=0.1, ch=0.75, fr=3000")).number == TEMPORARY_BASE + 5


def test_option_1_adds_only_a_missing_material() -> None:
    """The library's own recipe wins over the program's."""
    t = table()
    kept = t.apply(magic("o=1, nu=7, na=program's plate, ph=5, pd=1, ch=2, fr=1000"))
    assert kept == LIBRARY[7]
    added = t.apply(magic("o=1, nu=8, na=new, ph=5, pd=1, ch=2, fr=1000"))
    assert added.number == 8
    assert t.materials[8] == added
    assert t.changes == {8: added}
    assert t.selected_number == 0  # defining is not selecting


def test_option_2_adds_or_overwrites_and_the_material_in_force_follows() -> None:
    t = table(initial=7)
    new = t.apply(magic("o=2, nu=7, na=Plate 6 new tips, ph=4.2, pd=0.8, ch=1.7, fr=1500"))
    assert t.materials[7] == new
    assert t.selected == new
    assert t.changes == {7: new}
    assert LIBRARY[7].name == "Plate 6"  # the caller's mapping is not touched


def test_the_table_is_read_only_from_outside_and_checks_its_input() -> None:
    t = table()
    with pytest.raises(TypeError):
        t.materials[3] = recipe(3)  # type: ignore[index]
    with pytest.raises(MaterialError, match=r"^material 4: is numbered 5$"):
        MaterialTable({4: recipe(5)}, DEFAULT)
    with pytest.raises(MaterialError, match=r"^default material: must be number 0, not 3$"):
        MaterialTable(LIBRARY, recipe(3))
