"""A C test program of the firmware built natively (strict flags, ASan/UBSan) and its tests
listed from its table, so each C test runs as its own pytest test."""

from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

import pytest

__all__ = ["CFLAGS", "SANITIZE", "build_c_tests", "listed_c_tests", "run_c_test"]

CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O1", "-g")
SANITIZE = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all")


def listed_c_tests(source: Path) -> list[str]:
    """The C tests in the order the program's TESTS table lists them (``T(name),``)."""
    return re.findall(r"^\s+T\((\w+)\),$", source.read_text(), re.MULTILINE)


def build_c_tests(sources: Sequence[Path], exe: Path, *libs: str) -> Path:
    """Compile ``sources`` into ``exe``; skips the test where there is no C compiler."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler")
    cmd = [compiler, *CFLAGS, *SANITIZE, *map(str, sources), *libs, "-o", str(exe)]
    subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=120)
    return exe


def run_c_test(exe: Path, name: str) -> None:
    """Run one C test by name; it must print ``ok NAME`` and exit 0."""
    proc = subprocess.run([str(exe), name], capture_output=True, text=True, timeout=30, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip() == f"ok {name}"
