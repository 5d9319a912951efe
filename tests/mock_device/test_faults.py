"""Fault injection on the mock's link, and firmware variants with deliberate faults."""

from __future__ import annotations

import random
from typing import Any

import pytest

import firmware_protocol as fp
from mock_device.faults import FaultPlan, LinkFaultInjector
from mock_device.sim import SimulatedBoard
from mock_device.sim_host import SimHost
from mock_device.variants import DuplicatesActedTwice, LeaseIgnored, WrongCrcVariant


def _decode(board: SimulatedBoard, ms: int) -> fp.StreamDecoder:
    decoder = fp.StreamDecoder()
    board.advance_ms(ms)
    decoder.feed(board.read())
    return decoder


def test_bit_flips_show_up_as_crc_or_framing_errors() -> None:
    """A per-byte flip rate corrupts frames the host then rejects and counts."""
    board = SimulatedBoard("flat_clean", seed=1, faults=FaultPlan(bit_flip_rate=1e-3))
    stats = _decode(board, 2000).stats
    assert board.faults.flipped_bits > 0
    assert stats.crc_errors + stats.framing_errors > 0
    assert stats.frames_ok > 300


@pytest.mark.parametrize("rate", [0.01, 0.3, 0.9])
def test_bit_flip_rate_is_the_probability_per_byte(rate: float) -> None:
    """Each byte is hit with probability ``rate``, one bit per hit byte."""
    injector = LinkFaultInjector(FaultPlan(bit_flip_rate=rate), random.Random(5))
    data = bytes(100_000)
    out = injector.incoming(data)
    hit = sum(1 for b in out if b)
    assert all(bin(b).count("1") <= 1 for b in out)
    assert hit == injector.flipped_bits
    assert hit / len(data) == pytest.approx(rate, rel=0.1)


@pytest.mark.parametrize(
    ("plan", "name"),
    [
        ({"bit_flip_rate": 1.5}, "bit_flip_rate"),
        ({"drop_frame_rate": -0.1}, "drop_frame_rate"),
        ({"garbage_rate": 2.0}, "garbage_rate"),
        ({"delay_ms": -1.0}, "delay_ms"),
        ({"garbage_max_bytes": 0}, "garbage_max_bytes"),
    ],
)
def test_a_plan_out_of_range_is_refused_by_name(plan: dict[str, Any], name: str) -> None:
    """A rate outside 0..1, a negative delay or an empty garbage burst is a configuration error."""
    with pytest.raises(ValueError, match=name):
        FaultPlan(**plan)


def test_dropped_frames_leave_gaps_in_the_sample_stream() -> None:
    """Dropped board frames are missing from the stream_seq sequence."""
    board = SimulatedBoard("flat_clean", seed=1, faults=FaultPlan(drop_frame_rate=0.1))
    board.advance_ms(1000)
    batches = [m for m in fp.StreamDecoder().feed(board.read()) if isinstance(m, fp.Samples)]
    assert 150 < len(batches) < 195
    assert board.faults.dropped_frames == 200 - len(batches)


def test_garbage_bursts_cost_at_most_the_frame_they_precede() -> None:
    """A burst merges with the next frame at worst; every other frame decodes."""
    board = SimulatedBoard("flat_clean", seed=2, faults=FaultPlan(garbage_rate=0.3))
    decoder = _decode(board, 1000)
    bursts = board.faults.garbage_bursts
    assert bursts > 30
    assert decoder.stats.frames_ok >= 200 - bursts
    assert decoder.stats.frames_ok < 200
    assert decoder.stats.dropped_bytes >= board.faults.garbage_bytes


def test_lease_ignoring_firmware_is_counted_as_a_safety_violation() -> None:
    """The ground truth audits the lease on its own: a torch left on is a violation."""
    board = SimulatedBoard("flat_clean", seed=1, firmware_class=LeaseIgnored)
    host = SimHost(board)
    host.open_session(lease_ms=50)
    host.request(fp.Torch(0, True))
    host.pump(300)
    assert board.plant.torch_on
    assert board.plant.truth.violations.get("torch_on_after_lease_expiry") == 1
    assert board.unsafe_torch_us > 200_000  # 300 ms quiet, 50 ms lease: ~249 ms unsafe


def test_good_firmware_has_no_lease_violation() -> None:
    """The same scenario with the real firmware: torch off in time, nothing counted."""
    board = SimulatedBoard("flat_clean", seed=1)
    host = SimHost(board)
    host.open_session(lease_ms=50)
    host.request(fp.Torch(0, True))
    host.pump(300)
    assert not board.plant.torch_on
    assert not board.plant.truth.violations.get("torch_on_after_lease_expiry")
    assert board.unsafe_torch_us == 0


def test_duplicates_acted_twice_variant_reexecutes_retransmissions() -> None:
    """The faulty variant acts on a retransmitted TORCH on after TORCH off."""
    host = SimHost(SimulatedBoard("flat_clean", seed=1, firmware_class=DuplicatesActedTwice))
    host.open_session()
    seq = host.send(fp.Torch(0, True))
    host.request(fp.Torch(0, False))
    host.request(fp.Torch(0, True), seq=seq)
    assert host.board.plant.torch_on


def test_wrong_crc_variant_is_rejected_by_a_conforming_host() -> None:
    """Frames with Klipper's CRC variant all fail the CRC-16/CCITT-FALSE check."""
    board = SimulatedBoard("flat_clean", seed=1, firmware_class=WrongCrcVariant)
    decoder = _decode(board, 100)
    assert decoder.stats.frames_ok == 0
    assert decoder.stats.crc_errors == 20


def test_wrong_crc_variant_uses_klippers_crc_variant() -> None:
    """The variant's CRC really is CRC-16/MCRF4XX (check value 0x6F91), not a random one."""
    from mock_device.variants import _crc16_mcrf4xx

    assert _crc16_mcrf4xx(b"123456789") == 0x6F91
