"""Fault injection on the mock's link, and firmware variants with deliberate faults."""

from __future__ import annotations

import firmware_protocol as fp
from mock_device.faults import FaultPlan
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
