"""The voltage-to-frequency front end's arithmetic (firmware/avr/arc_vtof_calc.h, what the
Mega's vtof build runs in its sample tick), built natively: counts to centivolts at 0 V, mid
and full scale, across a 16-bit counter wrap, with a late tick, at other sample rates.

firmware/native/test_arc_vtof.c holds the C tests; the program is compiled once per module
with strict flags and ASan/UBSan, and each C test runs as its own pytest test.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from .native_tests import build_c_tests, listed_c_tests, run_c_test

ROOT = Path(__file__).resolve().parents[2]
TEST_SOURCE = ROOT / "firmware" / "native" / "test_arc_vtof.c"
C_TESTS = listed_c_tests(TEST_SOURCE)


@pytest.fixture(scope="module")
def test_arc_vtof(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_c_tests([TEST_SOURCE], tmp_path_factory.mktemp("vtof") / "test_arc_vtof", "-lm")


def test_c_tests_are_listed() -> None:
    """The pattern finds the C test table (a renamed macro would silently run nothing)."""
    assert len(C_TESTS) >= 8


@pytest.mark.parametrize("name", C_TESTS)
def test_vtof_conversion(test_arc_vtof: Path, name: str) -> None:
    """One C test of the count-to-centivolt conversion passes."""
    run_c_test(test_arc_vtof, name)


AVR_FLAGS = ("-Os", "-std=c99", "-Wall", "-Wextra", "-Werror", "-DF_CPU=16000000UL", "-c")
needs_avr_gcc = pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="avr-gcc missing")


@needs_avr_gcc
def test_the_vtof_build_fits_and_prints_its_size(tmp_path: Path) -> None:
    """``make -C firmware vtof`` builds the Mega's V-to-F ELF and HEX with -Werror and prints
    its size line; flash and static RAM leave the Mega's stack its room."""
    proc = subprocess.run(
        ["make", "-C", str(ROOT / "firmware"), f"BUILD={tmp_path}", "vtof"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "atmega2560-vtof flash" in proc.stdout
    assert (tmp_path / "atmega2560-vtof" / "dthc-firmware.hex").stat().st_size > 0
    sizes = subprocess.run(
        ["avr-size", "-A", str(tmp_path / "atmega2560-vtof" / "dthc-firmware.elf")],
        capture_output=True, text=True, check=True, timeout=30,
    ).stdout  # fmt: skip
    section = {p[0]: int(p[1]) for p in map(str.split, sizes.splitlines()) if len(p) >= 2
               and p[0].startswith(".") and p[1].isdigit()}  # fmt: skip
    ram = section.get(".data", 0) + section.get(".bss", 0) + section.get(".noinit", 0)
    assert section[".text"] + section.get(".data", 0) <= 253_952
    assert ram + 4096 <= 8192


@needs_avr_gcc
@pytest.mark.parametrize(
    ("mcu", "source", "defines", "reason"),
    [
        # 2 kHz (the ADC builds' cap): 402 counts from 0 V to full scale per sample, < 500
        ("atmega2560", "avr/arc_vtof.c", ("-DBOARD_MAX_RATE_HZ=2000",), "enough_counts"),
        ("atmega328p", "avr/hal_avr.c", ("-DDTHC_ARC_VTOF=1",), "no V-to-F arc input"),
        ("atmega328p", "avr/arc_vtof.c", ("-DDTHC_ARC_VTOF=1",), "no V-to-F arc input"),
    ],
)
def test_builds_without_a_sane_vtof_resolution_are_refused(
    tmp_path: Path, mcu: str, source: str, defines: tuple[str, ...], reason: str
) -> None:
    """A sample rate that leaves too few counts per sample does not compile, nor does the
    V-to-F option on the Nano (its T1 pin is the OHMIC input)."""
    proc = subprocess.run(
        ["avr-gcc", f"-mmcu={mcu}", *AVR_FLAGS, *defines, source, "-o", str(tmp_path / "x.o")],
        cwd=ROOT / "firmware", capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode != 0
    assert reason in proc.stderr
