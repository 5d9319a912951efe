"""The example configuration the installer puts in /etc/dthc-bridge: valid for the daemon."""

from __future__ import annotations

import tomllib
from pathlib import Path

from dthc_bridge.config import load_config
from dthc_bridge.deploy.render import BOARD_SYMLINK, example_config


def test_example_config_is_small_toml_with_the_documented_sections() -> None:
    """Four sections; the board link is the udev name the rules create."""
    config = tomllib.loads(example_config())
    assert set(config) == {"board", "mqtt", "controller", "logging"}
    assert config["board"]["link"] == f"/dev/{BOARD_SYMLINK}"


def test_daemon_accepts_the_example_config(tmp_path: Path) -> None:
    """The daemon's closed config model loads it (no unknown key, every value in bounds)."""
    path = tmp_path / "config.toml"
    path.write_text(example_config())
    config = load_config(path)
    assert config.board.link == "/dev/dthc0"
    assert (config.mqtt.host, config.mqtt.port) == ("localhost", 1883)
    assert config.logging.level == "info"
