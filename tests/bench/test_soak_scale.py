"""The soak and scale suites: short runs through the whole stack."""

from __future__ import annotations

import argparse

import pytest

from dthc_tools.bench import scale, soak

pytestmark = pytest.mark.slow


def _args(module: object, *argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)  # type: ignore[attr-defined]
    return parser.parse_args(list(argv))


@pytest.mark.timeout(240)  # 21 s of faults, then the last program run finishes
def test_soak_loses_no_command_and_never_leaves_the_torch_on() -> None:
    """20 s under bit errors, drops, an unplug, a reboot and a broker restart."""
    result = soak.run(_args(soak, "--minutes", "0.35"))
    assert result["commands_lost"] == 0
    assert result["unsafe_torch_ms"] == 0.0
    assert result["violations"] == {}
    assert isinstance(result["commands_sent"], int)
    assert result["commands_sent"] > 5
    assert isinstance(result["recoveries"], int)
    assert result["recoveries"] >= 1  # the unplug, at least, was recovered from


@pytest.mark.timeout(180)
def test_scale_runs_two_tables_on_one_broker() -> None:
    """Two daemons and two mock boards on one broker both complete their program."""
    result = scale.run(_args(scale, "--tables", "2"))
    assert result["programs_completed"] == 2
    assert result["safety_violations"] == 0
    assert isinstance(result["broker_messages_per_s"], float)
    assert result["broker_messages_per_s"] > 10
    goals = result["goals"]
    assert isinstance(goals, dict)
    assert "cpu_percent_per_table_max" in goals
