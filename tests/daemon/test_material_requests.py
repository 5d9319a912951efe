"""The daemon's material library over its request seam: list, get, set, delete.

Every request gets one answer; a bad one names what the user wrote and changes neither the
library nor its file (the file is the daemon's config state).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from dthc_bridge.board import BoardClient
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.controller.plasma import PlasmaController
from dthc_bridge.link import LinkSupervisor, LinkTiming
from dthc_bridge.materials import MaterialStore
from dthc_bridge.service import ControllerService
from mock_device.sim import SimulatedBoard
from tests.link.board_harness import RealtimeSimBoard

SHOP = Path(__file__).parents[1] / "programs" / "shop_material.cfg"

PLATE_6MM: dict[str, Any] = {
    "name": "Mild steel 6mm 65A",
    "thc": True,
    "pierce_height": 4.0,
    "pierce_delay": 0.8,
    "cut_height": 1.5,
    "cut_speed": 1900,
    "cut_amps": 65,
    "cut_volts": 128,
}


@pytest.fixture
def library(tmp_path: Path) -> Path:
    path = tmp_path / "machine_material.cfg"
    path.write_bytes(SHOP.read_bytes())
    return path


async def service_for(path: Path | None, **kwargs: Any) -> ControllerService:
    """A service whose board is never connected: material requests do not need it."""
    sim = RealtimeSimBoard(SimulatedBoard("flat_clean", seed=1))
    supervisor = LinkSupervisor("sim://board", LinkTiming(), opener=sim.opener)
    store = MaterialStore(path) if path is not None else None
    controller = PlasmaController(materials=store.load() if store else {})
    return ControllerService(
        controller, supervisor, BoardClient(supervisor), materials=store, **kwargs
    )


@pytest.fixture
async def service(library: Path) -> ControllerService:
    return await service_for(library)


def file_bytes(path: Path) -> bytes:
    """The file as it is on disk (a small read: fine inside a test's event loop)."""
    return path.read_bytes()


async def test_materials_lists_the_default_and_the_library(service: ControllerService) -> None:
    result = await service.execute_request("materials", {})
    assert result.ok
    numbers = [m["number"] for m in result.data["materials"]]  # type: ignore[attr-defined]
    assert numbers == [0, 3]
    assert result.data["selected"] == 0


async def test_material_get_answers_its_fields(service: ControllerService) -> None:
    result = await service.execute_request("material_get", {"number": 3})
    assert result.ok, result.error
    assert result.data["name"] == "Mild steel 1.5mm 45A"
    assert result.data["cut_speed"] == 3000.0


async def test_material_set_writes_the_file_and_a_program_can_select_it(
    service: ControllerService, library: Path
) -> None:
    result = await service.execute_request("material_set", {"number": 12, **PLATE_6MM})
    assert result.ok, result.error
    on_disk = MaterialStore(library).load()
    assert sorted(on_disk) == [3, 12]
    assert on_disk[12].name == "Mild steel 6mm 65A"
    assert on_disk[12].cut_speed == 1900.0
    selected = await service.execute_gcode("M190 P12", dialect=None)
    assert selected.ok, selected.error
    assert selected.data["cut_feed_mm_min"] == 1900.0
    assert service.sequence.params.pierce_height_mm == 4.0


async def test_material_set_replaces_and_delete_removes(
    service: ControllerService, library: Path
) -> None:
    changed = {**PLATE_6MM, "name": "thin", "cut_speed": 4200}
    assert (await service.execute_request("material_set", {"number": 3, **changed})).ok
    assert MaterialStore(library).load()[3].cut_speed == 4200.0
    assert (await service.execute_request("material_delete", {"number": 3})).ok
    assert MaterialStore(library).load() == {}
    gone = await service.execute_request("material_get", {"number": 3})
    assert not gone.ok
    assert "3" in (gone.error or "")


@pytest.mark.parametrize(
    ("name", "args", "says"),
    [
        ("material_set", {"number": 12, **PLATE_6MM, "pierce_height": None}, "pierce_height"),
        ("material_set", {"number": 12, "name": "x"}, "pierce_height: required, missing"),
        ("material_set", {"number": 12, **PLATE_6MM, "kerf": 1.2}, "kerf: unknown key"),
        ("material_set", {"number": 12, **PLATE_6MM, "cut_speed": -5}, "cut_speed"),
        ("material_set", {"number": "12", **PLATE_6MM}, "material_set number: '12'"),
        ("material_set", {"number": 0, **PLATE_6MM}, "0 is not a library material"),
        ("material_set", {"number": 1000000, **PLATE_6MM}, "not a library material"),
        ("material_delete", {"number": 99}, "99"),
        ("material_delete", {"number": 3, "name": "x"}, "material_delete name: unknown"),
        ("material_get", {"number": True}, "material_get number: True"),
    ],
)
async def test_a_bad_material_request_names_it_and_changes_nothing(
    service: ControllerService, library: Path, name: str, args: dict[str, Any], says: str
) -> None:
    before = file_bytes(library)
    listing = (await service.execute_request("materials", {})).data
    result = await service.execute_request(name, args)
    assert not result.ok
    assert says in (result.error or ""), result.error
    assert file_bytes(library) == before
    assert (await service.execute_request("materials", {})).data == listing


async def test_without_a_materials_file_edits_are_refused_but_reads_work() -> None:
    service = await service_for(None)
    assert (await service.execute_request("materials", {})).ok
    result = await service.execute_request("material_set", {"number": 5, **PLATE_6MM})
    assert not result.ok
    assert result.error == "material_set: no materials_file is configured"


async def test_program_start_tells_the_sender_the_shops_set_up(library: Path) -> None:
    """The material in force and its feed, the daemon's dialect and code table."""
    service = await service_for(library, dialect=Dialect.RELAY, codes={"H1": "M667", "M10": "M3"})
    assert (await service.execute_gcode("M190 P3", dialect=Dialect.PLASMAC)).ok
    result = await service.execute_request("program_start", {})
    assert result.ok, result.error
    data = dict(result.data)
    pins = data.pop("pins")  # what the program's #<_hal[...]> reads, in mm
    assert data == {
        "material": 3,
        "cut_feed_mm_min": 3000.0,
        "dialect": "relay",
        "codes": {"H1": "M667", "M10": "M3"},
    }
    assert isinstance(pins, dict)
    assert pins["plasmac.cut-feed-rate"] == 3000.0
    assert pins["plasmac.float-switch-travel"] == service.sequence.config.float_travel_mm
