"""Codec benchmark: ``python -m firmware_protocol.bench [--json]``.

The mix is what a board sends while cutting: mostly SAMPLES batches, with some events,
acks and status replies. Decoding is the full path from received bytes to typed messages,
fed in chunks the size of typical serial/USB reads.
"""

from __future__ import annotations

import argparse
import json
import platform
import random
import sys
import time
from collections.abc import Callable, Sequence

from .codec import encode
from .constants import DEFAULT_BATCH_SIZE, XY_SPEED_UNKNOWN
from .messages import Ack, Event, Message, Samples, Status
from .stream import StreamDecoder

__all__ = ["main", "realistic_mix", "run"]


def realistic_mix(count: int, batch_size: int = DEFAULT_BATCH_SIZE, seed: int = 1) -> list[Message]:
    """``count`` board messages: 94 % SAMPLES, 3 % ACK, 2 % EVENT, 1 % STATUS."""
    rng = random.Random(seed)
    out: list[Message] = []
    t_us = 0
    for i in range(count):
        r = rng.random()
        if r < 0.94:
            samples = tuple(12000 + rng.randrange(-300, 300) for _ in range(batch_size))
            out.append(
                Samples(0, i & 0xFFFF, t_us, 1000, 21500 + rng.randrange(-500, 500), 1,
                        i & 0xFFFF, XY_SPEED_UNKNOWN, 1, samples)
            )  # fmt: skip
            t_us = (t_us + 1000 * batch_size) & 0xFFFFFFFF
        elif r < 0.97:
            out.append(Ack(rng.randrange(1, 256), 0xC0FFEE01))
        elif r < 0.99:
            out.append(Event(0, i, t_us, 0, 1, 1, 21500))
        else:
            out.append(
                Status(rng.randrange(1, 256), 0xC0FFEE01, t_us, 0, 1, 1, 250, i, i & 0xFFFF,
                       i & 0xFFFF, 21500, 450, 0, 0, 0)
            )  # fmt: skip
    return out


def _best_rate(fn: Callable[[], int], repeats: int) -> float:
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        n = fn()
        dt = time.perf_counter() - t0
        best = max(best, n / dt)
    return best


def run(count: int = 200_000, chunk: int = 512, repeats: int = 5) -> dict[str, object]:
    msgs = realistic_mix(count)
    stream = b"".join(encode(m) for m in msgs)
    chunks = [stream[i : i + chunk] for i in range(0, len(stream), chunk)]

    def do_encode() -> int:
        for m in msgs:
            encode(m)
        return len(msgs)

    def do_decode() -> int:
        dec = StreamDecoder()
        n = 0
        feed = dec.feed
        for c in chunks:
            n += len(feed(c))
        if n != len(msgs):
            raise AssertionError(f"decoded {n} of {len(msgs)} messages")
        return n

    samples_sent = sum(len(m.samples_cv) for m in msgs if isinstance(m, Samples))
    samples_bytes = sum(len(encode(m)) for m in msgs if isinstance(m, Samples))
    return {
        "encode_msgs_per_s": round(_best_rate(do_encode, repeats)),
        "decode_msgs_per_s": round(_best_rate(do_decode, repeats)),
        "bytes_per_sample": round(samples_bytes / samples_sent, 3),
        "bytes_per_msg": round(len(stream) / len(msgs), 2),
        "batch_size": DEFAULT_BATCH_SIZE,
        "messages": len(msgs),
        "chunk_bytes": chunk,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m firmware_protocol.bench")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--count", type=int, default=200_000)
    parser.add_argument("--chunk", type=int, default=512, help="bytes per decoder feed")
    args = parser.parse_args(argv)
    result = run(args.count, args.chunk)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:>20}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
