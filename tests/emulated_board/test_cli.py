"""``dthc-emulated-board`` before it execs anything: what it says when it cannot run."""

from __future__ import annotations

import os
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


def test_arc_input_vtof_runs_the_vtof_build_with_the_card_model(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``--arc-input vtof`` execs the host with the Mega's vtof ELF
    (firmware/build/atmega2560-vtof) and passes the card's scaling through."""
    calls: list[list[str]] = []

    def fake_execv(path: str, argv: list[str]) -> None:
        calls.append(argv)

    monkeypatch.setattr(cli, "ensure_built", lambda root, firmware: None)
    monkeypatch.setattr(os, "execv", fake_execv)
    pty = str(tmp_path / "board")
    cli.main(["--pty", pty, "--arc-input", "vtof", "--vtof-zero-hz", "100000"])
    (argv,) = calls
    elf = Path(argv[argv.index("--elf") + 1])
    assert elf.parts[-2:] == ("atmega2560-vtof", "dthc-firmware.elf")
    assert argv[argv.index("--arc-input") + 1] == "vtof"
    assert float(argv[argv.index("--vtof-zero-hz") + 1]) == 100000.0
    calls.clear()
    cli.main(["--pty", pty])
    assert Path(calls[0][calls[0].index("--elf") + 1]).parts[-2] == "atmega2560"


def test_the_nano_has_no_vtof_build(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The 328P's T1 pin is its OHMIC input: ``--mcu atmega328p --arc-input vtof`` says so
    and exits 2."""
    monkeypatch.setattr(cli, "ensure_built", lambda root, firmware: None)
    argv = ["--pty", str(tmp_path / "board"), "--mcu", "atmega328p", "--arc-input", "vtof"]
    assert cli.main(argv) == cli.EXIT_SETUP
    assert "no V-to-F arc input" in capsys.readouterr().err


def test_bootloader_runs_arduinos_bootloader_with_the_flashed_hex(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """``--bootloader`` execs the host with Arduino's bootloader HEX for the MCU and no ELF
    (``--flash HEX`` passed through; without it the application is erased); ``--flash``
    alone is refused."""
    calls: list[list[str]] = []
    monkeypatch.setattr(cli, "ensure_built", lambda root, firmware: None)
    monkeypatch.setattr(os, "execv", lambda path, argv: calls.append(argv))
    monkeypatch.setattr(
        cli, "arduino_bootloader", lambda mcu, kind=None: Path(f"/boot/{mcu}-{kind}.hex")
    )
    pty = str(tmp_path / "board")
    cli.main(["--pty", pty, "--mcu", "atmega328p", "--bootloader", "--flash", "app.hex"])
    (argv,) = calls
    assert "--elf" not in argv
    assert argv[argv.index("--bootloader") + 1] == "/boot/atmega328p-None.hex"
    assert argv[argv.index("--flash") + 1] == "app.hex"
    calls.clear()
    cli.main(["--pty", pty, "--bootloader"])
    assert "--flash" not in calls[0]
    calls.clear()
    cli.main(["--pty", pty, "--mcu", "atmega328p", "--bootloader", "atmegaboot"])
    assert calls[0][calls[0].index("--bootloader") + 1] == "/boot/atmega328p-atmegaboot.hex"
    with pytest.raises(SystemExit):
        cli.main(["--pty", pty, "--flash", "app.hex"])
    assert "--flash needs --bootloader" in capsys.readouterr().err
