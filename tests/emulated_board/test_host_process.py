"""The emulated-board host as a process: how it starts, fails, and ends; the console script
(``dthc-emulated-board``) in front of it; the Nano/Uno (ATmega328P) pin map."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from dthc_tools.emulated_board import ControlError, host_binary, selftest_elf
from dthc_tools.procs import die_with_parent

from .conftest import start_selftest

pytestmark = pytest.mark.slow


def _wait_gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.02)
    return False


def test_a_missing_elf_or_pty_directory_exits_2_with_the_reason(
    built: Path, tmp_path: Path
) -> None:
    """No ELF, or a pty path whose directory does not exist: exit status 2 and a message
    naming the path; no READY."""
    host = str(host_binary(built))
    elf = str(selftest_elf(built, "atmega2560"))
    cases = [
        ([host, "--elf", str(tmp_path / "none.elf"), "--pty", str(tmp_path / "p")], "none.elf"),
        ([host, "--elf", elf, "--pty", str(tmp_path / "no" / "dir" / "p")], "does not exist"),
        ([host, "--elf", elf, "--pty", str(tmp_path)], "not a symlink"),
        ([host, "--elf", elf, "--pty", str(tmp_path / "p"), "--mcu", "atmega8"], "atmega8"),
    ]
    for argv, reason in cases:
        done = subprocess.run(
            argv, capture_output=True, text=True, timeout=10, check=False, stdin=subprocess.DEVNULL
        )
        assert done.returncode == 2, done
        assert reason in done.stderr
        assert "READY" not in done.stdout


def test_sigterm_exits_cleanly_and_removes_the_pty_link(built: Path, tmp_path: Path) -> None:
    """SIGTERM: exit status 0, the symlink gone, the record ends with an exit line."""
    board, client = start_selftest(built, tmp_path)
    client.close()
    link = tmp_path / "board.pty"
    assert link.is_symlink()
    assert board.stop() == 0
    assert not link.exists()
    assert (tmp_path / "record.csv").read_text().splitlines()[-1].split(",")[2] == "exit"


def test_the_host_dies_when_its_parent_is_killed(built: Path, tmp_path: Path) -> None:
    """A parent that starts the host and is then SIGKILLed takes the host with it: the
    kernel's parent-death signal (SIGTERM, so it still removes its pty link)."""
    host = host_binary(built)
    elf = selftest_elf(built, "atmega2560")
    script = textwrap.dedent(f"""
        import subprocess, sys
        p = subprocess.Popen([{str(host)!r}, "--elf", {str(elf)!r}, "--pty",
                              {str(tmp_path / "orphan.pty")!r}], stdout=subprocess.PIPE,
                              stdin=subprocess.DEVNULL)
        print(p.pid, p.stdout.readline().decode().strip(), flush=True)
        import time; time.sleep(60)
    """)
    parent = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
        preexec_fn=die_with_parent(),
    )  # fmt: skip
    assert parent.stdout is not None
    pid_text, ready = parent.stdout.readline().split(" ", 1)
    assert ready.startswith("READY")
    parent.send_signal(signal.SIGKILL)
    parent.wait(5)
    parent.stdout.close()
    assert _wait_gone(int(pid_text), 3.0)
    assert not (tmp_path / "orphan.pty").exists()


def test_the_command_execs_the_host_in_its_own_pid(built: Path, tmp_path: Path) -> None:
    """``dthc-emulated-board --selftest`` (its ``main()``, run as a module here: the console
    script may not be installed yet): the PID the user started is the host program itself
    (exec), so SIGUSR2 to it resets the MCU; model options reach the host."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "dthc_tools.emulated_board.cli", "--selftest", "--no-build",
         "--pty", str(tmp_path / "cli.pty"), "--plate-mm", "12.5"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, preexec_fn=die_with_parent(),
    )  # fmt: skip
    assert proc.stdout is not None
    assert proc.stdin is not None
    try:
        assert proc.stdout.readline().strip() == f"READY {tmp_path / 'cli.pty'}"
        assert Path(f"/proc/{proc.pid}/exe").resolve().name == "dthc-emulated-board-host"
        proc.stdin.write("status\n")
        proc.stdin.flush()
        assert "plate_mm=12.5000" in proc.stdout.readline()
        proc.send_signal(signal.SIGUSR2)
        time.sleep(0.1)
        proc.stdin.write("status\n")
        proc.stdin.flush()
        assert "reboots=1" in proc.stdout.readline()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(5) == 0
        proc.stdin.close()
        proc.stdout.close()


def test_atmega328p_map_steps_echoes_and_has_no_thc_or_limit_inputs(
    built: Path, tmp_path: Path
) -> None:
    """The Nano/Uno build: the same wires on its own pins; THC up/down and Z limit inputs
    do not exist there, and forcing one is refused."""
    board, client = start_selftest(built, tmp_path, mcu="atmega328p")
    try:
        assert client.ask("Ehello") == "Ehello"
        assert client.ask("U200") == "S200"
        assert board.status().z_um == 61_000
        board.set_input("estop", True)
        assert client.ask("I") == "I40"
        board.set_input("estop", None)
        with pytest.raises(ControlError, match="no thc_up input"):
            board.set_input("thc_up", True)
        assert "z_limit_max" not in board.status().inputs
    finally:
        client.close()
        board.stop()
