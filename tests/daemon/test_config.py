"""The daemon's configuration: TOML in, environment on top, unknown keys refused by name."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from pydantic import ValidationError

from dthc_bridge.config import ConfigError, DaemonConfig, load_config
from dthc_bridge.controller.commands import ThcMode

GOOD = """
[board]
link = "/dev/dthc0"
lease_ms = 200

[mqtt]
host = "localhost"
port = 1883

[controller]
thc_delay_s = 0.8

[controller.thc]
deadband_v = 0.5
"""


def test_a_valid_file_loads_with_defaults_filled_in(tmp_path: Path) -> None:
    """Values from the file are used; everything else keeps its documented default."""
    path = tmp_path / "config.toml"
    path.write_text(GOOD)
    config = load_config(path)
    assert config.board.lease_ms == 200
    assert config.board.timing().lease_ms == 200
    assert config.controller.sequence().thc_delay_s == 0.8
    assert config.controller.thc.build().deadband_v == 0.5
    assert config.board.baudrate == 921_600


def test_unknown_key_is_refused_naming_it(tmp_path: Path) -> None:
    """A typo in a key is an error that names the exact dotted key."""
    path = tmp_path / "config.toml"
    path.write_text(GOOD.replace("lease_ms = 200", "lease_msec = 200"))
    with pytest.raises(ConfigError, match=r"board\.lease_msec"):
        load_config(path)


def test_out_of_range_value_is_refused_naming_it(tmp_path: Path) -> None:
    """A value outside its bounds names the key and the bound."""
    path = tmp_path / "config.toml"
    path.write_text(GOOD.replace("lease_ms = 200", "lease_ms = 5"))
    with pytest.raises(ConfigError, match=r"board\.lease_ms.*greater than or equal to 20"):
        load_config(path)


def test_environment_overrides_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """DTHC_SECTION__KEY beats the file's value."""
    path = tmp_path / "config.toml"
    path.write_text(GOOD)
    monkeypatch.setenv("DTHC_BOARD__LEASE_MS", "300")
    monkeypatch.setenv("DTHC_MQTT__HOST", "broker.local")
    config = load_config(path)
    assert config.board.lease_ms == 300
    assert config.mqtt.host == "broker.local"


def test_check_config_exits_non_zero_naming_the_bad_key(tmp_path: Path) -> None:
    """`dthc-bridge check-config FILE` fails with the key in its message; a good file passes."""
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("[controller]", "[controller]\nprobe_heigth_mm = 3"))
    proc = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "check-config", str(bad)],
        capture_output=True, text=True, timeout=30, check=False,
    )  # fmt: skip
    assert proc.returncode != 0
    assert "controller.probe_heigth_mm" in proc.stderr
    good = tmp_path / "good.toml"
    good.write_text(GOOD)
    ok = subprocess.run(
        [sys.executable, "-m", "dthc_bridge", "check-config", str(good)],
        capture_output=True, text=True, timeout=30, check=False,
    )  # fmt: skip
    assert ok.returncode == 0, ok.stderr


def test_broken_toml_is_reported_with_the_file(tmp_path: Path) -> None:
    """A syntax error names the file and says it is not valid TOML."""
    path = tmp_path / "broken.toml"
    path.write_text("[board\nlink = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(path)


def test_slow_down_following_can_be_switched_off(tmp_path: Path) -> None:
    """``controller.thc.slow_follow = false`` reaches the controller: Z holds through
    every slow-down, as the open controllers do."""
    path = tmp_path / "config.toml"
    path.write_text("[controller.thc]\nslow_follow = false\nslow_follow_max_mm = 0.8\n")
    thc = load_config(path).controller.thc.build()
    assert thc.slow_follow is False
    assert thc.slow_follow_max_mm == 0.8
    assert load_config(None).controller.thc.build().slow_follow is True


def test_integer_choices_can_be_overridden_from_the_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Environment values arrive as text: DTHC_CONTROLLER__MODE=0 selects mode 0 (it was
    refused as "Input should be 0, 1 or 2"), and out of range is still refused by key."""
    monkeypatch.setenv("DTHC_CONTROLLER__MODE", "0")
    monkeypatch.setenv("DTHC_CONTROLLER__IHS_SKIP_TYPE", "1")
    controller = DaemonConfig().controller
    assert controller.mode == 0
    assert controller.thc_mode is ThcMode(0)
    assert controller.sequence().ihs_skip_type == 1
    monkeypatch.setenv("DTHC_CONTROLLER__MODE", "3")
    with pytest.raises(ValidationError, match=r"controller\.mode"):
        DaemonConfig()


def test_a_shops_code_table_loads_normalised(tmp_path: Path) -> None:
    path = tmp_path / "config.toml"
    path.write_text('[controller]\ncodes = { h1 = "M667", H0 = "M666", "M10" = "M3 $0" }\n')
    assert load_config(path).controller.codes == {"H1": "M667", "H0": "M666", "M10": "M3 $0"}


@pytest.mark.parametrize(
    ("table", "says"),
    [('{ X = "M3" }', "'X=M3': expected CODE=LINE"), ('{ M10 = "M3 (" }', "'M10=M3 ('")],
)
def test_a_bad_code_table_entry_is_refused_naming_it(tmp_path: Path, table: str, says: str) -> None:
    path = tmp_path / "config.toml"
    path.write_text(f"[controller]\ncodes = {table}\n")
    with pytest.raises(ConfigError, match=r"controller\.codes") as info:
        load_config(path)
    assert says in str(info.value)
