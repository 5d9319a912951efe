"""Fixtures for the deployment tests: fake notify sockets (see notify_socket.py), a staging
root and a virtual environment's bin for the installer, and a runner that must not run."""

import io
import stat
from collections.abc import Sequence
from pathlib import Path

import pytest

from dthc_bridge.deploy.install import HostState, InstallOptions, install_service

from .notify_socket import abstract_notify_socket, notify_socket

__all__ = [
    "abstract_notify_socket",
    "bin_dir",
    "file_mode",
    "install_staged",
    "never_run",
    "notify_socket",
    "root",
    "staged",
]


def never_run(argv: Sequence[str]) -> None:
    """The installer's command runner in tests that stage files only."""
    raise AssertionError(f"command run: {argv}")


def install_staged(
    root: Path, bin_dir: Path, host: HostState, **changes: object
) -> tuple[int, str]:
    """An installation staged under ``root`` on a machine like ``host``: (exit status,
    what it printed)."""
    options = InstallOptions(root=root, bin_dir=bin_dir, **changes)  # type: ignore[arg-type]
    out, err = io.StringIO(), io.StringIO()
    code = install_service(options, out=out, err=err, host=host, runner=never_run)
    return code, out.getvalue() + err.getvalue()


def staged(root: Path, system_path: str) -> Path:
    """Where a system path lands under the staging root."""
    return root / system_path.lstrip("/")


def file_mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.fixture
def root(tmp_path: Path) -> Path:
    path = tmp_path / "root"
    path.mkdir()
    return path


@pytest.fixture
def bin_dir(tmp_path: Path) -> Path:
    path = tmp_path / "opt" / "venv" / "bin"
    path.mkdir(parents=True)
    (path / "dthc-bridge").write_text("#!/bin/sh\n")
    (path / "dthc-bridge").chmod(0o755)
    return path
