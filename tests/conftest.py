"""Fixtures for every test."""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator

import pytest
import structlog

from dthc_bridge.link import frametrace


@pytest.fixture(autouse=True, scope="session")
def state_home(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Daemons started by the tests (in-process or as processes, which inherit it) keep
    their state (consumables.json) here, not in the user's ~/.local/state."""
    saved = os.environ.get("XDG_STATE_HOME")
    os.environ["XDG_STATE_HOME"] = str(tmp_path_factory.mktemp("state-home"))
    yield
    if saved is None:
        os.environ.pop("XDG_STATE_HOME", None)
    else:
        os.environ["XDG_STATE_HOME"] = saved


@pytest.fixture(autouse=True)
def restore_logging() -> Iterator[None]:
    """A test (or a tool it runs in-process) may configure logging onto its captured
    stderr; put everything back after it, so no later test logs into a closed stream."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    config = structlog.get_config()
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
    structlog.configure(**config)
    frametrace.enable(0)
