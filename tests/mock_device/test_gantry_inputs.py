"""The gantry control port's ``input`` op: a board input held by hand, seen by the board
at its pin exactly as a real switch (mock_device/gantry_server.py)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from typing import Any

import pytest

import firmware_protocol as fp
from firmware_protocol import FaultCode, InputBit, InputMask, NakCode
from mock_device.gantry_server import INPUT_NAMES, GantryServer
from mock_device.sim import SimulatedBoard
from mock_device.sim_host import SimHost


class Port:
    """A client of the control port, and the board behind it driven in simulated time."""

    def __init__(self, host: SimHost, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.host = host
        self.reader = reader
        self.writer = writer

    async def ask(self, request: dict[str, Any]) -> dict[str, Any]:
        self.writer.write(json.dumps(request).encode() + b"\n")
        await self.writer.drain()
        reply: dict[str, Any] = json.loads(await self.reader.readline())
        return reply

    def status(self) -> fp.Status:
        status = self.host.request(fp.Query(0, fp.QueryWhat.STATUS))
        assert isinstance(status, fp.Status)
        return status


@pytest.fixture
async def port() -> AsyncIterator[Port]:
    host = SimHost(SimulatedBoard("flat_clean", seed=3))
    host.open_session(lease_ms=2000)
    server = GantryServer(host.board.plant, "127.0.0.1", 0)
    await server.start()
    reader, writer = await asyncio.open_connection("127.0.0.1", server.bound_port)
    try:
        yield Port(host, reader, writer)
    finally:
        writer.close()
        await server.close()


def test_the_names_are_the_protocols_inputs() -> None:
    """Every input of PROTOCOL.md §7 by its lower-case name, with its bit."""
    assert {bit.name.lower(): 1 << bit for bit in InputBit} == INPUT_NAMES
    assert set(INPUT_NAMES) == {
        "arc_ok", "ohmic", "float", "breakaway", "thc_up", "thc_down", "estop",
        "z_limit_min", "z_limit_max",
    }  # fmt: skip


async def test_a_forced_estop_is_an_edge_a_latch_and_a_refused_reset_until_released(
    port: Port,
) -> None:
    """E-stop held on: an EVENT edge, FAULT ESTOP latched, the bit in SAMPLES and STATUS,
    TORCH refused, FAULT_RESET refused while held; released: the falling edge, the reset
    accepted."""
    host = port.host
    mark = len(host.received)
    assert await port.ask({"op": "input", "name": "estop", "on": True}) == {"ok": True}
    host.pump(10)
    new = host.received[mark:]
    rises = [m for m in new if isinstance(m, fp.Event) and m.input == InputBit.ESTOP]
    assert [(e.level, bool(e.inputs & InputMask.ESTOP)) for e in rises] == [(1, True)]
    assert [f.code for f in new if isinstance(f, fp.Fault)] == [FaultCode.ESTOP]
    assert all(b.inputs & InputMask.ESTOP for b in new if isinstance(b, fp.Samples))
    assert port.status().inputs & InputMask.ESTOP
    nak = host.request(fp.Torch(0, True))
    assert isinstance(nak, fp.Nak)
    assert (nak.code, nak.detail) == (NakCode.FAULT_LATCHED, FaultCode.ESTOP)
    nak = host.request(fp.FaultReset(0, 1 << FaultCode.ESTOP))
    assert isinstance(nak, fp.Nak)
    assert (nak.code, nak.detail) == (NakCode.FAULT_ACTIVE, FaultCode.ESTOP)
    mark = len(host.received)
    assert await port.ask({"op": "input", "name": "estop", "on": None}) == {"ok": True}
    host.pump(10)
    falls = [m for m in host.received[mark:] if isinstance(m, fp.Event)]
    assert [(e.input, e.level) for e in falls] == [(InputBit.ESTOP, 0)]
    assert isinstance(host.request(fp.FaultReset(0, 1 << FaultCode.ESTOP)), fp.Ack)
    assert port.status().faults == 0


async def test_a_forced_breakaway_latches_and_holds_its_reset_off(port: Port) -> None:
    """Breakaway held on latches BREAKAWAY; the plant's breakaway latch is clear, yet the
    reset is refused while the input is held, and accepted once it is handed back."""
    host = port.host
    assert (await port.ask({"op": "input", "name": "breakaway", "on": True}))["ok"]
    host.pump(5)
    assert port.status().faults == 1 << FaultCode.BREAKAWAY
    nak = host.request(fp.FaultReset(0, 1 << FaultCode.BREAKAWAY))
    assert isinstance(nak, fp.Nak)
    assert nak.code == NakCode.FAULT_ACTIVE
    assert (await port.ask({"op": "input", "name": "breakaway", "on": None}))["ok"]
    host.pump(5)
    assert isinstance(host.request(fp.FaultReset(0, 1 << FaultCode.BREAKAWAY)), fp.Ack)


@pytest.mark.parametrize("name", sorted(set(INPUT_NAMES) - {"estop", "breakaway"}))
async def test_each_input_held_on_then_off_then_handed_back(port: Port, name: str) -> None:
    """Held on, the bit is set in STATUS; held off, clear; handed back, it follows the
    plant again (at rest above the plate: nothing active). Ohmic contact needs sensing on,
    as a real board's does."""
    host = port.host
    bit = INPUT_NAMES[name]
    if name == "ohmic":
        assert await port.ask({"op": "input", "name": name, "on": True}) == {"ok": True}
        host.pump(5)
        assert not port.status().inputs & bit  # no ohmic circuit without sensing
        host.request(fp.OhmicSense(0, True))
    assert await port.ask({"op": "input", "name": name, "on": True}) == {"ok": True}
    host.pump(5)
    assert port.status().inputs & bit
    assert await port.ask({"op": "input", "name": name, "on": False}) == {"ok": True}
    host.pump(5)
    assert not port.status().inputs & bit
    assert await port.ask({"op": "input", "name": name, "on": None}) == {"ok": True}
    host.pump(5)
    assert port.status().inputs & bit == host.board.plant.inputs() & bit
    assert host.board.plant.forced_inputs == (0, 0)


