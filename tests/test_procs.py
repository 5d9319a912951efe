"""Children die with their parent, even when the parent is SIGKILLed.

The helper (``dthc_tools.procs.die_with_parent``, the kernel's parent-death signal), the
case from the issue (a killed latency bench left its mock running for good), and the mock
board's own watch on its parent for mocks started without the helper.

A killed parent's children are reparented to init (or a subreaper), which reaps them: a
zombie counts as gone, and a pid is matched with its start time so a reused pid is not
taken for the child.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from dthc_tools.procs import die_with_parent

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="PR_SET_PDEATHSIG is Linux's")

REPO = Path(__file__).parents[1]
POLL_S = 0.01


def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, start time in clock ticks) from /proc/PID/stat; None: no such pid."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = text.rpartition(")")[2].split()  # after "pid (comm)", which may hold spaces
    return fields[0], int(fields[1]), int(fields[19])


class Watched:
    """A process seen in /proc, followed by pid and start time."""

    def __init__(self, pid: int) -> None:
        stat = _stat(pid)
        assert stat is not None, f"pid {pid} is not running"
        self.pid = pid
        self.started = stat[2]

    def gone(self) -> bool:
        stat = _stat(self.pid)
        return stat is None or stat[2] != self.started or stat[0] in "ZX"

    def wait_gone(self, within_s: float) -> float | None:
        """Seconds until it was gone, or None if it still runs after ``within_s``."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < within_s:
            if self.gone():
                return time.monotonic() - t0
            time.sleep(POLL_S)
        return None

    def kill(self) -> None:
        if not self.gone():
            os.kill(self.pid, signal.SIGKILL)


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``, found by scanning /proc."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            stat = _stat(int(entry.name))
            if stat is not None and stat[1] == pid:
                found.append(int(entry.name))
    return found


def _cmdline(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
    except (FileNotFoundError, ProcessLookupError):
        return []


@contextmanager
def _parent(code: str) -> Iterator[subprocess.Popen[str]]:
    """``python -c CODE`` (a parent the test SIGKILLs), itself dying with this process."""
    proc = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)], cwd=REPO, text=True,
        stdout=subprocess.PIPE, preexec_fn=die_with_parent(),
    )  # fmt: skip
    try:
        yield proc
    finally:
        proc.kill()
        proc.wait(5)
        if proc.stdout is not None:
            proc.stdout.close()


def _read_pid(parent: subprocess.Popen[str]) -> Watched:
    assert parent.stdout is not None
    line = parent.stdout.readline()
    assert line.strip().isdigit(), line
    return Watched(int(line))


def _kill_parent_then_expect_gone(code: str, what: str, *, within_s: float) -> None:
    """Run ``code`` as a parent that prints its child's pid, SIGKILL the parent, and
    assert the child is gone within ``within_s``."""
    with _parent(code) as parent:
        child = _read_pid(parent)
        try:
            parent.kill()
            took_s = child.wait_gone(within_s)
            assert took_s is not None, f"{what} outlived its SIGKILLed parent"
        finally:
            child.kill()


def test_a_child_started_with_die_with_parent_dies_when_its_parent_is_sigkilled() -> None:
    """A parent starts a sleeper with ``preexec_fn=die_with_parent()`` and is SIGKILLed:
    the kernel kills the sleeper (PR_SET_PDEATHSIG) within 2 s, not 60 s later."""
    code = """
        import subprocess, sys, time
        from dthc_tools.procs import die_with_parent
        child = subprocess.Popen(
            [sys.executable, "-c", "import time; time.sleep(60)"], preexec_fn=die_with_parent()
        )
        print(child.pid, flush=True)
        time.sleep(60)
    """
    _kill_parent_then_expect_gone(code, "the child", within_s=2.0)


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_killing_the_latency_bench_kills_its_mock_board(tmp_path: Path) -> None:
    """The issue's case: ``bench latency`` is SIGKILLed while it measures over the pty; its
    mock board process is gone within 3 s. No latency log was written: the mock was
    killed by the kernel (the bench spawned it through die_with_parent), not stopped by
    its own parent watch, which would have written the log on its way out."""
    bench = subprocess.Popen(
        [sys.executable, "-m", "dthc_tools.bench", "latency", "--json", "--duration", "30"],
        cwd=REPO, env={**os.environ, "TMPDIR": str(tmp_path)},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=die_with_parent(),
    )  # fmt: skip
    mock: Watched | None = None
    try:
        deadline = time.monotonic() + 30.0
        while mock is None or not list(tmp_path.glob("dthc-bench-*/board")):
            assert time.monotonic() < deadline, "the bench started no mock board on a pty"
            assert bench.poll() is None, "the bench exited early"
            if mock is None:
                pids = [p for p in _children(bench.pid) if "mock_device" in _cmdline(p)]
                mock = Watched(pids[0]) if pids else None
            time.sleep(0.05)
        time.sleep(0.5)  # the mock runs its loop; the bench measures
        assert not mock.gone()
        bench.kill()
        took_s = mock.wait_gone(3.0)
        assert took_s is not None, "the mock board outlived its SIGKILLed bench"
        assert not list(tmp_path.glob("dthc-bench-*/latency.jsonl"))
    finally:
        bench.kill()
        bench.wait(5)
        if mock is not None:
            mock.kill()


@pytest.mark.slow
def test_a_mock_started_without_the_helper_exits_cleanly_when_its_parent_dies(
    tmp_path: Path,
) -> None:
    """A parent starts ``python -m mock_device --pty ...`` with a plain Popen (no parent-death
    signal) and is SIGKILLed: the mock sees its parent change and ends its run loop within
    2 s, as on SIGTERM: it logs parent_gone, then its exit report, and writes its truth."""
    log, truth = tmp_path / "mock.log", tmp_path / "truth.jsonl"
    code = f"""
        import subprocess, sys, time
        mock = subprocess.Popen(
            [sys.executable, "-m", "mock_device", "--pty", {str(tmp_path / "dthc0")!r},
             "--truth", {str(truth)!r}],
            stdout=subprocess.PIPE, stderr=open({str(log)!r}, "w"), text=True,
        )
        assert mock.stdout.readline().startswith("READY")
        print(mock.pid, flush=True)
        time.sleep(60)
    """
    _kill_parent_then_expect_gone(code, "the mock", within_s=2.0)
    events = [json.loads(line)["event"] for line in log.read_text().splitlines()]
    assert events[-2:] == ["parent_gone", "exit"]
    assert truth.exists()
