"""In-memory transport pairs (a test fixture), clean and hostile."""

from __future__ import annotations

import asyncio

import pytest

from dthc_bridge.transport import (
    TransportError,
    open_transport,
)

from .helpers import Recorder, settle
from .memory import LinkFaults, MemoryTransport, memory_pair

PAYLOAD = bytes(range(256)) * 4


def pair(
    a_to_b: LinkFaults | None = None, b_to_a: LinkFaults | None = None
) -> tuple[MemoryTransport, Recorder, MemoryTransport, Recorder]:
    rec_a, rec_b = Recorder(), Recorder()
    a, b = memory_pair(
        rec_a.on_bytes,
        rec_a.on_lost,
        rec_b.on_bytes,
        rec_b.on_lost,
        faults_a_to_b=a_to_b,
        faults_b_to_a=b_to_a,
    )
    return a, rec_a, b, rec_b


async def test_pair_exchanges_bytes_both_ways_in_order() -> None:
    """What one end writes the other receives, whole and in write order."""
    a, rec_a, b, rec_b = pair()
    a.write(b"\x00one")
    a.write(b"two\x00")
    b.write(b"reply")
    assert await rec_b.wait_for_bytes(8) == b"\x00onetwo\x00"
    assert await rec_a.wait_for_bytes(5) == b"reply"
    assert rec_b.chunks == [b"\x00one", b"two\x00"]
    await a.close()
    await b.close()


async def test_delivery_goes_through_the_loop_never_inside_write() -> None:
    """write() returns before the peer sees anything, so callbacks never re-enter the writer."""
    a, _, b, rec_b = pair()
    a.write(b"x")
    assert rec_b.chunks == []
    await settle(0)
    assert rec_b.chunks == [b"x"]
    await a.close()
    await b.close()


async def test_one_byte_at_a_time_delivers_the_same_bytes() -> None:
    """Split into single-byte deliveries, the stream arrives unchanged and in order."""
    a, _, b, rec_b = pair(LinkFaults(one_byte_at_a_time=True))
    a.write(PAYLOAD[:500])
    a.write(PAYLOAD[500:])
    assert await rec_b.wait_for_bytes(len(PAYLOAD)) == PAYLOAD
    assert {len(c) for c in rec_b.chunks} == {1}
    await a.close()
    await b.close()


async def test_loss_rate_one_delivers_nothing() -> None:
    """With every write lost, the peer receives nothing and the drops are counted."""
    a, _, b, rec_b = pair(LinkFaults(loss_rate=1.0))
    for _ in range(20):
        a.write(b"lost")
    await settle()
    assert rec_b.chunks == []
    assert a.writes_dropped == 20
    await a.close()
    await b.close()


async def test_partial_loss_is_seeded_and_repeatable() -> None:
    """The same seed drops the same writes; some but not all get through at rate 0.5."""
    outcomes = []
    for _ in range(2):
        a, _, b, rec_b = pair(LinkFaults(loss_rate=0.5, seed=7))
        for i in range(100):
            a.write(bytes([i]))
        await settle()
        outcomes.append(rec_b.data)
        await a.close()
        await b.close()
    assert outcomes[0] == outcomes[1]
    assert 20 < len(outcomes[0]) < 80


async def test_bit_flips_change_one_bit_per_hit_byte() -> None:
    """At rate 1.0 every byte arrives with exactly one bit flipped; length is unchanged."""
    a, _, b, rec_b = pair(LinkFaults(bit_flip_rate=1.0, seed=3))
    a.write(PAYLOAD)
    got = await rec_b.wait_for_bytes(len(PAYLOAD))
    assert len(got) == len(PAYLOAD)
    assert all(bin(x ^ y).count("1") == 1 for x, y in zip(got, PAYLOAD, strict=True))
    assert a.bytes_corrupted == len(PAYLOAD)
    await a.close()
    await b.close()


async def test_delayed_delivery_waits_and_keeps_order() -> None:
    """With a delay, nothing arrives early and many writes still arrive in order."""
    delay_s = 0.05
    a, _, b, rec_b = pair(LinkFaults(delay_s=delay_s, one_byte_at_a_time=True))
    loop = asyncio.get_running_loop()
    start = loop.time()
    a.write(PAYLOAD[:300])
    await settle(delay_s / 2)
    assert rec_b.chunks == []
    assert await rec_b.wait_for_bytes(300) == PAYLOAD[:300]
    assert loop.time() - start >= delay_s
    await a.close()
    await b.close()


async def test_break_link_makes_both_ends_see_one_transport_error() -> None:
    """A cut wire: both ends get on_lost(TransportError) once, in-flight bytes are dropped."""
    a, rec_a, b, rec_b = pair(LinkFaults(delay_s=0.01))
    a.write(b"in flight")
    a.break_link()
    assert not a.is_open
    assert not b.is_open
    with pytest.raises(TransportError):
        a.write(b"x")
    with pytest.raises(TransportError):
        b.write(b"x")
    await rec_a.wait_for_lost()
    await rec_b.wait_for_lost()
    await settle(0.03)
    assert rec_b.chunks == []
    for rec, end in ((rec_a, a), (rec_b, b)):
        assert len(rec.lost) == 1
        error = rec.lost[0]
        assert isinstance(error, TransportError)
        assert error.url == end.url
    await a.close()
    await b.close()
    assert len(rec_a.lost) == len(rec_b.lost) == 1


async def test_close_reaches_the_peer_after_the_bytes_in_flight() -> None:
    """Closing one end: it sees None; the peer gets the last bytes, then 'closed by peer'."""
    a, rec_a, b, rec_b = pair()
    a.write(b"bye")
    await a.close()
    assert rec_a.lost == [None]
    error = await rec_b.wait_for_lost()
    assert rec_b.data == b"bye"
    assert isinstance(error, TransportError)
    assert "closed by peer" in str(error)
    await b.close()
    assert len(rec_b.lost) == 1


async def test_discard_output_drops_bytes_not_yet_delivered() -> None:
    """discard_output drops what is still in flight; later writes go through."""
    a, _, b, rec_b = pair(LinkFaults(delay_s=0.01))
    a.write(b"stale")
    a.discard_output()
    a.write(b"fresh")
    assert await rec_b.wait_for_bytes(5) == b"fresh"
    await settle(0.02)
    assert rec_b.data == b"fresh"
    await a.close()
    await b.close()


async def test_invalid_fault_rates_are_rejected() -> None:
    """A rate outside 0..1 or a negative delay is a configuration error, not a silent no-op."""
    with pytest.raises(ValueError, match="loss_rate"):
        LinkFaults(loss_rate=1.5)
    with pytest.raises(ValueError, match="bit_flip_rate"):
        LinkFaults(bit_flip_rate=-0.1)
    with pytest.raises(ValueError, match="delay_s"):
        LinkFaults(delay_s=-1)


async def test_the_product_has_no_memory_link_kind() -> None:
    """``memory://`` is refused by the production URL parser: tests inject an opener."""
    rec = Recorder()
    with pytest.raises(ValueError, match="unsupported scheme 'memory'"):
        await open_transport("memory://board", rec.on_bytes, rec.on_lost)
