"""install-service / uninstall-service: the right files, idempotent, never a user's config lost."""

from __future__ import annotations

import argparse
import io
import os
import re
from pathlib import Path

import pytest

from dthc_bridge.deploy import install
from dthc_bridge.deploy.actions import Command, Context, StartService
from dthc_bridge.deploy.install import (
    CONFIG_PATH,
    RULES_PATH,
    UNIT_PATH,
    HostState,
    InstallOptions,
    UninstallOptions,
    add_install_arguments,
    add_uninstall_arguments,
    install_service,
    plan_install,
    run_install,
    run_uninstall,
    uninstall_service,
)
from dthc_bridge.deploy.render import BoardIds

from .conftest import file_mode, install_staged, never_run, staged

FRESH_HOST = HostState(
    user_exists=False,
    group_exists=False,
    serial_group_exists=True,
    user_in_serial_group=False,
    systemd_booted=True,
    has_udevadm=True,
)
INSTALLED_HOST = HostState(
    user_exists=True,
    group_exists=True,
    serial_group_exists=True,
    user_in_serial_group=True,
    systemd_booted=True,
    has_udevadm=True,
)


def _install(root: Path, bin_dir: Path, **changes: object) -> tuple[int, str]:
    return install_staged(root, bin_dir, FRESH_HOST, **changes)


def _uninstall(root: Path, **changes: object) -> tuple[int, str]:
    options = UninstallOptions(root=root, **changes)  # type: ignore[arg-type]
    out, err = io.StringIO(), io.StringIO()
    code = uninstall_service(options, out=out, err=err, host=INSTALLED_HOST, runner=never_run)
    return code, out.getvalue() + err.getvalue()


def test_staging_install_writes_the_filled_in_files(root: Path, bin_dir: Path) -> None:
    """Unit, rules and config land under the root with placeholders filled and tight modes."""
    board = BoardIds.parse("1209", "d7c0", "TABLE1")
    code, output = _install(root, bin_dir, board=board)
    assert code == 0, output
    unit = staged(root, UNIT_PATH).read_text()
    assert f"ExecStart={bin_dir}/dthc-bridge run --config /etc/dthc-bridge/config.toml" in unit
    assert "User=dthc" in unit
    rules = staged(root, RULES_PATH).read_text()
    assert 'ATTRS{serial}=="TABLE1"' in rules
    assert 'GROUP="dthc"' in rules
    for text in (unit, rules):
        assert re.search(r"@[A-Z_]+@", text) is None
    assert (
        staged(root, CONFIG_PATH).read_text()
        == (Path(install.__file__).parent / "templates" / "config.example.toml").read_text()
    )
    assert file_mode(staged(root, UNIT_PATH)) == 0o644
    assert file_mode(staged(root, RULES_PATH)) == 0o644
    assert file_mode(staged(root, CONFIG_PATH)) == 0o640
    assert file_mode(staged(root, "/etc/dthc-bridge")) == 0o750
    # Nothing touches the host from a staging root.
    assert "skip" in output
    assert "staging root" in output


def test_second_install_changes_nothing(root: Path, bin_dir: Path) -> None:
    """Re-running the installer rewrites nothing and keeps the config."""
    assert _install(root, bin_dir)[0] == 0
    before = {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}
    code, output = _install(root, bin_dir)
    assert code == 0
    assert {p: p.read_bytes() for p in root.rglob("*") if p.is_file()} == before
    assert "write" not in output
    assert f"unchanged        {UNIT_PATH}" in output
    assert f"unchanged        {RULES_PATH}" in output
    assert f"keep             {CONFIG_PATH} (exists; never overwritten)" in output


def test_existing_config_is_never_overwritten(root: Path, bin_dir: Path) -> None:
    """An operator's tuned configuration survives every install."""
    config = staged(root, CONFIG_PATH)
    config.parent.mkdir(parents=True)
    config.write_text('[board]\nlink = "/dev/ttyACM3"\n')
    assert _install(root, bin_dir)[0] == 0
    assert _install(root, bin_dir, board=BoardIds(serial="X1"))[0] == 0
    assert config.read_text() == '[board]\nlink = "/dev/ttyACM3"\n'


