"""The README stays true to the code: every configuration key and request is documented."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel

from dthc_bridge.config import DaemonConfig
from dthc_bridge.controller.gcode import REQUEST_NAMES

README = (Path(__file__).parents[1] / "README.md").read_text()


def _keys(model: type[BaseModel], prefix: str) -> list[str]:
    keys = []
    for name, field in model.model_fields.items():
        annotation = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            keys += _keys(annotation, f"{prefix}{name}.")
        else:
            keys.append(f"{prefix}{name}")
    return keys


def test_every_configuration_key_is_in_the_readme() -> None:
    """A key added to the config model without a README row fails here."""
    missing = [key for key in _keys(DaemonConfig, "") if f"`{key}`" not in README]
    assert missing == []


def test_every_named_request_is_in_the_readme() -> None:
    """Each request name the parser accepts is listed for sender authors."""
    missing = [name for name in sorted(REQUEST_NAMES) if f"`{name}`" not in README]
    assert missing == []


def test_readme_shows_exactly_the_two_setup_commands() -> None:
    """A newcomer's two commands: make demo and make test."""
    assert "make demo" in README
    assert "make test" in README
