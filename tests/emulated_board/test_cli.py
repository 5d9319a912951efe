"""``dthc-emulated-board`` before it execs anything: what it says when it cannot run."""

from __future__ import annotations

from pathlib import Path

import pytest

from dthc_tools.emulated_board import INSTALL_HINT, build, cli


def test_missing_build_tools_name_the_install_command_and_exit_2(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Without avr-gcc (or simavr's headers) the command names what is missing and the
    apt-get line that installs it, and exits 2 without building or starting anything."""
    monkeypatch.setattr(build, "missing_tools", lambda: ["avr-gcc", "simavr (pkg-config)"])
    assert cli.main(["--pty", str(tmp_path / "board")]) == cli.EXIT_SETUP
    err = capsys.readouterr().err
    assert "avr-gcc, simavr (pkg-config)" in err
    assert INSTALL_HINT in err
    assert "apt-get install simavr libsimavr-dev" in INSTALL_HINT


def test_a_checkout_without_the_emulator_is_named(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Installed without the source tree (no firmware/emulator beside the package): a clear
    error and exit 2."""
    monkeypatch.setattr(build, "__file__", str(tmp_path / "a" / "b" / "build.py"))
    monkeypatch.setattr(cli, "checkout_root", build.checkout_root)
    assert cli.main(["--pty", str(tmp_path / "board")]) == cli.EXIT_SETUP
    assert "installed editable from a source checkout" in capsys.readouterr().err