def test_new_serial_rewrites_only_the_rules(root: Path, bin_dir: Path) -> None:
    """Installing again with the board's serial updates the rules, not the unit."""
    assert _install(root, bin_dir)[0] == 0
    code, output = _install(root, bin_dir, board=BoardIds(serial="X1"))
    assert code == 0
    assert f"write            {RULES_PATH}" in output
    assert f"unchanged        {UNIT_PATH}" in output
    assert 'ATTRS{serial}=="X1"' in staged(root, RULES_PATH).read_text()


def test_dry_run_lists_every_action_and_changes_nothing(root: Path, bin_dir: Path) -> None:
    """--dry-run prints each file it would write and leaves the root empty."""
    code, output = _install(root, bin_dir, dry_run=True)
    assert code == 0
    assert "dry run" in output
    for path in (UNIT_PATH, RULES_PATH, CONFIG_PATH):
        assert f"would write      {path}" in output
    assert list(root.iterdir()) == []


def test_live_dry_run_shows_the_commands(bin_dir: Path) -> None:
    """On this system, the dry run names each command it would run, in order."""
    if Path(UNIT_PATH).exists() or Path(RULES_PATH).exists():
        pytest.skip("dthc-bridge is installed on this machine: the dry run would compare to it")
    out, err = io.StringIO(), io.StringIO()
    options = InstallOptions(dry_run=True, bin_dir=bin_dir)
    code = install_service(options, out=out, err=err, host=FRESH_HOST, runner=never_run)
    assert code == 0, err.getvalue()
    commands = [
        line.split("would run", 1)[1].strip()
        for line in out.getvalue().splitlines()
        if "would run" in line
    ]
    assert [c.split()[:2] for c in commands] == [
        ["useradd", "--system"],
        ["udevadm", "control"],
        ["udevadm", "trigger"],
        ["systemctl", "daemon-reload"],
        ["systemctl", "enable"],
        ["systemctl", "restart"],
    ]
    assert commands[0].endswith("--user-group --groups dialout dthc")
    assert "--shell /usr/sbin/nologin" in commands[0]
    assert "--no-create-home" in commands[0]


def test_account_steps_follow_what_exists() -> None:
    """useradd only for a missing user; usermod only to add a missing dialout membership."""

    def commands(host: HostState) -> list[str]:
        steps = plan_install(InstallOptions(bin_dir=Path("/opt/v/bin")), host)
        return [" ".join(step.argv) for step in steps if isinstance(step, Command)]

    assert not any(
        c.startswith(("useradd", "usermod", "groupadd")) for c in commands(INSTALLED_HOST)
    )
    group_only = HostState(**{**INSTALLED_HOST.__dict__, "user_exists": False})
    assert any(c.startswith("useradd") and "--gid dthc" in c for c in commands(group_only))
    not_in_dialout = HostState(**{**INSTALLED_HOST.__dict__, "user_in_serial_group": False})
    assert "usermod --append --groups dialout dthc" in commands(not_in_dialout)


def _run_live_commands(root: Path, bin_dir: Path) -> list[tuple[str, ...]]:
    """Apply the unit, rules and command steps as on a live system (files under ``root``)."""
    ran: list[tuple[str, ...]] = []
    ctx = Context(
        root=root, live=True, dry_run=False, out=io.StringIO(),
        runner=lambda argv: ran.append(tuple(argv)), systemd_booted=True, has_udevadm=True,
    )  # fmt: skip
    for step in plan_install(InstallOptions(root=root, bin_dir=bin_dir), INSTALLED_HOST):
        if isinstance(step, Command | StartService) or getattr(step, "target", "") in {
            UNIT_PATH,
            RULES_PATH,
        }:
            step.apply(ctx)
    return ran


