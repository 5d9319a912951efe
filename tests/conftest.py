"""Fixtures for every test."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest
import structlog

from dthc_bridge.link import frametrace


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
