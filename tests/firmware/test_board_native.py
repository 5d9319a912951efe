"""The reference firmware's board logic (firmware/board/), built natively over a fake HAL.

firmware/native/test_board.c holds the C test functions (lease expiry within one tick,
duplicates replayed not re-executed, NAK with the rejected frame's seq, the probe's stop on
contact in the tick, Z_VELOCITY staleness and expiry, soft limits, E-stop and breakaway
latches, CONFIGURE refusals, the filters, ...); the program is compiled once per module
with strict flags and ASan/UBSan, and each C test runs as its own pytest test. The AVR
builds are checked to fit their MCUs.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from .native_tests import build_c_tests, listed_c_tests, run_c_test

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
TEST_SOURCE = FIRMWARE / "native" / "test_board.c"
SOURCES = (
    TEST_SOURCE,
    FIRMWARE / "native" / "hal_fake.c",
    FIRMWARE / "board" / "board.c",
    FIRMWARE / "board" / "board_cmd.c",
    FIRMWARE / "board" / "board_motion.c",
    ROOT / "firmware_protocol" / "c" / "dthc_protocol.c",
)
C_TESTS = listed_c_tests(TEST_SOURCE)
# The Nano's 2 KB: what static RAM may take so the stack (nested tick, UART and step
# interrupts under the main loop's deepest call: 175 B measured by the timing build) keeps
# its room.
NANO_STACK_RESERVE_B = 400
NANO_FLASH_B = 30 * 1024  # 32 KB less a 2 KB bootloader


@pytest.fixture(scope="module")
def test_board(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # BOARD_CURRENT_OUT: the mock device's build option (SET_CURRENT applied), tested here.
    exe = tmp_path_factory.mktemp("fw") / "test_board"
    return build_c_tests(SOURCES, exe, "-DBOARD_CURRENT_OUT=1")


def test_c_tests_are_listed() -> None:
    """The pattern finds the C test table (a renamed macro would silently run nothing)."""
    assert len(C_TESTS) >= 20


@pytest.mark.parametrize("name", C_TESTS)
def test_board_logic(test_board: Path, name: str) -> None:
    """One C test of the board logic passes (its name says what behaviour it proves)."""
    run_c_test(test_board, name)


def _section_sizes(elf: Path) -> dict[str, int]:
    out = subprocess.run(
        ["avr-size", "-A", str(elf)], capture_output=True, text=True, check=True, timeout=30
    ).stdout
    sizes: dict[str, int] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sizes[parts[0]] = int(parts[1])
    return sizes


@pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="avr-gcc not installed")
def test_avr_builds_fit(tmp_path: Path) -> None:
    """`make -C firmware firmware` builds both MCUs with -Werror, prints the sizes, and the
    Nano build leaves its stack reserve and fits below the bootloader."""
    proc = subprocess.run(
        ["make", "-C", str(FIRMWARE), f"BUILD={tmp_path}", "firmware"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "atmega2560  flash" in proc.stdout
    assert "atmega328p  flash" in proc.stdout
    for mcu, flash_b, ram_b, reserve_b in (
        ("atmega2560", 253_952, 8192, 4096),
        ("atmega328p", NANO_FLASH_B, 2048, NANO_STACK_RESERVE_B),
    ):
        sizes = _section_sizes(tmp_path / mcu / "dthc-firmware.elf")
        flash = sizes[".text"] + sizes.get(".data", 0)
        ram = sizes.get(".data", 0) + sizes.get(".bss", 0) + sizes.get(".noinit", 0)
        assert flash <= flash_b, f"{mcu}: {flash} B of flash"
        assert ram + reserve_b <= ram_b, f"{mcu}: {ram} B of static RAM"
        assert (tmp_path / mcu / "dthc-firmware.hex").stat().st_size > 0
