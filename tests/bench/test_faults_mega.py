"""``bench faults --board atmega2560``: the fault matrix on the reference firmware's ELF on
the emulated Mega. Its ground truth from the emulator's record (pure), the emulator's link
faults as the matrix strikes them, and one cell run for real."""

from __future__ import annotations

import argparse
import os
import select
import time
import tty
from pathlib import Path

import pytest

from dthc_tools.bench import faults
from dthc_tools.emulated_board import (
    EmulatedBoard,
    HarnessOptions,
    RecordEvent,
    read_record,
)
from dthc_tools.emulated_board.harness import torch_on_edges, unsafe_torch_us
from tests.emulated_board.conftest import needs_tools

GRACE_US = 251_250  # a 250 ms lease, one 1 ms sample period, the 250 µs decode tolerance


def rec(t_us: int, event: str, *fields: str) -> RecordEvent:
    return RecordEvent(t_us, t_us / 1e6, event, fields)


def frames_every(start_us: int, end_us: int, step_us: int = 10_000) -> list[RecordEvent]:
    return [
        rec(t, "host_frame", "0x05", "1", "9", str(t)) for t in range(start_us, end_us, step_us)
    ]


def test_the_relay_on_past_the_lease_after_the_last_host_frame_is_unsafe() -> None:
    # Host frames until 50 ms, the relay on from 1 ms to 400 ms: on 98.75 ms past its grace.
    events = sorted(
        [rec(1_000, "torch", "1"), *frames_every(0, 50_001), rec(400_000, "torch", "0")],
        key=lambda e: e.t_us,
    )
    assert unsafe_torch_us(events, GRACE_US) == (400_000 - 50_000 - GRACE_US, 1)
    # Off within the grace: nothing.
    early = [e for e in events if e.event != "torch"] + [rec(1_000, "torch", "1"),
                                                         rec(300_000, "torch", "0")]  # fmt: skip
    assert unsafe_torch_us(sorted(early, key=lambda e: e.t_us), GRACE_US) == (0, 0)
    # Frames all along: never late, however long the relay burns.
    steady = [*frames_every(0, 2_000_000), rec(2_000_000, "torch", "0")]
    steady.insert(1, rec(5, "torch", "1"))
    assert unsafe_torch_us(steady, GRACE_US) == (0, 0)
    # Still on at the record's end: counted to its last line; two late stretches, two
    # episodes (a frame in between renews the lease).
    gaps = [rec(0, "host_frame", "0x05", "1", "9"), rec(10, "torch", "1"),
            rec(300_000, "host_frame", "0x05", "2", "9"), rec(600_000, "z", "20000")]  # fmt: skip
    assert unsafe_torch_us(gaps, GRACE_US) == (2 * (300_000 - GRACE_US), 2)
    # The relay never on, or on before any host frame (all of it late).
    assert unsafe_torch_us(frames_every(0, 900_000), GRACE_US) == (0, 0)
    assert unsafe_torch_us([rec(0, "torch", "1"), rec(5_000, "torch", "0")], GRACE_US) == (
        5_000,
        1,
    )


def test_each_rising_edge_of_the_relay_is_one_torch_on_carried_out() -> None:
    events = [rec(0, "torch", "1"), rec(1, "torch", "0"), rec(2, "torch", "1"),
              rec(3, "ohmic_enable", "1"), rec(4, "torch", "0")]  # fmt: skip
    assert torch_on_edges(events) == 2
    assert torch_on_edges([]) == 0


def test_board_truth_reads_the_record_as_the_mock_reports_its_exit(tmp_path: Path) -> None:
    record = tmp_path / "board-record.csv"
    record.write_text(
        "# dthc emulated board record v1: t_us,mono_s,event,fields...\n"
        "100,1.0,host_frame,0x05,1,9,90\n"
        "200,1.1,torch,1\n"
        "600200,1.7,torch,0\n"
        "699900,1.8,host_frame,0x05,2,9,699850\n"
        "700000,1.8,torch,1\n"
        "800000,1.9,z,20000\n"
    )
    truth = faults.board_truth(record, lease_ms=250)
    assert truth["unsafe_torch_ms"] == pytest.approx((600_200 - 100 - 251_250) / 1000)
    assert truth["torch_on_commands"] == 2
    assert truth["violations"] == {"torch_on_after_lease_expiry": 1}
    assert truth["host_frames"] == 2
    assert truth["relay_on_at_end"] is True


