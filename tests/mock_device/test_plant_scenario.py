"""Scenario files: the bundled set loads, and bad files fail with the exact key named."""

from pathlib import Path

import pytest

from mock_device.plant import ScenarioError, list_scenarios, load_scenario, scenario_from_dict

BUNDLED = {
    "flat_clean",
    "warped_sheet",
    "kerf_crossing",
    "noisy_hf_start",
    "painted_plate",
    "arc_lost_midcut",
}


def test_all_bundled_scenarios_load_with_a_default_program() -> None:
    """The six bundled scenarios load and each has a motion program at its cut feed."""
    assert set(list_scenarios()) >= BUNDLED
    for name in BUNDLED:
        scenario = load_scenario(name)
        assert scenario.name == name
        assert scenario.description
        assert len(scenario.default_program) >= 3
        feed = f"F{scenario.material.cut_feed_mm_min:g}"
        assert any(feed in line for line in scenario.default_program)


def test_scenario_specific_settings() -> None:
    """Each scenario sets the condition it is named after."""
    assert load_scenario("painted_plate").surface.condition == "painted"
    assert load_scenario("arc_lost_midcut").faults.arc_lost_at_s == 2.0
    assert len(load_scenario("kerf_crossing").kerfs) >= 2
    noisy = load_scenario("noisy_hf_start").noise
    assert noisy.hf_start_spike_rate_per_s > 0
    assert noisy.spike_rate_per_s > 0
    assert noisy.burst_rate_per_s > 0
    assert load_scenario("warped_sheet").plate.waves


def test_defaults_match_the_reference_numbers() -> None:
    """An empty scenario gets the reference defaults (1.5 mm, 7.5 V/mm, 7 mm arc-loss, …)."""
    s = scenario_from_dict({"name": "defaults"})
    assert s.material.cut_height_mm == 1.5
    assert s.material.slope_v_per_mm == 7.5
    assert s.material.pierce_height_mm == 3.8
    assert s.arc.lose_above_height_mm == 7.0
    assert s.arc.rise_v == 10.0
    assert s.arc.pilot_to_transfer_s == (0.15, 0.5)
    assert s.torch.float_travel_mm == 1.5
    assert s.torch.max_float_mm == 6.0
    assert (s.zaxis.min_mm, s.zaxis.max_mm, s.zaxis.max_velocity_mm_s) == (0.0, 100.0, 60.0)
    assert s.thc_set_voltage_v == s.material.cut_voltage_v


@pytest.mark.parametrize(
    ("data", "key", "reason"),
    [
        ({"material": {"cut_hieght_mm": 1.5}}, "material.cut_hieght_mm", "unknown key"),
        ({"colour": "red"}, "colour", "unknown key"),
        (
            {"plate": {"waves": [{"amplitude_mm": 1, "wavelenght_mm": 2}]}},
            "plate.waves[0].wavelenght_mm",
            "unknown key",
        ),
        ({"material": {"cut_height_mm": -1.0}}, "material.cut_height_mm", "must be > 0"),
        ({"material": {"cut_height_mm": "low"}}, "material.cut_height_mm", "must be a number"),
        ({"arc": {"pilot_to_transfer_s": [0.5, 0.1]}}, "arc.pilot_to_transfer_s", "low <= high"),
        ({"arc": {"pilot_to_transfer_s": [0.5]}}, "arc.pilot_to_transfer_s", "2 elements"),
        ({"surface": {"condition": "oily"}}, "surface.condition", "must be one of"),
        ({"kerfs": [{"x0_mm": 1, "y0_mm": 2, "x1_mm": 3}]}, "kerfs[0].y1_mm", "missing"),
        (
            {"voids": [{"x_min_mm": 5, "y_min_mm": 0, "x_max_mm": 1, "y_max_mm": 9}]},
            "voids[0].x_max_mm",
            "greater",
        ),
        ({"zaxis": {"start_mm": 120.0}}, "zaxis.start_mm", "within"),
        ({"torch": {"max_float_mm": 1.0}}, "torch.max_float_mm", "greater"),
        ({"noise": {"spike_length_samples": [1.5, 2]}}, "noise.spike_length_samples", "integer"),
        ({"default_program": "G1 X1"}, "default_program", "array"),
        (
            {"surface": {"rusty_contact_probability": 1.5}},
            "surface.rusty_contact_probability",
            "<= 1",
        ),
    ],
)
def test_invalid_tables_are_rejected_naming_the_key(
    data: dict[str, object], key: str, reason: str
) -> None:
    """Unknown keys, wrong types, out-of-bounds values: ScenarioError with the dotted key."""
    with pytest.raises(ScenarioError, match=reason) as info:
        scenario_from_dict(data, source="test.toml")
    assert info.value.key == key
    assert str(info.value).startswith(f"test.toml: {key}: ")


def test_load_from_path_and_errors_for_missing_or_broken_files(tmp_path: Path) -> None:
    """A path loads (name from the stem); a missing name lists the known ones; bad TOML is named."""
    good = tmp_path / "mine.toml"
    good.write_text('description = "x"\n[material]\ncut_voltage_v = 130.0\n', encoding="utf-8")
    scenario = load_scenario(good)
    assert scenario.name == "mine"
    assert scenario.material.cut_voltage_v == 130.0
    with pytest.raises(ScenarioError, match=r"known: .*flat_clean"):
        load_scenario("no_such_scenario")
    bad = tmp_path / "bad.toml"
    bad.write_text("[material\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match="invalid TOML"):
        load_scenario(bad)
    typo = tmp_path / "typo.toml"
    typo.write_text("[noise]\nsigma = 1.0\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"typo\.toml: noise\.sigma: unknown key"):
        load_scenario(str(typo))
