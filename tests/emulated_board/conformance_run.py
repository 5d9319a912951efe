"""``dthc-bridge conformance`` against an emulated board, as a table owner runs it."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Sequence
from typing import Any

from dthc_tools.emulated_board import EmulatedBoard

__all__ = ["run_conformance"]


def run_conformance(
    board: EmulatedBoard, only: Sequence[str] = (), *, home: bool = False
) -> dict[str, Any]:
    """Every check (or ``only`` these, with what they are measured with), SIGUSR2 for the
    reset check, the plate 5 mm below the start; fails naming every failed check with its
    figures. The JSON report."""
    extra = (["--only", ",".join(only)] if only else []) + (["--home"] if home else [])
    done = subprocess.run(
        [sys.executable, "-m", "dthc_bridge.conformance", str(board.pty), "--yes",
         "--start-z-mm", "25", "--reset-signal-pid", str(board.pid), "--json", *extra],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    report: dict[str, Any] = json.loads(done.stdout)
    # The homing cycle runs when asked (``home``) of a board that homes: the Nano's build
    # has no home switch input, and its cycle is skipped by design.
    homes = home and "HOMING" in str(report["board"]["capabilities"])
    failed = [
        f"{c['name']}: {c['figure']}"
        for c in report["checks"]
        if not c["passed"]
        and (not only or c["name"] in only)
        and not (c["name"] == "z_home_cycle" and c["passed"] is None and not homes)
    ]
    assert not failed, failed
    if not only:
        assert done.returncode == 0
    return report
