"""Fixtures for the deployment tests: fake notify sockets (see notify_socket.py), a staging
root and a virtual environment's bin for the installer, and a runner that must not run."""

from collections.abc import Sequence
from pathlib import Path

import pytest

from .notify_socket import abstract_notify_socket, notify_socket

__all__ = ["abstract_notify_socket", "bin_dir", "never_run", "notify_socket", "root"]


def never_run(argv: Sequence[str]) -> None:
    """The installer's command runner in tests that stage files only."""
    raise AssertionError(f"command run: {argv}")


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
