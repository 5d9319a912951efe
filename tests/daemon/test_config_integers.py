"""Integer keys take integers: ``port = 1883.0`` is refused by name, not rounded; the
environment's text ``"1883"`` is still an integer."""

from __future__ import annotations

from pathlib import Path

import pytest

from dthc_bridge.cli import main
from dthc_bridge.config import ConfigError, load_config


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "config.toml"
    path.write_text(text)
    return path


def test_a_float_for_an_integer_key_is_refused_naming_the_key(tmp_path: Path) -> None:
    """``[mqtt] port = 1883.0`` loaded as 1883 (pydantic's lax mode); now it is refused,
    naming the key and the value, as is a float in a nested section."""
    path = _write(tmp_path, "[mqtt]\nport = 1883.0\n[board]\nlease_ms = 200.0\n")
    with pytest.raises(ConfigError) as refused:
        load_config(path)
    message = str(refused.value)
    assert "mqtt.port: must be an integer, not 1883.0" in message
    assert "board.lease_ms: must be an integer, not 200.0" in message
    assert message.startswith(str(path))


def test_a_boolean_for_an_integer_key_is_refused(tmp_path: Path) -> None:
    """``ohmic_retries = true`` is not 1."""
    path = _write(tmp_path, "[controller]\nohmic_retries = true\n")
    with pytest.raises(ConfigError, match=r"controller\.ohmic_retries: must be an integer"):
        load_config(path)


def test_integers_and_floats_where_floats_belong_still_load(tmp_path: Path) -> None:
    """An integer where a float is expected (``deadband_v = 1``) and an integer for an
    integer key load as before."""
    path = _write(tmp_path, "[mqtt]\nport = 1884\n[controller.thc]\ndeadband_v = 1\n")
    config = load_config(path)
    assert config.mqtt.port == 1884
    assert config.controller.thc.deadband_v == 1.0


def test_an_environment_override_given_as_text_is_an_integer(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``DTHC_MQTT__PORT=1885`` arrives as the text "1885": read as the integer 1885."""
    monkeypatch.setenv("DTHC_MQTT__PORT", "1885")
    monkeypatch.setenv("DTHC_BOARD__LEASE_MS", " 250 ")
    config = load_config(_write(tmp_path, "[mqtt]\nport = 1884\n"))
    assert (config.mqtt.port, config.board.lease_ms) == (1885, 250)


def test_an_environment_override_with_a_fraction_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``DTHC_MQTT__PORT=1883.0`` is refused like the file's 1883.0."""
    monkeypatch.setenv("DTHC_MQTT__PORT", "1883.0")
    with pytest.raises(ConfigError, match=r"mqtt\.port: must be an integer, not '1883.0'"):
        load_config(_write(tmp_path, ""))


def test_check_config_refuses_a_float_port_with_its_exit_status(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The tester's probe: ``check-config`` said ok for ``port = 1883.0``; now it exits 1
    naming the key, as for any bad configuration."""
    path = _write(tmp_path, "[mqtt]\nport = 1883.0\n")
    assert main(["check-config", str(path)]) == 1
    err = capsys.readouterr().err
    assert "invalid:" in err
    assert "mqtt.port: must be an integer, not 1883.0" in err
