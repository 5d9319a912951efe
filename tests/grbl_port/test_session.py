"""A grbl sender's session on the port: one answer per line, in order; an M3's answer (and
the lines streamed behind it) only once the daemon lets XY move; refusals the sender shows;
real-time bytes at once."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import pytest

from dthc_tools.grbl_port.cli import _link
from dthc_tools.grbl_port.session import BANNER, RX_BUFFER_BYTES, PortSession
from dthc_tools.sender import Sender

from ..sender.test_sender_lines import FakeBackend, FakeDaemon


class Daemon(FakeDaemon):
    """The sender tests' daemon; an M3 answered only once ``xy_may_move`` is set, its
    status ``state``, and a thc_hold that ends a lit cut when ``cut_ended_on_hold``."""

    def __init__(self) -> None:
        super().__init__()
        self.xy_may_move = asyncio.Event()
        self.state = "idle"
        self.cut_ended_on_hold = False

    async def request(self, name: str, /, **args: Any) -> dict[str, Any]:
        if name == "status":
            self.requests.append(name)
            return {"state": self.state}
        if name == "thc_hold" and args.get("on") and self.cut_ended_on_hold:
            self.requests.append(name)
            return {"cut_ended": True}  # the daemon put the torch out for the pause
        return await super().request(name, **args)

    async def gcode(self, line: str, **args: Any) -> dict[str, Any]:
        answer = await super().gcode(line, **args)
        if line.startswith("M3"):
            await self.xy_may_move.wait()
        return answer


class Grbl(FakeBackend):
    """The sender tests' backend, with what the port adds: grbl's report, real-time bytes,
    relayed commands; it counts resets and releases."""

    status_line = "<Idle|MPos:0.000,0.000,0.000|FS:0,0>"

    def __init__(self) -> None:
        super().__init__()
        self.realtime_bytes: list[int] = []
        self.cleared = 0
        self.relayed: list[str] = []
        self.resumed = 0

    async def clear(self) -> None:
        self.cleared += 1

    async def resume(self) -> None:
        self.resumed += 1

    def realtime(self, byte: int) -> None:
        self.realtime_bytes.append(byte)

    async def relay(self, text: str) -> list[str]:
        self.relayed.append(text)
        return ["$0=10", "$1=25", "ok"] if text == "$$" else ["ok"]


class Port:
    def __init__(self) -> None:
        self.daemon, self.grbl = Daemon(), Grbl()
        self.out = bytearray()
        self.session = PortSession(Sender(self.daemon, self.grbl), self.grbl, self.out.extend)

    @property
    def said(self) -> list[str]:
        return self.out.decode().splitlines()

    async def settle(self) -> None:
        """Until the port has done all it can with what it was given (fakes answer at once)."""
        for _ in range(200):
            await asyncio.sleep(0)


async def _with_port(body: Callable[[Port], Any], grbl: Grbl | None = None) -> Port:
    port = Port()
    if grbl is not None:  # another table's grbl behind the port
        port.grbl = grbl
        port.session = PortSession(Sender(port.daemon, grbl), grbl, port.out.extend)
    runner = asyncio.ensure_future(port.session.run())
    try:
        await body(port)
    finally:
        runner.cancel()
        await asyncio.gather(runner, return_exceptions=True)
    return port


async def test_lines_behind_an_m3_wait_for_the_pierce_and_every_line_gets_one_ok() -> None:
    async def body(port: Port) -> None:
        port.session.received(b"G0 X10 Y10\nM3\nG1 X50 F2000\nG1 Y50\n")
        await port.settle()
        assert port.said == ["ok"]  # the rapid; the M3 waits for the daemon
        assert port.grbl.queued == ["G0 X10 Y10"]  # nothing moves XY before the pierce
        port.session.received(b"?")
        await port.settle()
        assert port.said[-1] == Grbl.status_line  # real-time: answered while lines wait
        port.daemon.xy_may_move.set()
        await port.settle()
        assert port.said == ["ok", Grbl.status_line, "ok", "ok", "ok"]
        assert port.grbl.queued == ["G0 X10 Y10", "G1 X50 F2000", "G1 Y50"]

    port = await _with_port(body)
    assert port.daemon.lines[0] == "M3"


async def test_a_refused_line_is_shown_then_answered_with_an_error_and_the_next_runs() -> None:
    async def body(port: Port) -> None:
        port.session.received(b"G200 P99999\nG1 X5 F100\n(comment)\n\n")
        await port.settle()

    port = await _with_port(body)
    said = port.said
    assert said[0].startswith("[MSG:G200")
    assert said[0].endswith("]")
    assert said[1:] == ["error:20", "ok", "ok", "ok"]
    assert port.daemon.lines == ["G1 F100"]  # the feed note of the next line only
    assert port.grbl.queued == ["G1 X5 F100"]


async def test_an_overlong_line_is_error_11_and_a_program_end_ends_the_program() -> None:
    async def body(port: Port) -> None:
        port.session.received(b"G1 X" + b"1" * 300 + b"\nG0 X1\nM30\nG0 X2\n")
        await port.settle()

    port = await _with_port(body)
    assert port.said == ["error:11", "ok", "ok", "ok"]
    assert port.daemon.requests == ["program_start", "program_end", "program_start"]


async def test_a_reset_drops_the_waiting_lines_resets_grbl_and_says_the_banner() -> None:
    async def body(port: Port) -> None:
        port.session.received(b"M3\nG1 X50 F2000\n")
        await port.settle()
        port.session.received(b"\x18")
        await port.settle()
        assert port.grbl.cleared == 1
        assert port.said[-1] == BANNER
        port.daemon.xy_may_move.set()
        await port.settle()

    port = await _with_port(body)
    assert port.said == [BANNER]  # neither the M3 nor the line behind it is answered
    assert "G1 X50 F2000" not in port.grbl.queued  # dropped: it waited behind the M3
    assert "abort" in port.daemon.requests  # the cut the M3 started is stopped


async def test_override_bytes_go_to_grbl_and_a_cycle_start_with_nothing_waiting_too() -> None:
    async def body(port: Port) -> None:
        port.session.received(b"\x91~")
        await port.settle()

    port = await _with_port(body)
    assert port.grbl.realtime_bytes == [0x91, ord("~")]
    assert port.said == []


async def test_grbls_own_commands_pass_through_and_a_jog_is_refused_while_a_cut_is_lit() -> None:
    async def body(port: Port) -> None:
        port.session.received(b"$$\n$J=G91 X10 F1000\n")
        await port.settle()
        port.daemon.state = "cutting"
        port.session.received(b"$J=G91 X10 F1000\n")
        await port.settle()

    port = await _with_port(body)
    assert port.grbl.relayed == ["$$", "$J=G91 X10 F1000"]  # the second jog never reached grbl
    assert port.said[:4] == ["$0=10", "$1=25", "ok", "ok"]
    assert port.said[4].startswith("[MSG:jog refused: a cut is lit")
    assert port.said[5] == "error:8"


async def test_a_feed_hold_mid_cut_holds_the_next_line_and_cycle_start_pierces_again() -> None:
    async def body(port: Port) -> None:
        port.daemon.xy_may_move.set()
        port.daemon.cut_ended_on_hold = True
        port.session.received(b"G0 X10 Y10\nM3\nG1 X50 F2000\n")
        await port.settle()
        assert port.said == ["ok", "ok", "ok"]
        port.session.received(b"!")  # the torch goes out (the daemon), grbl holds
        await port.settle()
        port.session.received(b"G1 Y50\n")
        await port.settle()
        assert port.said == ["ok", "ok", "ok"]  # held, not refused
        assert port.grbl.queued[-1] == "G1 X50 F2000"
        port.session.received(b"~")
        await port.settle()

    port = await _with_port(body)
    assert port.said == ["ok", "ok", "ok", "ok"]
    assert port.grbl.queued[-1] == "G1 Y50"  # went on after the resume
    assert port.daemon.lines.count("M3") == 2  # the cut started again where the torch stood
    assert port.grbl.resumed == 1
    assert "rearm" in port.daemon.requests


async def test_a_sender_is_told_the_ports_receive_buffer_not_grbls() -> None:
    """``$I``'s [OPT:] gives the port's 128 bytes (grblHAL would say 1024); a report's Bf:
    the port's free bytes, less the lines it holds behind an M3."""

    class GrblHal(Grbl):
        status_line = "<Idle|MPos:0.000,0.000,0.000|Bf:35,1023|FS:0,0>"

        async def relay(self, text: str) -> list[str]:
            return ["[VER:1.1f.20230101:]", "[OPT:VNMZL,35,1024]", "ok"]

    async def body(port: Port) -> None:
        port.session.received(b"$I\n")
        await port.settle()
        port.session.received(b"?")
        await port.settle()
        port.session.received(b"M3\nG1 X50 F2000\n?")  # 3 + 13 bytes wait, ends included
        await port.settle()
        port.daemon.xy_may_move.set()
        await port.settle()
        port.session.received(b"?")
        await port.settle()

    port = await _with_port(body, GrblHal())
    said = port.said
    assert said[:3] == ["[VER:1.1f.20230101:]", f"[OPT:VNMZL,35,{RX_BUFFER_BYTES}]", "ok"]
    reports = [line for line in said if line.startswith("<")]
    assert reports == [
        f"<Idle|MPos:0.000,0.000,0.000|Bf:35,{RX_BUFFER_BYTES}|FS:0,0>",
        f"<Idle|MPos:0.000,0.000,0.000|Bf:35,{RX_BUFFER_BYTES - 16}|FS:0,0>",
        f"<Idle|MPos:0.000,0.000,0.000|Bf:35,{RX_BUFFER_BYTES}|FS:0,0>",
    ]


def test_a_tcp_listener_beyond_loopback_is_said_to_be_open_to_its_network(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Invariant 8: a grbl's TCP port has no login, so listening beyond loopback is said
    out loud; loopback says nothing (the pty, the default, is the serial ports' group's)."""
    session = Port().session
    _link("tcp://127.0.0.1:2323", session)
    _link("tcp://localhost:2323", session)
    assert capsys.readouterr().err == ""
    _link("tcp://0.0.0.0:2323", session)
    assert "anyone who can reach this address can start a cut" in capsys.readouterr().err
