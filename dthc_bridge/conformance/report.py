"""Check results and the suite report: a readable table, or one JSON object.

A check either passed (``passed`` True), failed (False) or was skipped (None: it could not
run here, e.g. no way to reset the board, or an earlier failure made it meaningless). The
exit status is non-zero only when a check failed; skipped checks do not fail a run.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TextIO

__all__ = ["CheckResult", "SuiteReport", "Value", "failed", "passed", "skipped"]

Value = float | int | str | bool | None


@dataclass(frozen=True, slots=True)
class CheckResult:
    """The outcome of one check, with its measured figures.

    ``figure`` is the one-line human summary; ``values`` the same figures as numbers (units
    in the keys), for scripts; ``hint`` what to do about a failure or a skip.
    """

    name: str
    passed: bool | None
    figure: str
    values: Mapping[str, Value] = field(default_factory=dict)
    hint: str = ""
    seconds: float = 0.0

    @property
    def status(self) -> str:
        return {True: "PASS", False: "FAIL", None: "SKIP"}[self.passed]

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {
            "name": self.name,
            "passed": self.passed,
            "figure": self.figure,
            "values": dict(self.values),
            "seconds": round(self.seconds, 3),
        }
        if self.hint:
            out["hint"] = self.hint
        return out


def passed(name: str, figure: str, *, values: Mapping[str, Value] | None = None) -> CheckResult:
    return CheckResult(name, True, figure, dict(values or {}))


def failed(
    name: str, figure: str, *, hint: str = "", values: Mapping[str, Value] | None = None
) -> CheckResult:
    return CheckResult(name, False, figure, dict(values or {}), hint)


def skipped(
    name: str, figure: str, *, hint: str = "", values: Mapping[str, Value] | None = None
) -> CheckResult:
    return CheckResult(name, None, figure, dict(values or {}), hint)


@dataclass(slots=True)
class SuiteReport:
    link: str
    board: dict[str, Value] = field(default_factory=dict)
    checks: list[CheckResult] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def failures(self) -> list[CheckResult]:
        return [c for c in self.checks if c.passed is False]

    @property
    def passed(self) -> bool:
        return not self.failures

    @property
    def exit_status(self) -> int:
        return 0 if self.passed else 1

    def as_dict(self) -> dict[str, object]:
        return {
            "link": self.link,
            "passed": self.passed,
            "board": dict(self.board),
            "summary": {
                "passed": sum(c.passed is True for c in self.checks),
                "failed": len(self.failures),
                "skipped": sum(c.passed is None for c in self.checks),
            },
            "seconds": round(self.seconds, 3),
            "checks": [c.as_dict() for c in self.checks],
        }

    def write_json(self, out: TextIO) -> None:
        out.write(json.dumps(self.as_dict()) + "\n")

    # --- the readable report ----------------------------------------------------------------

    def header_line(self) -> str:
        return f"dthc-bridge conformance {self.link}"

    def board_line(self) -> str:
        b = self.board
        if not b:
            return "  board: no handshake"
        return (
            f"  board: {b.get('serial')!s} firmware {b.get('firmware')!s} "
            f"protocol {b.get('protocol')!s} boot id {b.get('boot_id')!s}"
        )

    @staticmethod
    def check_lines(check: CheckResult) -> list[str]:
        lines = [f"  {check.status}  {check.name:<18} {check.figure}"]
        if check.hint and check.passed is not True:
            lines.append(f"        {'':<18} hint: {check.hint}")
        return lines

    def summary_line(self) -> str:
        d = self.as_dict()["summary"]
        assert isinstance(d, dict)
        verdict = "PASS" if self.passed else "FAIL"
        return (
            f"result: {verdict} ({d['passed']} passed, {d['failed']} failed, "
            f"{d['skipped']} skipped) in {self.seconds:.1f} s"
        )

    def write_text(self, out: TextIO) -> None:
        lines = [self.header_line(), self.board_line()]
        for check in self.checks:
            lines.extend(self.check_lines(check))
        lines.append(self.summary_line())
        out.write("\n".join(lines) + "\n")
