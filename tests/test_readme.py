"""The README stays true to the code: every configuration key and request is documented."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel

from dthc_bridge.config import DaemonConfig
from dthc_bridge.requests import REQUESTS

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
    """Each request of the daemon's request table is listed for sender authors."""
    missing = [name for name in sorted(REQUESTS) if f"`{name}`" not in README]
    assert missing == []


def test_readme_shows_exactly_the_two_setup_commands() -> None:
    """A newcomer's two commands: make demo and make test."""
    assert "make demo" in README
    assert "make test" in README


def _defaults(model: type[BaseModel], prefix: str) -> dict[str, object]:
    defaults: dict[str, object] = {}
    for name, field in model.model_fields.items():
        annotation = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            defaults |= _defaults(annotation, f"{prefix}{name}.")
        else:
            defaults[f"{prefix}{name}"] = field.default
    return defaults


def _shown(value: object) -> str:
    if value is None:
        return "none"
    if isinstance(value, str):
        return f'`"{value}"`'
    return f"`{value!r}`"


def test_every_configuration_default_in_the_readme_is_the_models() -> None:
    """The README's default column shows each key's default as the model has it."""
    rows = {}
    for line in README.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if len(cells) >= 2 and cells[0].startswith("`") and cells[0].endswith("`"):
            rows[cells[0].strip("`")] = cells[1]
    defaults = _defaults(DaemonConfig, "")
    wrong = {
        key: rows.get(key) for key, value in defaults.items() if rows.get(key) != _shown(value)
    }
    assert wrong == {}
