"""``bench fuzz``, short: mutated frames into the daemon's pty and mutated MQTT payloads
through mosquitto while it cuts; the mutations themselves, checked without processes."""

from __future__ import annotations

import argparse
import random

import pytest

import firmware_protocol as fp
from dthc_bridge.mqtt.topics import REQUEST_NAME
from dthc_tools.bench import fuzz


def test_every_frame_mutation_is_refused_by_the_decoder_and_the_tail_is_valid() -> None:
    """Only the deliberate tail (a board that restarted) decodes; everything before it is
    refused by the same decoder the daemon runs, each kind counted."""
    fuzzer = fuzz.FrameFuzzer(random.Random(5), boot_id=0x1234)
    frames = list(fuzzer.frames(3000, tail_reboots=3))
    decoder = fp.StreamDecoder()
    body = list(decoder.feed(b"".join(frames[:-3])))
    assert body == []
    assert decoder.stats.crc_errors > 0
    assert decoder.stats.unknown_type > 0
    assert decoder.stats.length_errors > 0
    tail = list(fp.StreamDecoder().feed(b"".join(frames[-3:])))
    assert [type(m).__name__ for m in tail] == ["Samples", "HelloInfo", "Ack"]
    assert all(m.boot_id != 0x1234 for m in tail if isinstance(m, fp.HelloInfo | fp.Ack))
    assert sum(fuzzer.kinds.values()) == 3000
    assert set(fuzzer.kinds) >= {"bit_flips", "truncated", "oversized", "unknown_type",
                                 "wrong_length", "garbage"}  # fmt: skip


def test_payloads_are_seeded_and_never_a_state_changing_command() -> None:
    first, second = fuzz.PayloadFuzzer(random.Random(9)), fuzz.PayloadFuzzer(random.Random(9))
    a, b = list(first.messages(500)), list(second.messages(500))
    assert a == b  # the seed reproduces the run
    assert first.skipped_valid > 0  # valid commands were drawn, and not sent
    for transaction, name in first.expected.items():
        assert REQUEST_NAME.fullmatch(name), transaction
    assert not fuzz.PayloadFuzzer._harmless("gcode", {"line": "M3"})
    assert not fuzz.PayloadFuzzer._harmless("abort", {})
    assert fuzz.PayloadFuzzer._harmless("gcode", {"line": "G1 X5 F100"})
    assert fuzz.PayloadFuzzer._harmless("torch_up", {"volts": "many"})


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_short_fuzz_run_mid_cut_keeps_every_promise() -> None:
    parser = argparse.ArgumentParser()
    fuzz.add_arguments(parser)
    args = parser.parse_args(["--frames", "3000", "--payloads", "1000", "--seed", "11"])
    result = fuzz.run(args)
    goals = result["goals"]
    assert isinstance(goals, dict)
    assert all(goal["pass"] for goal in goals.values()), goals
    assert result["daemon_alive"] is True
    assert result["responses"] == result["well_formed_requests"]
    assert isinstance(result["bytes_injected"], int)
    assert result["bytes_injected"] > 100_000  # through the mock's pty, not dropped
    assert isinstance(result["well_formed_requests"], int)
    assert result["well_formed_requests"] > 300
    # The board "restarted" at the end (the tail): the cut was ended safely, never resumed.
    program = result["program"]
    assert isinstance(program, dict)
    assert "board_rebooted" in str(program["error"])
    assert result["unsafe_torch_ms"] == 0.0
