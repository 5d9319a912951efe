"""The mock board as its own process on a real pty, seen through pyserial like a USB port."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

import firmware_protocol as fp
from dthc_tools.procs import die_with_parent
from tests.processes import stop

pytestmark = pytest.mark.slow


def _start(pty: Path, *extra: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "mock_device", "--pty", str(pty), "--seed", "9", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=die_with_parent(),
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("READY"), line + proc.stderr.read() if proc.stderr else ""
    return proc


@pytest.fixture
def mock(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], Path]]:
    pty = tmp_path / "dthc0"
    proc = _start(pty, "--unplug-for", "0.5")
    yield proc, pty
    stop(proc)


def _exchange(port: serial.Serial, msg: fp.Message, want: type[fp.Message]) -> fp.Message:
    decoder = fp.StreamDecoder()
    port.write(fp.encode(msg))
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        for reply in decoder.feed(port.read(port.in_waiting or 1)):
            if isinstance(reply, want) and reply.seq == msg.seq:
                return reply
    raise AssertionError(f"no {want.__name__} for {msg!r}")


def _read_until_error(port: serial.Serial, within_s: float) -> None:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        port.read(64)


def test_handshake_and_samples_over_a_real_pty(
    mock: tuple[subprocess.Popen[str], Path],
) -> None:
    """A pyserial client on the symlinked pty gets HELLO_INFO and a 1 kHz sample stream."""
    _, pty = mock
    with serial.Serial(str(pty), timeout=0.05, exclusive=True) as port:
        info = _exchange(port, fp.Hello(1, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 5), fp.HelloInfo)
        assert isinstance(info, fp.HelloInfo)
        assert info.sample_rate_hz == 1000
        decoder = fp.StreamDecoder()
        t0 = time.monotonic()
        batches: list[fp.Samples] = []
        while time.monotonic() - t0 < 0.5:
            batches += [m for m in decoder.feed(port.read(512)) if isinstance(m, fp.Samples)]
        span_us = batches[-1].t0_us - batches[0].t0_us
        assert len(batches) >= 50
        assert span_us == (len(batches) - 1) * 5000  # no batch lost on a clean pty


def test_unplug_looks_like_a_usb_unplug_and_the_port_comes_back(
    mock: tuple[subprocess.Popen[str], Path],
) -> None:
    """SIGUSR1 closes the pty master: pyserial raises SerialException; later the path reopens."""
    proc, pty = mock
    port = serial.Serial(str(pty), timeout=0.2)
    try:
        assert port.read(64)
        proc.send_signal(signal.SIGUSR1)
        with pytest.raises(serial.SerialException):
            _read_until_error(port, 2.0)
    finally:
        port.close()
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            with serial.Serial(str(pty), timeout=0.2) as again:
                assert again.read(64)
                return
        except (serial.SerialException, OSError):
            time.sleep(0.05)
    pytest.fail("the pty did not come back behind the same path")


def test_lease_expiry_in_the_real_time_process(mock: tuple[subprocess.Popen[str], Path]) -> None:
    """A host that goes quiet after TORCH on sees LEASE_EXPIRED within lease + one period."""
    _, pty = mock
    with serial.Serial(str(pty), timeout=0.02) as port:
        _exchange(port, fp.Hello(1, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 5), fp.HelloInfo)
        _exchange(port, fp.SetLease(2, 100), fp.Ack)
        _exchange(port, fp.Torch(3, True), fp.Ack)
        decoder = fp.StreamDecoder()
        fault = None
        last_torch_on_t = None
        deadline = time.monotonic() + 2.0
        while fault is None and time.monotonic() < deadline:
            for m in decoder.feed(port.read(512)):
                if isinstance(m, fp.Samples) and m.status & fp.StatusBit.TORCH_ON:
                    last_torch_on_t = m.t0_us + 4 * m.period_us
                if isinstance(m, fp.Fault):
                    fault = m
        assert isinstance(fault, fp.Fault)
        assert fault.code == fp.FaultCode.LEASE_EXPIRED
        assert last_torch_on_t is not None
        assert fault.t_us - last_torch_on_t <= 1000 + 5000  # within the batch that saw it


def test_ground_truth_is_written_on_exit(tmp_path: Path) -> None:
    """--truth writes the recorded ground truth when the process ends after --duration."""
    truth = tmp_path / "truth.csv"
    proc = subprocess.run(
        [sys.executable, "-m", "mock_device", "--pty", str(tmp_path / "p"), "--duration", "0.3",
         "--truth", str(truth)],
        capture_output=True, text=True, timeout=30, check=True,
    )  # fmt: skip
    assert proc.stdout.startswith("READY")
    header, *rows = truth.read_text().splitlines()
    assert "true_height_mm" in header
    assert len(rows) >= 250
    assert not os.path.exists(tmp_path / "p")


def test_latency_log_records_receipts_and_sends(tmp_path: Path) -> None:
    """--latency-log: each Z_VELOCITY's receipt and each SAMPLES send, in board time."""
    log = tmp_path / "latency.jsonl"
    pty = tmp_path / "dthc0"
    proc = _start(pty, "--latency-log", str(log))
    seen: list[fp.Samples] = []
    status = None
    try:
        with serial.Serial(str(pty), timeout=0.02) as port:
            _exchange(port, fp.Hello(1, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 5), fp.HelloInfo)
            decoder = fp.StreamDecoder()
            for seq in (1, 2, 2):  # the repeat is received, and not applied again
                port.write(fp.encode(fp.ZVelocity(0, seq, 0, 50)))
                deadline = time.monotonic() + 0.05
                while time.monotonic() < deadline:
                    seen += [m for m in decoder.feed(port.read(256)) if isinstance(m, fp.Samples)]
    finally:
        status = stop(proc)
    assert status == 0
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert records[0]["kind"] == "start"
    rx = [r for r in records if r["kind"] == "zvel_rx"]
    tx = [r for r in records if r["kind"] == "samples_tx"]
    assert [r["stream_seq"] for r in rx] == [1, 2, 2]
    assert all(r["current"] for r in rx)
    assert rx[0]["rx_board_us"] <= rx[1]["rx_board_us"] <= rx[2]["rx_board_us"]
    # Board time of the receipt is near the firmware's clock (within a few wakes).
    assert all(abs(r["rx_board_us"] - r["fw_t_us"]) < 50_000 for r in rx)
    # Every batch the host saw was logged as sent, with its last sample's time.
    sent = {(r["stream_seq"], r["t0_us"]): r for r in tx}
    assert seen
    for m in seen:
        r = sent[(m.stream_seq, m.t0_us)]
        assert r["t_last_us"] == m.t_last_us
        assert r["samples"] == len(m.samples_cv) == 5
        assert abs(r["tx_board_us"] - r["t_last_us"]) < 50_000
    # No batch leaves before its last sample's board time (a tick runs once it is due).
    early = [r for r in tx if r["tx_board_us"] < r["t_last_us"]]
    assert early == []
    tx_times = [r["tx_board_us"] for r in tx]
    assert tx_times == sorted(tx_times)
    assert [r["stream_seq"] for r in tx] == list(range(len(tx)))  # from the first batch on


def test_after_a_reboot_board_time_restarts_and_runs_at_real_time(
    mock: tuple[subprocess.Popen[str], Path],
) -> None:
    """SIGUSR2 reboots the board: its clock starts again at 0 and keeps pace with the wall
    clock; it does not run the ticks since the process started at once (which would move
    the plant and the gantry ahead by that much)."""
    proc, pty = mock
    time.sleep(2.0)
    proc.send_signal(signal.SIGUSR2)
    rebooted = time.monotonic()
    time.sleep(0.2)
    with serial.Serial(str(pty), timeout=0.05, exclusive=True) as port:
        hello = fp.Hello(1, fp.PROTOCOL_MAJOR, fp.PROTOCOL_MINOR, 5)
        assert isinstance(_exchange(port, hello, fp.HelloInfo), fp.HelloInfo)
        decoder = fp.StreamDecoder()
        batches: list[fp.Samples] = []
        while len(batches) < 20:
            batches += [m for m in decoder.feed(port.read(512)) if isinstance(m, fp.Samples)]
        since_reboot_us = (time.monotonic() - rebooted) * 1e6
    assert batches[-1].t0_us <= since_reboot_us + 100_000
