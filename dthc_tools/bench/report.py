"""What every suite's report carries: the machine, the command, the goals; and its printing."""

from __future__ import annotations

import json
import math
import os
import platform
import shlex
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "Goal",
    "goals_block",
    "machine_info",
    "percentiles",
    "print_report",
    "report_header",
]


def machine_info() -> dict[str, object]:
    """CPU model (from /proc/cpuinfo), cores, architecture and kernel of this machine."""
    cpu = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "nproc": os.cpu_count(),
        "arch": platform.machine(),
        "system": f"{platform.system()} {platform.release()}",
    }


def report_header(
    suite: str, argv: Sequence[str], prog: str = "dthc-bridge bench"
) -> dict[str, object]:
    return {
        "suite": suite,
        "command": f"{prog} {shlex.join(argv)}",
        "python": platform.python_version(),
        "implementation": sys.implementation.name,
        "machine": machine_info(),
    }


@dataclass(frozen=True)
class Goal:
    """A figure against its target: ``value <= target`` (``at_most``) or ``>=``."""

    name: str
    value: float | None
    target: float
    at_most: bool
    unit: str = ""

    @property
    def ok(self) -> bool:
        if self.value is None or math.isnan(self.value):
            return False
        return self.value <= self.target if self.at_most else self.value >= self.target

    def as_dict(self) -> dict[str, object]:
        return {
            "value": self.value,
            "target": f"{'<=' if self.at_most else '>='} {self.target:g}{self.unit}",
            "pass": self.ok,
        }


def goals_block(goals: Sequence[Goal]) -> dict[str, object]:
    return {g.name: g.as_dict() for g in goals}


def percentiles(values: Sequence[float], scale: float = 1.0, digits: int = 1) -> dict[str, object]:
    """p50/p99/max (nearest rank) and count of ``values`` times ``scale``."""
    if not values:
        return {"n": 0, "p50": None, "p99": None, "max": None}
    ordered = sorted(values)
    n = len(ordered)

    def rank(q: float) -> float:
        return ordered[min(n - 1, max(0, math.ceil(q * n) - 1))] * scale

    return {
        "n": n,
        "p50": round(rank(0.50), digits),
        "p99": round(rank(0.99), digits),
        "max": round(ordered[-1] * scale, digits),
    }


def _flatten(prefix: str, value: object, out: list[tuple[str, str]]) -> None:
    if isinstance(value, Mapping):
        for key, item in value.items():
            _flatten(f"{prefix}.{key}" if prefix else str(key), item, out)
    elif isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value):
        for i, item in enumerate(value):
            _flatten(f"{prefix}[{i}]", item, out)
    else:
        out.append((prefix, json.dumps(value) if not isinstance(value, str) else value))


def print_report(report: Mapping[str, object], as_json: bool) -> None:
    """One JSON object on one line, or ``key: value`` lines for a person."""
    if as_json:
        print(json.dumps(report, allow_nan=False))
        return
    rows: list[tuple[str, str]] = []
    _flatten("", report, rows)
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")


def proc_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` (None when it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text(encoding="ascii").rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
