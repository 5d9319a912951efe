"""The request table (dthc_bridge/requests.py) is the one list of requests: the gateway
decodes by it, the service serves by it, the broker's ACL and the fuzz bench read it."""

from __future__ import annotations

import asyncio
from collections.abc import Mapping

import pytest

from dthc_bridge.controller.commands import Command
from dthc_bridge.controller.dialect import Dialect
from dthc_bridge.mqtt.payloads import decode_request
from dthc_bridge.mqtt.roles import PANEL_REQUESTS
from dthc_bridge.mqtt.roles import REQUESTS as ACL_REQUESTS
from dthc_bridge.port import CommandResult
from dthc_bridge.requests import REQUESTS, GcodeRequest, Request, serve_request
from dthc_tools.bench.fuzz import PayloadFuzzer


class RecordingHandlers:
    """Each handler answers ok with its own name, so a test sees where a request went."""

    def __init__(self) -> None:
        self.calls: list[str] = []

    def _done(self, what: str) -> CommandResult:
        self.calls.append(what)
        return CommandResult(True, {"by": what})

    async def execute_gcode(
        self,
        line: str,
        *,
        line_number: int | None,
        xy_mm: tuple[float, float] | None,
        dialect: Dialect | None = None,
    ) -> CommandResult:
        return self._done("execute_gcode")

    async def execute_command(self, command: Command) -> CommandResult:
        return self._done(f"execute_command {type(command).__name__}")

    def snapshot(self) -> dict[str, object]:
        self.calls.append("snapshot")
        return {}

    def material_request(self, name: str, args: Mapping[str, object]) -> CommandResult:
        return self._done(f"material_request {name}")

    def host_motion(
        self, speed_mm_s: float, feed_mm_min: float | None, state: str | None
    ) -> CommandResult:
        return self._done("host_motion")

    async def reset_consumables(self) -> CommandResult:
        return self._done("reset_consumables")

    def start_program(self) -> CommandResult:
        return self._done("start_program")

    def end_program(self) -> CommandResult:
        return self._done("end_program")


VALID_ARGS: dict[str, dict[str, object]] = {
    "gcode": {"line": "M3"},
    "thc": {"on": True},
    "thc_hold": {"on": True},
    "height_override": {"mm": 0.1},
    "jog_z": {"mm": 1.0},
    "operating_mode": {"mode": 1},
    "velocity_reduction": {"percent": 50},
    "material_select": {"number": 1},
    "motion": {"xy_speed_mm_s": 10.0},
}


@pytest.mark.parametrize("name", sorted(REQUESTS))
def test_every_request_of_the_table_reaches_a_handler(name: str) -> None:
    """A valid request of each name is served by exactly one handler, never 'unknown'."""
    handlers = RecordingHandlers()
    result = asyncio.run(serve_request(handlers, name, VALID_ARGS.get(name, {})))
    assert result.ok, result.error
    assert len(handlers.calls) == 1


def test_an_unknown_request_is_refused_with_the_same_words() -> None:
    """Unchanged from before the table: ``<name>: unknown request``."""
    result = asyncio.run(serve_request(RecordingHandlers(), "fire", {}))
    assert (result.ok, result.error) == (False, "fire: unknown request")


def test_the_gateway_decodes_each_request_with_its_table_model() -> None:
    """gcode's payload is a GcodeRequest (a bare string is its line); every other name,
    and an unknown one, is a Request whose extra keys are the arguments."""
    for name, spec in REQUESTS.items():
        payload = b'{"line": "M5"}' if spec.payload is GcodeRequest else b"{}"
        assert type(decode_request(name, payload, max_payload_bytes=4096)) is spec.payload
    assert isinstance(decode_request("gcode", b'"M5"', max_payload_bytes=4096), GcodeRequest)
    assert type(decode_request("echo", b"{}", max_payload_bytes=4096)) is Request


def test_the_acl_and_the_fuzz_bench_read_the_same_table() -> None:
    """Who may send what (the broker's ACL) and the names the fuzz bench sends are the
    table's: a request added to it is covered by both."""
    assert {name: spec.sender_only for name, spec in REQUESTS.items()} == ACL_REQUESTS
    assert {name for name, spec in REQUESTS.items() if not spec.sender_only} == PANEL_REQUESTS
    assert set(PayloadFuzzer.NAMES) == set(REQUESTS)
