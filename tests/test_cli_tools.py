"""Runtime and tools apart: the daemon installs lean, tools say which extra they need."""

from __future__ import annotations

import subprocess
import sys
from importlib import metadata

import pytest

from dthc_bridge import cli

FAKE_REQUIRES = [
    "aiomqtt<3,>=2.5",
    'matplotlib>=3.8; extra == "demo"',
    'amqtt<0.13,>=0.12; extra == "demo"',
    'dthc-bridge[demo]; extra == "bench"',
    'looptime<1,>=0.9; extra == "bench"',
    'pytest>=8; extra == "dev"',
]


def test_the_runtime_dependencies_carry_no_tool() -> None:
    """matplotlib, amqtt and looptime are extras' dependencies, never the daemon's."""
    runtime = [r for r in metadata.requires("dthc-bridge") or [] if "extra ==" not in r]
    names = {r.split(";")[0].split("<")[0].split(">")[0].split("=")[0].strip() for r in runtime}
    assert names.isdisjoint({"matplotlib", "amqtt", "looptime", "pytest"}), names
    assert {"aiomqtt", "pyserial", "pyusb", "pydantic", "structlog"} <= names


def test_the_daemon_imports_no_tool_and_no_mock() -> None:
    """Importing and parsing the daemon's command line pulls in no tool package, no mock
    board and no tool dependency."""
    code = (
        "import sys, dthc_bridge.cli, dthc_bridge.daemon;"
        "dthc_bridge.cli.build_parser();"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('dthc_tools', 'mock_device', 'matplotlib', 'amqtt', 'looptime'));"
        "print(bad)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert out.stdout.strip() == "[]"


def test_an_installed_extra_is_complete() -> None:
    """In the development install every tool's extra is there."""
    for tool in cli.TOOL_COMMANDS.values():
        assert cli.missing_for_extra(tool.extra) == [], tool


def _fake_metadata(monkeypatch: pytest.MonkeyPatch, installed: set[str]) -> None:
    def version(name: str) -> str:
        if name not in installed:
            raise metadata.PackageNotFoundError(name)
        return "1.0"

    monkeypatch.setattr(metadata, "requires", lambda _dist: FAKE_REQUIRES)
    monkeypatch.setattr(metadata, "version", version)


def test_a_missing_extra_is_named_with_what_it_lacks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Extras of extras are followed: bench needs the demo's plot library too."""
    _fake_metadata(monkeypatch, installed={"aiomqtt", "amqtt", "pytest"})
    assert cli.missing_for_extra("demo") == ["matplotlib"]
    assert cli.missing_for_extra("bench") == ["matplotlib", "looptime"]
    assert cli.missing_for_extra("sender") == []


def test_a_tool_without_its_extra_says_how_to_install_it(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``dthc-bridge bench control`` on a runtime-only install: exit 2 and one line naming
    the extra, what is missing and the pip command; nothing is run."""
    _fake_metadata(monkeypatch, installed={"aiomqtt"})
    assert cli.main(["bench", "control", "--json"]) == 2
    err = capsys.readouterr().err
    assert "needs the 'bench' extra" in err
    assert "matplotlib" in err
    assert "pip install 'dthc-bridge[bench]'" in err


def test_tool_arguments_pass_through_untouched(capsys: pytest.CaptureFixture[str]) -> None:
    """Everything after the tool's name is the tool's: its own --help answers."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--log-level", "warning", "demo", "--help"])
    assert exit_info.value.code == 0
    assert "usage: dthc-bridge demo" in capsys.readouterr().out