def test_commands_run_only_for_what_changed(root: Path, bin_dir: Path) -> None:
    """First install: reload udev and systemd, enable, (re)start. Re-install: enable + start
    only, so a service that is running (maybe cutting) is not restarted."""
    assert _run_live_commands(root, bin_dir) == [
        ("udevadm", "control", "--reload"),
        ("udevadm", "trigger", "--action=change", "--subsystem-match=tty",
         "--subsystem-match=usb", "--subsystem-match=usb-serial"),
        ("systemctl", "daemon-reload"),
        ("systemctl", "enable", "dthc-bridge.service"),
        ("systemctl", "restart", "dthc-bridge.service"),
    ]  # fmt: skip
    assert _run_live_commands(root, bin_dir) == [
        ("systemctl", "enable", "dthc-bridge.service"),
        ("systemctl", "start", "dthc-bridge.service"),
    ]


def test_uninstall_removes_unit_and_rules_but_keeps_config(root: Path, bin_dir: Path) -> None:
    """Without --purge the configuration stays; a second uninstall finds nothing to do."""
    assert _install(root, bin_dir)[0] == 0
    code, output = _uninstall(root)
    assert code == 0, output
    assert not staged(root, UNIT_PATH).exists()
    assert not staged(root, RULES_PATH).exists()
    assert staged(root, CONFIG_PATH).exists()
    assert "--purge removes them" in output
    code, output = _uninstall(root)
    assert code == 0
    assert f"absent           {UNIT_PATH}" in output


def test_uninstall_purge_removes_the_configuration(root: Path, bin_dir: Path) -> None:
    """--purge also removes /etc/dthc-bridge and /var/lib/dthc-bridge."""
    assert _install(root, bin_dir)[0] == 0
    state = staged(root, "/var/lib/dthc-bridge")
    state.mkdir(parents=True)
    (state / "stats.json").write_text("{}")
    code, output = _uninstall(root, purge=True)
    assert code == 0, output
    assert not staged(root, "/etc/dthc-bridge").exists()
    assert not state.exists()
    assert "skip             userdel dthc (staging root)" in output


def test_live_install_needs_root(monkeypatch: pytest.MonkeyPatch, bin_dir: Path) -> None:
    """Not root, not --dry-run, not --root: a clear error and nothing done."""
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    err = io.StringIO()
    code = install_service(
        InstallOptions(bin_dir=bin_dir),
        out=io.StringIO(),
        err=err,
        host=FRESH_HOST,
        runner=never_run,
    )
    assert code == 1
    assert "run it as root" in err.getvalue()
    assert "--dry-run" in err.getvalue()
    code = uninstall_service(
        UninstallOptions(), out=io.StringIO(), err=err, host=INSTALLED_HOST, runner=never_run
    )
    assert code == 1


def test_live_install_refuses_a_missing_executable(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A unit whose ExecStart does not exist would fail with 203/EXEC: refuse up front."""
    monkeypatch.setattr(os, "geteuid", lambda: 0)
    err = io.StringIO()
    code = install_service(
        InstallOptions(bin_dir=tmp_path),
        out=io.StringIO(),
        err=err,
        host=FRESH_HOST,
        runner=never_run,
    )
    assert code == 1
    assert "missing or not executable" in err.getvalue()


def test_environment_under_home_is_flagged(root: Path) -> None:
    """ProtectHome=yes hides /home and /root: the installer says so."""
    code, output = _install(root, Path("/home/op/venv/bin"))
    assert code == 0
    assert "warning: the daemon's environment is under /home" in output


def test_command_line_options(root: Path, bin_dir: Path) -> None:
    """The argparse helpers the CLI wires in: install, then uninstall, by flags."""
    parser = argparse.ArgumentParser()
    add_install_arguments(parser)
    args = parser.parse_args(
        ["--root", str(root), "--bin-dir", str(bin_dir), "--vid", "0x0403", "--pid", "6015",
         "--serial", "DN05ABCD", "--no-start"]
    )  # fmt: skip
    assert run_install(args) == 0
    assert 'ATTRS{idVendor}=="0403"' in staged(root, RULES_PATH).read_text()
    assert run_install(parser.parse_args(["--root", str(root), "--vid", "12345"])) == 2

    parser = argparse.ArgumentParser()
    add_uninstall_arguments(parser)
    assert run_uninstall(parser.parse_args(["--root", str(root), "--purge"])) == 0
    assert not staged(root, UNIT_PATH).exists()
    assert not staged(root, CONFIG_PATH).exists()
