"""CNCjs, a real grbl sender from the npm registry, drives the table through the grbl port
(issue 32): CNCjs's server and the port as their own processes, the port on a pty in front
of the emulated grbl, the daemon and the mock board beside it over mosquitto. CNCjs is
driven headless over its socket.io API, with the settings file the README gives.

- Programs in the forms posts write them (MASSO, PlasmaC, a grbl relay program that probes
  by itself), with their comments (CNCjs strips them): every cut burns, the torch is lit
  only inside cuts, nothing moves XY before a pierce.
- A line the daemon refuses: CNCjs's console shows why, then grbl's error.
- CNCjs's feed hold mid-cut puts the torch out; its cycle start relights where the torch
  stands and the program finishes.
- The daemon killed mid-cut: grbl is held, and CNCjs shows Hold.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import pytest

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.summary import summarize
from dthc_tools.grbl_port.process import start_port

from .cncjs import Cncjs, cncjs_server, missing

pytestmark = [
    pytest.mark.slow,
    pytest.mark.timeout(240),
    pytest.mark.skipif(missing() is not None, reason=str(missing())),
]

TELEMETRY_HZ = StackOptions(Path()).telemetry_hz
LIT = frozenset(
    {"torch_on", "arc_wait", "pierce_delay", "puddle_jump", "to_cut_height", "cutting"}
)  # fmt: skip

MASSO = """\
(MASSO post: plasma tool, G200 touch-off and pierce)
G21 G90
T112 M6 (plasma torch)
G200 F250 P3.8 D300 C1.5 V0 A90 O1 S0
G0 X10 Y10
M3
M667 F600 (THC on)
G1 X60 Y10 F3000
G1 X60 Y40
M666 (THC off)
M5
G0 X0 Y0
M30
"""

PLASMAC = """\
(PlasmaC as SheetCam writes it)
G21 G90
G0 X20 Y60
M3 $0 S1 (cut)
G1 X90 Y60 F2500
G1 X90 Y80
M5 $0
G0 X0 Y0
M2
"""

RELAY = """\
; a grbl relay program: it probes and runs its start sequence itself
G21 G90
G0 Z10
G0 X30 Y30
G38.2 Z-40 F300
G92 Z-1.5 (the float switch trips 1.5 mm after contact)
G0 Z3.8
M03 S1000
G4 P0.4
G1 Z1.5 F600
G1 X90 Y30 F2800
G1 X90 Y50
M05
G0 Z10
M30
"""

REFUSED = """\
(a scribe: this table has none)
G21 G90
G0 X10 Y10
M3 $1 S1
G1 X50 Y10
M5 $1
M2
"""

LONG_CUT = """\
G21 G90
G0 X10 Y20
M3 $0 S1
G1 X160 Y20 F1500
M5 $0
G0 X0 Y0
M2
"""


async def test_cncjs_cuts_masso_plasmac_and_relay_programs_and_shows_a_refusal(
    tmp_path: Path,
) -> None:
    port = tmp_path / "grbl-port"
    async with Stack(StackOptions(tmp_path, broker="mosquitto", motion="grbl")) as stack:
        with _Port(stack, port), cncjs_server(tmp_path, [port]) as (url, secret):
            cncjs = await asyncio.to_thread(_open, url, secret, port)
            try:
                cncjs.send("list")  # the ports CNCjs offers: the .cncrc entry among them
                await asyncio.to_thread(
                    cncjs.wait_for, lambda: cncjs.seen("serialport:list"), 10, "the port list"
                )  # fmt: skip
                assert cncjs.seen("serialport:list", lambda a: str(port) in json.dumps(a))
                for name, text in (("masso.nc", MASSO), ("plasmac.ngc", PLASMAC),
                                   ("relay.nc", RELAY)):  # fmt: skip
                    await asyncio.to_thread(_run, cncjs, port, name, text)
                console_before = len(cncjs.console())
                await asyncio.to_thread(_run, cncjs, port, "scribe.ngc", REFUSED, refused=True)
                shown = cncjs.console()[console_before:]
            finally:
                cncjs.close()
        result = await stack.finish()
    summary = summarize(result, TELEMETRY_HZ)
    assert any(line.startswith("[MSG:") and "$1" in line for line in shown), shown
    assert any(line.startswith("error:20") for line in shown), shown
    cuts = summary["cuts"]
    assert len(cuts) == 3, cuts  # MASSO, PlasmaC, relay; the scribe never lit
    assert all(cut["arc_on_s"] > 0 for cut in cuts), cuts
    assert summary["safety_violations"] == 0, summary["violations"]
    assert summary["torch_on_at_exit"] is False


async def test_cncjs_feed_hold_puts_the_torch_out_and_cycle_start_finishes_then_a_dead_daemon_holds_grbl(  # noqa: E501
    tmp_path: Path,
) -> None:
    port = tmp_path / "grbl-port"
    figures: dict[str, Any] = {}
    async with Stack(StackOptions(tmp_path, broker="mosquitto", motion="grbl")) as stack:
        with _Port(stack, port), cncjs_server(tmp_path, [port]) as (url, secret):
            cncjs = await asyncio.to_thread(_open, url, secret, port)
            try:
                await asyncio.to_thread(_load_and_start, cncjs, port, "long.ngc", LONG_CUT)
                await _until(lambda: _state(stack) == "cutting", 60, "the cut to start")
                await asyncio.sleep(0.5)
                held_at = time.monotonic()
                cncjs.send("command", str(port), "feedhold")
                await _until(lambda: _state(stack) not in LIT, 10, "the torch to go out")
                figures["hold_to_torch_off_ms"] = round(
                    (_left_lit_at(stack, held_at) - held_at) * 1000, 1
                )
                await asyncio.sleep(1.0)
                assert _state(stack) not in LIT
                cncjs.send("command", str(port), "cyclestart")
                await _until(lambda: _state(stack) == "cutting", 30, "the cut to relight")
                await asyncio.to_thread(_wait_idle, cncjs, 90)
                # Again, and the daemon killed mid-cut: grbl held, CNCjs shows it.
                await asyncio.to_thread(_load_and_start, cncjs, port, "long.ngc", LONG_CUT)
                await _until(lambda: _state(stack) == "cutting", 60, "the second cut")
                await asyncio.sleep(0.5)
                assert stack.daemon is not None
                stack.daemon.kill()
                await asyncio.to_thread(
                    cncjs.wait_for, lambda: cncjs.active_state().startswith("Hold"), 10,
                    "CNCjs to show Hold after the daemon died",
                )  # fmt: skip
            finally:
                cncjs.close()
        result = await stack.finish()
    summary = summarize(result, TELEMETRY_HZ)
    figures["arc_on_s"] = [cut["arc_on_s"] for cut in summary["cuts"]]
    print(json.dumps(figures))
    # The long cut lit, held (out), relit where it stood and finished (150 mm at F1500: about
    # 6 s of arc in all, most of it after the relight); then the second one, cut short.
    before, relit, *killed = figures["arc_on_s"]
    assert 0.3 < before < 3.0, figures
    assert relit > 3.0, figures
    assert len(killed) == 1, figures
    assert summary["safety_violations"] == 0, summary["violations"]
    assert summary["torch_on_at_exit"] is False


# --- helpers ----------------------------------------------------------------------------


class _Port:
    """The grbl port as its own process, in front of the stack's emulated grbl."""

    def __init__(self, stack: Stack, path: Path) -> None:
        self.stack, self.path = stack, path

    def __enter__(self) -> None:
        self.log = (self.path.parent / "grbl-port.log").open("w")
        self.proc = start_port(
            self.path, self.stack.grbl_pty, self.stack.broker.port, self.stack.base, self.log
        )

    def __exit__(self, *exc: object) -> None:
        self.proc.terminate()
        self.proc.wait(10)
        self.log.close()


