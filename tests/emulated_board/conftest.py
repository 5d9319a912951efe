"""Fixtures: the harness built once, one self-test board per module where tests can share it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from dthc_tools.emulated_board import (
    EmulatedBoard,
    HarnessOptions,
    checkout_root,
    ensure_built,
    missing_tools,
    selftest_elf,
)

from .serial_line import LineClient

MISSING = missing_tools()
needs_tools = pytest.mark.skipif(
    bool(MISSING), reason=f"emulated-board build tools missing: {', '.join(MISSING)}"
)


@pytest.fixture(scope="session")
def built() -> Path:
    """The checkout, with the host program and the self-test ELFs built (not the firmware)."""
    if MISSING:
        pytest.skip(f"emulated-board build tools missing: {', '.join(MISSING)}")
    root = checkout_root()
    ensure_built(root, firmware=False)
    return root


def start_selftest(
    root: Path, tmp: Path, mcu: str = "atmega2560", model: dict[str, float] | None = None
) -> tuple[EmulatedBoard, LineClient]:
    options = HarnessOptions(
        mcu=mcu, elf=selftest_elf(root, mcu), record=tmp / "record.csv", model=model or {},
        build=False, stderr=tmp / "host.log",
    )  # fmt: skip
    board = EmulatedBoard(tmp / "board.pty", options)
    board.start()
    client = LineClient(tmp / "board.pty")
    client.drain(0.05)  # the boot banner
    return board, client


@pytest.fixture(scope="module")
def selftest_board(
    built: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[EmulatedBoard, LineClient, Path]]:
    """One self-test board (Mega 2560, noise off) shared by a module's tests."""
    tmp = tmp_path_factory.mktemp("emu")
    board, client = start_selftest(built, tmp, model={"noise-v": 0.0})
    try:
        yield board, client, tmp
    finally:
        client.close()
        board.stop()