async def test_a_forced_float_switch_stops_a_probe(port: Port) -> None:
    """A probe far above the plate ends CONTACT by FLOAT when the float switch is held on."""
    host = port.host
    ack = host.request(fp.ZProbe(0, 5_000, 30_000, InputMask.FLOAT))
    assert isinstance(ack, fp.Ack)
    host.pump(50)
    assert (await port.ask({"op": "input", "name": "float", "on": True}))["ok"]
    host.pump(100)
    (result,) = host.of_type(fp.ProbeResult)
    assert result.result == fp.ProbeOutcome.CONTACT
    assert result.sensor == InputMask.FLOAT


@pytest.mark.parametrize(
    ("request_", "error"),
    [
        ({"op": "input", "name": "e-stop", "on": True}, 'unknown name "e-stop"'),
        ({"op": "input", "name": 6, "on": True}, "unknown name 6"),
        ({"op": "input", "on": True}, "unknown name null"),
        ({"op": "input", "name": "estop", "on": 1}, "not 1"),
        ({"op": "input", "name": "estop", "on": "yes"}, 'not "yes"'),
        ({"op": "input", "name": "estop"}, "'on' is missing"),
    ],
)
async def test_a_bad_input_request_names_what_was_written_and_changes_nothing(
    port: Port, request_: dict[str, Any], error: str
) -> None:
    """An unknown name or an 'on' that is not true, false or null: ok false, an error
    naming what was written, no input held."""
    reply = await port.ask(request_)
    assert reply["ok"] is False
    assert error in reply["error"]
    assert port.host.board.plant.forced_inputs == (0, 0)
    port.host.pump(5)
    assert port.status().inputs == 0
