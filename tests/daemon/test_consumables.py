"""Consumable life: the pierce count and the arc-on time, counted from the board's batches
and kept across restarts in a crash-safe file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dthc_bridge.consumables import ConsumableLog, default_consumables_file
from tests.controller.test_sequence import SQUARE, ready
from tests.daemon.test_material_requests import service_for


def test_a_cut_counts_one_pierce_and_its_burn_time() -> None:
    loop = ready()
    started, ok, ended = loop.cut(*SQUARE)
    assert started.ok
    assert ok
    assert ended.ok
    counters = loop.service.consumables.counters
    assert counters.pierces == 1
    burn = loop.plant.truth.summary().cuts[0].duration_s
    assert counters.arc_on_s == pytest.approx(burn, abs=0.3)
    assert loop.service.snapshot()["consumables"] == counters.as_dict()


def test_the_counters_survive_a_restart_and_a_reset_starts_them_again(tmp_path: Path) -> None:
    path = tmp_path / "state" / "consumables.json"
    first = ConsumableLog(path)
    first.pierced()
    first.burned(12.5)
    first.save()
    again = ConsumableLog(path)
    assert (again.counters.pierces, again.counters.arc_on_s) == (1, 12.5)
    assert again.counters.since == first.counters.since
    again.reset()
    assert json.loads(path.read_text())["pierces"] == 0
    assert ConsumableLog(path).counters.pierces == 0


def test_an_unreadable_file_starts_from_zero_instead_of_stopping_the_daemon(
    tmp_path: Path,
) -> None:
    path = tmp_path / "consumables.json"
    path.write_text("{not json")
    assert ConsumableLog(path).counters.pierces == 0


def test_the_file_lives_in_the_services_state_directory_under_systemd(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("STATE_DIRECTORY", "/var/lib/dthc-bridge")
    assert default_consumables_file() == Path("/var/lib/dthc-bridge/consumables.json")
    monkeypatch.delenv("STATE_DIRECTORY")
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    assert default_consumables_file() == tmp_path / "dthc-bridge" / "consumables.json"


async def test_consumables_reset_answers_with_the_fresh_counters() -> None:
    service = await service_for(None)
    service.consumables.pierced()
    result = await service.execute_request("consumables_reset", {})
    assert result.ok
    assert result.data["consumables"]["pierces"] == 0  # type: ignore[index]
    bad = await service.execute_request("consumables_reset", {"all": True})
    assert bad.error == "consumables_reset all: unknown argument"
