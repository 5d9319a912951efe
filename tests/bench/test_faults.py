"""``bench faults``: what a cell measures, without processes (the matrix itself runs in
``make bench``; a short cell runs here)."""

from __future__ import annotations

import argparse
from typing import Any

import pytest

from dthc_tools.bench import faults


def ev(topic: str, state: str, at: float) -> dict[str, Any]:
    return {"topic": topic, "state": state, "received_s": at}


def test_recovery_counts_from_the_faults_end_until_daemon_and_board_are_both_back() -> None:
    events = [
        ev("board", "online", 1.0),  # before the fault: ignored
        ev("availability", "offline", 10.2),
        ev("board", "offline", 10.3),
        ev("availability", "online", 12.5),
        ev("board", "connecting", 12.6),
        ev("board", "online", 12.9),
    ]
    assert faults.recovery_s(events, struck_at=10.0, fault_end=12.0) == 0.9
    assert faults.recovery_s(events[:1], struck_at=10.0, fault_end=12.0) == 0.0  # never down
    assert faults.recovery_s(events[:5], struck_at=10.0, fault_end=12.0) is None  # not back


def seq(state: str, previous: str) -> dict[str, Any]:
    return {"topic": "event", "type": "sequence", "state": state, "previous": previous}


def test_a_cut_that_goes_on_after_a_fault_without_a_rearm_is_a_silent_resume() -> None:
    cut = [seq("arc_wait", "torch_on"), seq("cutting", "pierce_delay")]
    fault = [seq("faulted", "cutting")]
    rearm = [seq("idle", "faulted")]
    assert faults.silent_resumes(cut + fault + rearm + cut) == 0
    assert faults.silent_resumes(cut + fault + cut) == 1
    assert faults.silent_resumes(cut + cut) == 0


def cell(**changes: Any) -> dict[str, Any]:
    base = {"unsafe_torch_ms": 0.0, "requests_lost": 0, "requests_duplicated": 0,
            "recovery_s": 0.4, "outcome": "completed", "violations": {}}  # fmt: skip
    return {**base, **changes}


def test_a_cell_holds_only_when_every_promise_does() -> None:
    assert faults.cell_holds(cell())
    assert faults.cell_holds(cell(outcome="stopped: paused: board fault: LEASE_EXPIRED"))
    for broken in ({"unsafe_torch_ms": 3.0}, {"requests_lost": 1}, {"requests_duplicated": 1},
                   {"recovery_s": 2.5}, {"recovery_s": None}, {"outcome": "stopped: "},
                   {"silent_resumes": 1},
                   {"violations": {"torch_on_after_lease_expiry": 1}}):  # fmt: skip
        assert not faults.cell_holds(cell(**broken)), broken


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_two_cells_mid_cut_hold() -> None:
    """Mid-cut: the daemon stopped 0.5 s (the board's 250 ms lease turns the torch off by
    itself; the program stops naming the fault and the cut to restart from), the sender
    killed (its will ends the cut). A broker restart mid-cut is tests/e2e's and
    tests/mqtt's (the will a broker sends as it shuts down)."""
    parser = argparse.ArgumentParser()
    faults.add_arguments(parser)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args([
        "--faults", "daemon_stop_0.5s,sender_kill", "--phases", "cutting",
        "--json",
    ])  # fmt: skip
    result = faults.run(args)
    assert result["cells_failed"] == 0, result["matrix"]
    assert result["unsafe_torch_ms"] == 0.0
    matrix = result["matrix"]
    assert isinstance(matrix, list)
    stopped, killed = matrix
    assert "LEASE_EXPIRED" in stopped["outcome"]
    assert stopped["restart_line"] == 5
    assert any("sender lost" in reason for reason in killed["daemon_faults"]), killed
