"""The grbl port's unit (issue 32): ``install-service --grbl DEVICE`` writes, enables and
starts it in front of the table's grbl, logged in as the sender role when the installer
wrote the broker's files; systemd accepts it and its sandbox scores well; the port gives its
pty to the serial ports' group, so a sender running as another user opens it."""

from __future__ import annotations

import grp
import os
import re
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

from dthc_bridge.deploy.broker import BrokerOptions, Listener
from dthc_bridge.deploy.install import (
    PORT_UNIT_PATH,
    UninstallOptions,
    plan_uninstall,
)
from dthc_bridge.deploy.render import DEFAULT_GRBL_LISTEN, DeployError, render_port_unit
from dthc_tools.grbl_port.cli import build_parser, share_pty
from mock_device.links import PtyLink

from .conftest import install_staged, staged
from .test_install import FRESH_HOST, INSTALLED_HOST

SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
needs_systemd_analyze = pytest.mark.skipif(
    SYSTEMD_ANALYZE is None, reason="systemd-analyze not installed (Debian package: systemd)"
)


def _exec_start(unit: str) -> list[str]:
    line = next(x for x in unit.splitlines() if x.startswith("ExecStart="))
    return line.removeprefix("ExecStart=").split()


def test_install_with_grbl_writes_the_port_unit_logged_in_as_the_sender(
    root: Path, bin_dir: Path
) -> None:
    code, said = install_staged(
        root, bin_dir, FRESH_HOST, grbl="/dev/ttyUSB1", board_id="plasma", start=False,
        broker=BrokerOptions(listen=Listener(1884, "127.0.0.1")),
    )  # fmt: skip
    assert code == 0, said
    unit = staged(root, PORT_UNIT_PATH).read_text()
    argv = _exec_start(unit)
    assert argv[:2] == [f"{bin_dir}/dthc-bridge", "grbl-port"]
    options = dict(zip(argv[2::2], argv[3::2], strict=False))
    assert options["--grbl"] == "/dev/ttyUSB1"
    assert options["--listen"] == DEFAULT_GRBL_LISTEN
    assert options["--board-id"] == "plasma"
    # With the broker's files written (a default install, invariant 8), the port logs in
    # as the sender role, the one role the ACL lets light the torch.
    assert options["--broker"] == "mqtt://dthc-sender@localhost:1884"
    assert options["--broker-password-file"] == "/etc/dthc-bridge/broker/sender.password"
    assert "systemctl start dthc-grbl-port.service" in said
    assert DEFAULT_GRBL_LISTEN in said  # where to point the sender


def test_a_broker_the_installer_did_not_write_gets_the_ports_defaults(
    root: Path, bin_dir: Path
) -> None:
    code, said = install_staged(root, bin_dir, FRESH_HOST, grbl="socket://10.0.0.7:23")
    assert code == 0, said
    argv = _exec_start(staged(root, PORT_UNIT_PATH).read_text())
    assert "--broker" not in argv
    assert argv[argv.index("--grbl") + 1] == "socket://10.0.0.7:23"


def test_install_without_grbl_has_no_port_unit(root: Path, bin_dir: Path) -> None:
    code, said = install_staged(root, bin_dir, FRESH_HOST, start=False)
    assert code == 0, said
    assert not staged(root, PORT_UNIT_PATH).exists()
    assert "dthc-grbl-port" not in said


@pytest.mark.parametrize("bad", ["/dev/tty USB0", "/dev/%h", "COM3", "socket://host", "$GRBL"])
def test_a_grbl_systemd_would_reinterpret_is_refused_naming_it(bad: str, tmp_path: Path) -> None:
    with pytest.raises(DeployError, match="--grbl"):
        render_port_unit(bin_dir=tmp_path, user="dthc", group="dthc", grbl=bad)


def test_uninstall_removes_the_port_unit() -> None:
    steps = plan_uninstall(UninstallOptions(), INSTALLED_HOST)
    described = [str(getattr(s, "argv", getattr(s, "target", ""))) for s in steps]
    assert any("dthc-grbl-port.service" in d and "disable" in d for d in described), described
    assert PORT_UNIT_PATH in described


@needs_systemd_analyze
def test_systemd_accepts_the_port_unit_and_its_sandbox_scores_well(
    tmp_path: Path, bin_dir: Path
) -> None:
    assert SYSTEMD_ANALYZE is not None
    path = tmp_path / "dthc-grbl-port.service"
    path.write_text(
        render_port_unit(bin_dir=bin_dir, user="root", group="root", grbl="/dev/ttyUSB1")
    )
    verify = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", "--man=no", str(path)], capture_output=True, text=True,
        check=False,
    )  # fmt: skip
    complaints = [
        line for line in verify.stderr.splitlines()
        if "dthc-grbl-port" in line and "bin/dthc-bridge" not in line
    ]  # fmt: skip
    assert verify.returncode == 0, verify.stderr
    assert not complaints, verify.stderr
    security = subprocess.run(
        [SYSTEMD_ANALYZE, "security", "--offline=yes", "--no-pager", str(path)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if "unrecognized option" in security.stderr:
        pytest.skip("this systemd-analyze has no security --offline")
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", security.stdout)
    assert match is not None, security.stdout + security.stderr
    exposure = float(match.group(1))
    print({"port_unit_exposure": exposure})
    assert exposure <= 2.0, security.stdout  # measured 2.0 (the daemon's: 1.5)


async def test_the_port_gives_its_pty_to_the_serial_group_mode_0660(tmp_path: Path) -> None:
    group = grp.getgrgid(os.getgid()).gr_name  # a group this user may give
    link = PtyLink(tmp_path / "grbl", lambda _: None)
    await link.open()
    try:
        share_pty(link, group)
        device = (tmp_path / "grbl").resolve().stat()
        assert device.st_gid == os.getgid()
        assert stat.S_IMODE(device.st_mode) == 0o660
    finally:
        await link.close()
    assert build_parser().parse_args(["--listen", "x", "--grbl", "y"]).pty_group == "dialout"