def test_the_board_serials_are_the_ones_the_daemon_logged_from_hello(tmp_path: Path) -> None:
    log = tmp_path / "daemon.log"
    log.write_text(
        '{"event": "starting"}\n'
        '{"serial": "DTHC-MEGA-0001", "event": "board_hello"}\n'
        "not json\n"
        '{"serial": "DTHC-MEGA-0001", "event": "board_hello"}\n'  # after a reconnect: once
    )
    assert faults.board_serials(log) == ["DTHC-MEGA-0001"]


class RawPort:
    """The emulated board's pty opened raw, non-blocking."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)

    def drain(self, for_s: float) -> bytes:
        """What arrives within ``for_s`` (b"" once the port hung up)."""
        got = b""
        deadline = time.monotonic() + for_s
        while (left := deadline - time.monotonic()) > 0:
            ready, _, _ = select.select([self.fd], [], [], left)
            if not ready:
                break
            try:
                chunk = os.read(self.fd, 65536)
            except BlockingIOError:
                continue
            if not chunk:
                raise EOFError
            got += chunk
        return got

    def close(self) -> None:
        os.close(self.fd)


@needs_tools
@pytest.mark.timeout(60)
def test_the_emulators_link_faults_unplug_replug_inject_and_drop(tmp_path: Path) -> None:
    """The matrix's board faults on the firmware's ELF: garbage appears in the board's
    stream; frame loss at rate 1 silences it; unplugged, the client's port hangs up and its
    path is gone; replugged, a new port at the same path carries the board's frames."""
    pty = tmp_path / "board.pty"
    options = HarnessOptions(record=tmp_path / "record.csv", stderr=tmp_path / "host.log")
    with EmulatedBoard(pty, options) as board:
        port = RawPort(pty)
        try:
            normal = port.drain(0.4)
            assert len(normal) > 200, "the firmware streams frames on its own"
            board.inject(b"\xaa" * 500)
            assert b"\xaa" * 240 in port.drain(0.2)
            board.drop_frames(1.0, 0.6)
            port.drain(0.05)  # the frame that had started
            assert len(port.drain(0.4)) < len(normal) / 4
            assert int(board.status().fields["frames_lost"]) > 0
            board.unplug()
            assert not pty.exists()
            assert board.status().fields["link"] == "unplugged"
            with pytest.raises((EOFError, OSError)):
                port.drain(1.0)
        finally:
            port.close()
        board.replug()
        assert pty.exists()
        port = RawPort(pty)
        try:
            assert len(port.drain(0.4)) > 200
        finally:
            port.close()
        assert board.status().fields["link"] == "up"
    kinds = {e.event for e in read_record(tmp_path / "record.csv")}
    assert {"inject", "link_drop", "frame_lost", "unplug", "replug"} <= kinds


@needs_tools
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_cell_mid_cut_holds_on_the_emulated_mega() -> None:
    """The daemon killed while cutting (its supervisor restarts it), against the firmware
    on the emulated Mega: no torch-on past the lease at the relay pin, nothing lost or
    doubled, back within 2 s. The cell is the emulator's: its record saw the daemon's frames
    and its clock ran. (The corrupt-byte and frame-loss faults' emulator side is
    test_the_emulators_link_faults_unplug_replug_inject_and_drop; one cell keeps the suite
    short, the whole matrix is the bench's.)"""
    parser = argparse.ArgumentParser()
    faults.add_arguments(parser)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args([
        "--board", "atmega2560", "--faults", "daemon_kill_restart",
        "--phases", "cutting", "--json",
    ])  # fmt: skip
    result = faults.run(args)
    assert result["board"] == "atmega2560"
    assert result["cells_failed"] == 0, result["matrix"]
    assert result["unsafe_torch_ms"] == 0.0
    matrix = result["matrix"]
    assert isinstance(matrix, list)
    (killed,) = matrix
    for cell in matrix:
        assert cell["board"] == "atmega2560"
        assert cell["board_serials"] == ["DTHC-MEGA-0001"], cell  # the firmware's HELLO
        emulator = cell["emulator"]
        assert emulator["host_frames"] > 100, emulator  # the daemon talked to the MCU
        assert emulator["sim_s"] > 5.0, emulator
        assert emulator["speed"] > 0.5, emulator
        assert cell["recovery_s"] is not None
        assert cell["recovery_s"] <= faults.RECOVERY_GOAL_S
    assert "LEASE_EXPIRED" in str(killed["daemon_faults"]), killed
    assert killed["restart_line"] == 5
