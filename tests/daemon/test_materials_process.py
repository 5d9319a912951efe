"""The material library round trip through the daemon process: load the file, change it
over MQTT, kill the daemon, start it again: same file, same retained ``materials`` topic."""

from __future__ import annotations

import json
import signal
import uuid
from pathlib import Path
from typing import Any

import pytest

from dthc_bridge.materials import MaterialStore
from tests.mqtt.conftest import Broker
from tests.mqtt.helpers import Probe, open_probe, unique_base

from .conftest import STARTUP_S, Daemon, MockBoard, daemon_config

pytestmark = pytest.mark.slow

SHOP = Path(__file__).parents[1] / "programs" / "shop_material.cfg"

ALUMINIUM: dict[str, Any] = {
    "name": "Aluminium 3mm 45A",
    "kerf_width": 1.6,
    "thc": True,
    "pierce_height": 3.2,
    "pierce_delay": 0.2,
    "puddle_jump_height": 150.0,
    "puddle_jump_delay": 0.1,
    "cut_height": 1.5,
    "cut_speed": 3600.0,
    "cut_amps": 45.0,
    "cut_volts": 119.0,
    "pause_at_end": 0.3,
    "gas_pressure": 5.5,
    "cut_mode": 1,
}


async def request(probe: Probe, topic: str, name: str, args: dict[str, Any]) -> dict[str, Any]:
    transaction = f"mat-{uuid.uuid4().hex[:8]}"
    start = len(probe.messages)
    await probe.publish_json(f"{topic}/request/{name}", {**args, "transaction": transaction})
    return await probe.wait_json(
        f"{topic}/response/{name}", lambda d: d.get("transaction") == transaction, 10.0, start
    )


async def online(probe: Probe, topic: str) -> None:
    """This daemon is up: the will of a killed one said offline, so online is new."""
    await probe.wait_json(f"{topic}/availability", lambda d: d.get("state") == "online",
                          STARTUP_S)  # fmt: skip


async def retained_materials(
    probe: Probe, topic: str, numbers: list[int], speed_of_3: float | None = None
) -> dict[str, Any]:
    """The first ``materials`` document listing ``numbers`` (and material 3 at that speed:
    the documents published between two changes list the same numbers)."""

    def listed(doc: dict[str, Any]) -> bool:
        materials = doc.get("materials", [])
        if [m["number"] for m in materials] != numbers:
            return False
        return speed_of_3 is None or any(
            m["number"] == 3 and m["cut_speed"] == speed_of_3 for m in materials
        )

    return await probe.wait_json(f"{topic}/materials", listed, STARTUP_S)


async def test_material_file_round_trips_through_mqtt_and_a_daemon_crash(
    tmp_path: Path, own_broker: Broker, mock_board: MockBoard
) -> None:
    library = tmp_path / "shop_material.cfg"
    library.write_bytes(SHOP.read_bytes())
    base = unique_base()
    topic = f"{base}/t1"
    config = daemon_config(mock_board.pty, own_broker, base) + (
        f'\n[controller]\nmaterials_file = "{library}"\n'
    )

    daemon = Daemon(tmp_path, config)
    try:
        async with open_probe(own_broker, f"{topic}/#") as probe:
            await online(probe, topic)
            await retained_materials(probe, topic, [0, 3])  # loaded from the file
            reply = await request(probe, topic, "material_set", {"number": 8, **ALUMINIUM})
            assert reply["status"] == "ok", reply
            changed = {**ALUMINIUM, "name": "Mild steel 1.5mm (slower)", "cut_speed": 2600.0}
            reply = await request(probe, topic, "material_set", {"number": 3, **changed})
            assert reply["status"] == "ok", reply
            bad = await request(probe, topic, "material_set", {"number": 9, "name": "x"})
            assert bad["status"] == "error"
            assert "pierce_height" in bad["error"]
            published = await retained_materials(probe, topic, [0, 3, 8], 2600.0)
        written = library.read_bytes()
        daemon.signal(signal.SIGKILL)  # a crash: nothing more is written
        assert daemon.wait(5) == -signal.SIGKILL
    finally:
        daemon.close()

    assert library.read_bytes() == written
    on_disk = MaterialStore(library).load()
    assert sorted(on_disk) == [3, 8]
    assert on_disk[3].cut_speed == 2600.0
    assert on_disk[8].name == "Aluminium 3mm 45A"

    async with open_probe(own_broker) as cleaner:  # what follows is the new daemon's
        await cleaner.client.publish(f"{topic}/materials", b"", qos=1, retain=True)
    restarted = Daemon(tmp_path, config)
    try:
        async with open_probe(own_broker, f"{topic}/#") as probe:
            await online(probe, topic)
            again = await retained_materials(probe, topic, [0, 3, 8], 2600.0)
            assert again["materials"] == published["materials"]
            got = await request(probe, topic, "material_get", {"number": 8})
            assert got["status"] == "ok", got
            assert {k: got["data"][k] for k in ALUMINIUM} == ALUMINIUM
            # The restarted daemon reads what it wrote; its start does not rewrite it.
            assert library.read_bytes() == written
            json.loads(json.dumps(got))  # one plain JSON answer
    finally:
        restarted.close()