def _open(url: str, secret: str, port: Path) -> Cncjs:
    cncjs = Cncjs(url, secret)
    reply = cncjs.emit("open", str(port), {"controllerType": "Grbl", "baudrate": 115200})
    assert reply == [None], reply
    cncjs.wait_for(lambda: cncjs.active_state() != "", 20, "a status report from the port")
    return cncjs


def _load_and_start(cncjs: Cncjs, port: Path, name: str, text: str) -> None:
    reply = cncjs.emit("command", str(port), "gcode:load", name, text)
    assert reply, reply
    assert reply[0] is None, reply
    cncjs.send("command", str(port), "gcode:start")
    cncjs.wait_for(lambda: cncjs.workflow()[-1:] == ["running"], 10, f"{name} to start")


def _wait_idle(cncjs: Cncjs, timeout: float) -> None:
    cncjs.wait_for(lambda: cncjs.workflow()[-1:] == ["idle"], timeout, "the program to end")


def _run(cncjs: Cncjs, port: Path, name: str, text: str, *, refused: bool = False) -> None:
    """Load and start; wait for the end (or, ``refused``, for CNCjs's pause on the error,
    then stop it as an owner would)."""
    _load_and_start(cncjs, port, name, text)
    if refused:
        cncjs.wait_for(lambda: cncjs.workflow()[-1:] == ["paused"], 60, "CNCjs's pause")
        cncjs.send("command", str(port), "gcode:stop", {"force": True})
        cncjs.send("command", str(port), "reset")
        time.sleep(1.0)
        return
    _wait_idle(cncjs, 120)
    console = cncjs.console()
    assert not any(line.startswith("error:") for line in console), console


def _state(stack: Stack) -> str:
    states = [e["state"] for e in stack.events if e.get("type") == "sequence"]
    return str(states[-1]) if states else ""


def _left_lit_at(stack: Stack, after: float) -> float:
    for e in stack.events:
        late = e.get("type") == "sequence" and e.get("received_s", 0) >= after
        if late and e["state"] not in LIT:
            return float(e["received_s"])
    return float("nan")


async def _until(done: Any, within_s: float, what: str) -> None:
    deadline = time.monotonic() + within_s
    while not done():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.05)
