"""The emulated board as it comes off the shelf: Arduino's own bootloader (Debian's
arduino-core-avr) at the top of flash, the application erased, the MCU reset whenever the
port is opened. Debian's avrdude flashes the firmware's HEX through that bootloader with
firmware/README.md's own command (the port replaced by the pty); the daemon's handshake
then rides the bootloader window without a warning, and the conformance suite passes
against what was flashed.
"""

from __future__ import annotations

import asyncio
import json
import re
import shutil
import subprocess
import time
from collections.abc import MutableMapping
from pathlib import Path
from typing import Any

import pytest
import structlog.testing

from dthc_bridge.conformance import CHECK_NAMES
from dthc_bridge.link.session import BoardSession
from dthc_bridge.link.stats import LinkStats
from dthc_bridge.link.timing import LinkTiming
from dthc_bridge.transport import open_transport
from dthc_tools.emulated_board import (
    EmulatedBoard,
    EmulatedBoardError,
    HarnessOptions,
    arduino_bootloader,
    ensure_built,
    read_record,
)
from dthc_tools.emulated_board.build import BOOTLOADER_AVRDUDE, MCU_BOOTLOADERS

from .conformance_run import run_conformance

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

BAUD = 1_000_000  # the firmware's UART
FLASH_TIMEOUT_S = 60.0
HANDSHAKE_LIMIT_MS = 2500.0  # the boot window (under 1.5 s) and a loaded machine's slack


def readme_avrdude(root: Path, mcu: str, kind: str) -> list[str]:
    """firmware/README.md's avrdude command for ``mcu`` through its ``kind`` of bootloader
    (the programmer and baud rate of BOOTLOADER_AVRDUDE), as words."""
    programmer, baud = BOOTLOADER_AVRDUDE[kind]
    text = (root / "firmware" / "README.md").read_text()
    commands = re.sub(r"\\\n\s*", " ", text).splitlines()
    for line in commands:
        words = line.split()
        if (
            words[:1] == ["avrdude"]
            and f"-p {mcu}" in line
            and f"-c {programmer}" in line
            and f"-b {baud} " in line
        ):
            return words
    raise AssertionError(f"no avrdude command for {mcu} -c {programmer} -b {baud} in README")


def with_port(words: list[str], port: Path) -> list[str]:
    at = words.index("-P")
    return [*words[: at + 1], str(port), *words[at + 2 :]]


def flash_as_the_readme_says(root: Path, board: EmulatedBoard, mcu: str, kind: str) -> float:
    """README's avrdude command through the board's ``kind`` of bootloader, on its pty: it
    must write and verify the HEX. The seconds it took."""
    command = with_port(readme_avrdude(root, mcu, kind), board.pty)
    started_s = time.monotonic()
    done = subprocess.run(
        command, cwd=root, capture_output=True, text=True, timeout=FLASH_TIMEOUT_S, check=False
    )
    assert done.returncode == 0, done.stderr
    assert "bytes of flash verified" in done.stderr, done.stderr
    return time.monotonic() - started_s


async def daemon_handshake(port: Path) -> tuple[float, list[MutableMapping[str, Any]]]:
    """The daemon's own session opening ``port`` and shaking hands: milliseconds from the
    open to HELLO_INFO, and what it logged."""
    loop = asyncio.get_running_loop()
    with structlog.testing.capture_logs() as logs:
        session = BoardSession(str(port), LinkTiming(), LinkStats())
        started_s = loop.time()
        await session.open(
            lambda on_bytes, on_lost: open_transport(str(port), on_bytes, on_lost, baudrate=BAUD)
        )
        try:
            await session.handshake()
            elapsed_ms = (loop.time() - started_s) * 1e3
        finally:
            await session.close()
    return elapsed_ms, logs


@pytest.fixture
def tools() -> None:
    if shutil.which("avrdude") is None:
        pytest.skip("avrdude is not installed (apt-get install avrdude)")
    for mcu, kinds in MCU_BOOTLOADERS.items():
        for kind in kinds:
            try:
                arduino_bootloader(mcu, kind)
            except EmulatedBoardError as exc:
                pytest.skip(str(exc))


@pytest.mark.parametrize(("mcu", "kind"), [("atmega2560", "stk500v2"), ("atmega328p", "optiboot")])
def test_avrdude_flashes_through_the_bootloader_and_the_flashed_firmware_conforms(
    built: Path, tmp_path: Path, mcu: str, kind: str, tools: None
) -> None:
    """An erased board with Arduino's bootloader: README's avrdude command flashes and
    verifies the firmware's HEX over the pty; then the daemon's handshake, through the
    bootloader window that opening the port starts, answers within the window and logs no
    warning; then every conformance check passes against the flashed firmware (its reset
    check through the bootloader too)."""
    ensure_built(built, firmware=True)
    options = HarnessOptions(
        mcu=mcu, bootloader=True, bootloader_kind=kind, record=tmp_path / "record.csv",
        build=False, stderr=tmp_path / "host.log",
    )  # fmt: skip
    with EmulatedBoard(tmp_path / "board.pty", options) as board:
        flash_s = flash_as_the_readme_says(built, board, mcu, kind)
        handshake_ms, logs = asyncio.run(daemon_handshake(board.pty))
        loud = [e for e in logs if e.get("log_level") in ("warning", "error", "critical")]
        assert loud == []
        assert handshake_ms < HANDSHAKE_LIMIT_MS
        report = run_conformance(board, home=mcu == "atmega2560")
    # The homing cycle on the Mega (its switch at 102 mm); the Nano's build has none.
    expected = [n for n in CHECK_NAMES if mcu == "atmega2560" or n != "z_home_cycle"]
    assert [c["name"] for c in report["checks"] if c["passed"]] == expected
    assert options.record is not None
    resets = [e for e in read_record(options.record) if e.event == "reboot"]
    # avrdude's open, the daemon's, the suite's (and its reset check's SIGUSR2)
    assert sum(e.fields[:1] == ("auto_reset",) for e in resets) >= 3
    print(json.dumps({"mcu": mcu, "bootloader": kind, "avrdude_s": round(flash_s, 2),
                      "open_to_hello_info_ms": round(handshake_ms),
                      "conformance": f"{len(expected)}/{len(CHECK_NAMES)}"}))  # fmt: skip


def test_avrdude_flashes_the_old_nano_through_its_atmegaboot(
    built: Path, tmp_path: Path, tools: None
) -> None:
    """The old Nano's bootloader (ATmegaBOOT, most clones): README's 57600-baud command
    writes and verifies the firmware's HEX, and the flashed firmware answers the daemon's
    handshake (the whole suite runs on the optiboot Nano above: the same HEX)."""
    ensure_built(built, firmware=True)
    options = HarnessOptions(
        mcu="atmega328p", bootloader=True, bootloader_kind="atmegaboot", build=False,
        stderr=tmp_path / "host.log",
    )  # fmt: skip
    with EmulatedBoard(tmp_path / "board.pty", options) as board:
        flash_s = flash_as_the_readme_says(built, board, "atmega328p", "atmegaboot")
        handshake_ms, _ = asyncio.run(daemon_handshake(board.pty))
        assert handshake_ms < HANDSHAKE_LIMIT_MS
    print(json.dumps({"mcu": "atmega328p", "bootloader": "atmegaboot",
                      "avrdude_s": round(flash_s, 2),
                      "open_to_hello_info_ms": round(handshake_ms)}))  # fmt: skip
