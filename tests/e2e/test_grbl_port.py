"""A grbl sender through the grbl port (issue 32, in progress): the port as its own process
on a pty, the table's grbl (the emulated grbl on its pty, mirrored into the mock's plant)
behind it, the daemon and the mock board beside it over mosquitto. The "sender" here is a
script doing what CNCjs does (character counting with a 120-byte budget, comments
stripped, ``?`` polled); CNCjs itself comes with the rest of the issue.

Every line gets exactly one answer, in order; the cuts burn; nothing moves XY before a
pierce; the torch is never lit outside a cut (the plant's violations)."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
import serial

from dthc_tools.demo import Stack, StackOptions
from dthc_tools.demo.stack import StackResult
from dthc_tools.demo.summary import summarize
from dthc_tools.grbl_port.process import start_port

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

# A MASSO-form program as a sender streams it (no comments: senders strip them).
PROGRAM = [
    "G21 G90",
    "G200 F250 P3.8 D300 C1.5 V0 A90 O1 S0",
    "G0 X10 Y10",
    "M3",
    "M667 F600",
    "G1 X60 Y10 F3000",
    "G1 X60 Y40",
    "M666",
    "M5",
    "G0 X80 Y10",
    "M3",
    "G1 X120 Y10 F3000",
    "M5",
    "G0 X0 Y0",
    "M30",
]
# Then a PlasmaC-form program on the same port: its dialect found from its own lines.
PLASMAC = ["G21 G90", "G0 X20 Y60", "M3 $0 S1", "G1 X90 Y60 F2500", "M5 $0", "G0 X0 Y0", "M2"]
TELEMETRY_HZ = StackOptions(Path()).telemetry_hz
BUDGET = 120  # CNCjs's character-counting budget (grbl's 128 less a margin)


def stream(
    port: Path, lines: list[str], timeout_s: float = 90.0, *, hold_after: int | None = None
) -> tuple[list[str], str]:
    """Character counting as CNCjs does it; the answers (ok / error:N) in order, and every
    other line the port said (banner, [MSG:...], status reports). ``hold_after``: once
    that many lines are answered, a feed hold (!), and cycle start (~) 1.5 s later."""
    answers: list[str] = []
    said: list[str] = []
    in_flight: list[int] = []
    with serial.Serial(str(port), 115200, timeout=0.05) as link:
        # A pty cannot tell the port it was opened (no DTR reset as on an Arduino): a soft
        # reset asks it who it is, as UGS does on connecting.
        link.write(b"\x18")
        buffer = b""
        banner_deadline = time.monotonic() + 10.0
        while b"Grbl " not in buffer and time.monotonic() < banner_deadline:
            buffer += link.read(4096)
        pending = list(lines)
        deadline = time.monotonic() + timeout_s
        last_poll = 0.0
        resume_at: float | None = None
        while (pending or in_flight) and time.monotonic() < deadline:
            if hold_after is not None and len(answers) >= hold_after and resume_at is None:
                link.write(b"!")
                resume_at = time.monotonic() + 1.5
            if resume_at is not None and time.monotonic() >= resume_at:
                link.write(b"~")
                resume_at = float("inf")
            while pending and sum(in_flight) + len(pending[0]) + 1 <= BUDGET:
                line = pending.pop(0)
                link.write(line.encode() + b"\n")
                in_flight.append(len(line) + 1)
            if time.monotonic() - last_poll > 0.25:
                link.write(b"?")
                last_poll = time.monotonic()
            buffer += link.read(4096)
            *complete, buffer = buffer.split(b"\n")
            for raw in complete:
                text = raw.decode().strip()
                if text == "ok" or text.startswith("error:"):
                    answers.append(text)
                    in_flight.pop(0)
                elif text:
                    said.append(text)
    return answers, "\n".join(said)


async def test_a_grbl_sender_cuts_a_masso_then_a_plasmac_program_through_the_port(
    tmp_path: Path,
) -> None:
    result, answers, said = await through_the_port(tmp_path, ["$$", *PROGRAM, *PLASMAC])
    summary = summarize(result, TELEMETRY_HZ)
    assert answers == ["ok"] * (1 + len(PROGRAM) + len(PLASMAC)), (answers, said)
    assert "$110=" in said  # grbl's own settings, relayed as it wrote them
    assert "Grbl 1.1" in said  # the banner, after the reset
    assert "<Idle" in said or "<Run" in said  # ? answered with grbl's own report
    assert len(summary["cuts"]) == 3
    assert all(cut["arc_on_s"] > 0 for cut in summary["cuts"])
    assert summary["safety_violations"] == 0, summary["violations"]
    assert summary["torch_on_at_exit"] is False


async def through_the_port(
    workdir: Path, lines: list[str], *, hold_after: int | None = None
) -> tuple[StackResult, list[str], str]:
    """The stack with an emulated grbl, the port in front of it, ``lines`` streamed."""
    port = workdir / "grbl-port"
    async with Stack(StackOptions(workdir, broker="mosquitto", motion="grbl")) as stack:
        log = (workdir / "grbl-port.log").open("w")
        proc = await asyncio.to_thread(
            start_port, port, stack.grbl_pty, stack.broker.port, stack.base, log
        )
        try:
            answers, said = await asyncio.to_thread(stream, port, lines, hold_after=hold_after)
        finally:
            proc.terminate()
            await asyncio.to_thread(proc.wait, 10)
            log.close()
        return await stack.finish(), answers, said
