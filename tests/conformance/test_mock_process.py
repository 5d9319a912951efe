"""``dthc-bridge conformance`` against the mock board as its own process on a pty.

The good firmware passes every check; each firmware variant with a deliberate fault is
caught by the check written for it, with a non-zero exit status; a board whose CRC is wrong
fails the handshake and the suite ends at once instead of waiting on every check.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from dthc_bridge.conformance import CHECK_NAMES, EXIT_FAILED, EXIT_PASSED
from dthc_tools.procs import die_with_parent
from tests.processes import stop

pytestmark = pytest.mark.slow

# What CI passes: the mock's plate is at 20 mm, so start 5 mm above it. The round-trip
# limit is relaxed for shared CI machines: these tests prove the suite, not the scheduler.
MOCK_ARGS = ("--yes", "--start-z-mm", "25", "--feed-mm-s", "50", "--rtt-limit-ms", "100")
SUITE_TIMEOUT_S = 45.0


@dataclass(frozen=True)
class SuiteRun:
    returncode: int
    stdout: str
    stderr: str
    seconds: float

    @property
    def report(self) -> dict[str, Any]:
        report: dict[str, Any] = json.loads(self.stdout)
        return report

    def checks(self) -> dict[str, dict[str, Any]]:
        return {c["name"]: c for c in self.report["checks"]}

    def failed(self) -> set[str]:
        return {name for name, c in self.checks().items() if c["passed"] is False}


@contextmanager
def mock_board(tmp: Path, variant: str = "good") -> Iterator[tuple[Path, int]]:
    """The mock board process on a pty at ``tmp/dthc0``; yields (pty path, pid)."""
    pty = tmp / "dthc0"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mock_device", "--pty", str(pty), "--seed", "5",
         "--firmware-variant", variant],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        preexec_fn=die_with_parent(),
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("READY")
        yield pty, proc.pid
    finally:
        stop(proc)


def run_conformance(*args: str) -> SuiteRun:
    """``python -m dthc_bridge.conformance ARGS`` with stdin not a terminal."""
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "dthc_bridge.conformance", *args],
        stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=SUITE_TIMEOUT_S,
        check=False, preexec_fn=die_with_parent(),
    )  # fmt: skip
    return SuiteRun(done.returncode, done.stdout, done.stderr, time.monotonic() - t0)


def run_against_variant(tmp: Path, variant: str, *extra: str) -> SuiteRun:
    with mock_board(tmp, variant) as (pty, pid):
        return run_conformance(str(pty), *MOCK_ARGS, "--reset-signal-pid", str(pid), *extra)


@pytest.fixture(scope="module")
def good_run(tmp_path_factory: pytest.TempPathFactory) -> SuiteRun:
    """One JSON run of the whole suite against the good firmware, shared by the tests."""
    return run_against_variant(tmp_path_factory.mktemp("good"), "good", "--json", "--home")


def test_good_firmware_passes_every_check(good_run: SuiteRun) -> None:
    """Against the good mock board every check runs (reset by signal) and passes: exit 0."""
    assert good_run.returncode == EXIT_PASSED, good_run.stdout + good_run.stderr
    checks = good_run.checks()
    assert list(checks) == list(CHECK_NAMES)
    assert {name: c["passed"] for name, c in checks.items()} == dict.fromkeys(CHECK_NAMES, True)
    assert good_run.report["passed"] is True
    # The lease fault comes within lease + one sample period, measured on the board clock.
    lease = checks["lease_expiry"]["values"]
    assert lease["fault_after_ms"] <= lease["lease_ms"] + lease["sample_period_us"] / 1000
    assert lease["detail"] == 0  # ohmic sensing on: latched
    lapse = checks["lease_idle_lapse"]["values"]
    assert lapse["lapse_after_ms"] <= lapse["lease_ms"] + lapse["sample_period_us"] / 1000
    assert (lapse["detail"], lapse["faults"], lapse["reports"]) == (1, "0x0000", 1)
    assert checks["probe_contact"]["values"]["contact_z_mm"] == pytest.approx(20.0, abs=0.05)
    assert good_run.seconds < 15.0


def test_json_report_has_one_entry_per_check_with_name_passed_figure(good_run: SuiteRun) -> None:
    """``--json`` prints exactly one object whose ``checks`` are {name, passed, figure, ...}."""
    assert good_run.stdout.count("\n") == 1  # one line: one JSON object, nothing else
    report = good_run.report
    assert set(report) >= {"link", "passed", "board", "summary", "checks"}
    assert report["summary"] == {"passed": len(CHECK_NAMES), "failed": 0, "skipped": 0}
    for check in report["checks"]:
        assert {"name", "passed", "figure", "values"} <= set(check)
        assert isinstance(check["name"], str)
        assert check["passed"] in (True, False, None)
        assert isinstance(check["figure"], str)
        assert check["figure"]
    assert report["board"]["serial"] == "MOCK-0001"


def test_lease_ignored_firmware_fails_the_lease_check(tmp_path: Path) -> None:
    """A firmware that never notices the host went silent fails lease_expiry and
    lease_idle_lapse (and only those), in the readable report, with exit status 1."""
    run = run_against_variant(tmp_path, "lease-ignored")
    assert run.returncode == EXIT_FAILED, run.stdout + run.stderr
    fail_lines = [line for line in run.stdout.splitlines() if line.lstrip().startswith("FAIL")]
    assert len(fail_lines) == 2, run.stdout
    assert "lease_expiry" in fail_lines[0]
    assert "no LEASE_EXPIRED fault" in fail_lines[0]
    assert "ohmic sense still on" in fail_lines[0]
    assert "lease_idle_lapse" in fail_lines[1]
    assert "no FAULT LEASE_EXPIRED within" in fail_lines[1]
    # the homing cycle not asked (no --home): skipped
    assert f"result: FAIL ({len(CHECK_NAMES) - 3} passed, 2 failed, 1 skipped)" in run.stdout


@pytest.mark.parametrize(
    ("variant", "why"),
    [
        ("idle-lapse-latched", "the lease latched LEASE_EXPIRED at rest (detail 0"),
        ("idle-lapse-unreported", "no FAULT LEASE_EXPIRED within"),
    ],
)
def test_idle_lapse_variants_fail_the_idle_lapse_check(
    tmp_path: Path, variant: str, why: str
) -> None:
    """A firmware that still latches the lease at rest (an idle table to re-arm), and one
    that latches nothing and says nothing, each fail lease_idle_lapse (and only that)."""
    run = run_against_variant(tmp_path, variant, "--json")
    assert run.returncode == EXIT_FAILED, run.stdout + run.stderr
    assert run.failed() == {"lease_idle_lapse"}
    assert why in run.checks()["lease_idle_lapse"]["figure"]


def test_duplicates_twice_firmware_fails_the_duplicate_check(tmp_path: Path) -> None:
    """A firmware that executes retransmissions again fails duplicate_seq: the resent
    OHMIC_SENSE on switched ohmic sensing back on."""
    run = run_against_variant(tmp_path, "duplicates-twice", "--json")
    assert run.returncode == EXIT_FAILED, run.stdout + run.stderr
    assert run.failed() == {"duplicate_seq"}
    check = run.checks()["duplicate_seq"]
    assert check["values"]["ohmic_sense_after"] is True
    assert "executed again" in check["figure"]


def test_wrong_crc_firmware_fails_the_handshake_and_ends_quickly(tmp_path: Path) -> None:
    """A firmware framing with the wrong CRC fails the handshake with the CRC error count;
    every other check is reported skipped at once (no hang, no per-check timeouts)."""
    run = run_against_variant(tmp_path, "wrong-crc", "--json")
    assert run.returncode == EXIT_FAILED, run.stdout + run.stderr
    checks = run.checks()
    assert list(checks) == list(CHECK_NAMES)
    handshake = checks["handshake"]
    assert handshake["passed"] is False
    assert "0 valid frames" in handshake["figure"]
    assert handshake["values"]["crc_errors"] > 0
    assert "CCITT-FALSE" in handshake["hint"]
    assert all(c["passed"] is None for name, c in checks.items() if name != "handshake")
    assert run.seconds < 5.0


def test_refuses_to_run_without_yes_when_stdin_is_not_a_terminal(tmp_path: Path) -> None:
    """With no terminal to confirm the motion window and no --yes, the command refuses
    (exit 2) before opening the link, and says how to confirm."""
    pty = tmp_path / "no-such-board"
    run = run_conformance(str(pty), "--json")
    assert run.returncode == 2
    assert run.stdout == ""
    assert "--yes" in run.stderr
    assert "±10 mm" in run.stderr
