"""Honest logs: tracebacks under JSON, a logger name on every line, stdlib logging through the
same pipeline, and the frame trace a session dumps when a corrupt frame arrives."""

from __future__ import annotations

import asyncio
import json
import logging
from typing import Any

import pytest
import structlog

import firmware_protocol as fp
from dthc_bridge.link import BoardSession, LinkStats, LinkTiming, frametrace
from dthc_bridge.logs import configure_logging
from dthc_bridge.transport import Transport
from dthc_bridge.transport.base import BytesCallback, LostCallback
from tests.transport.memory import LinkFaults, MemoryTransport, memory_pair

LINK_LOGGER = "dthc_bridge.link"


def json_lines(capsys: pytest.CaptureFixture[str]) -> list[dict[str, Any]]:
    return [json.loads(line) for line in capsys.readouterr().err.splitlines() if line]


def raise_value_error() -> None:
    raise ValueError("torch collision at 12.5 mm")


def test_json_exception_log_carries_a_structured_traceback(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """JSON ``log.exception`` prints the exception type, message and frames, not exc_info."""
    configure_logging("info", json=True)
    log = structlog.get_logger(LINK_LOGGER)
    try:
        raise_value_error()
    except ValueError:
        log.exception("handler_failed", topic="dthc/cmd")
    [line] = json_lines(capsys)
    assert "exc_info" not in line
    assert line["event"] == "handler_failed"
    assert line["level"] == "error"
    assert line["topic"] == "dthc/cmd"
    [exception] = line["exception"]
    assert exception["exc_type"] == "ValueError"
    assert exception["exc_value"] == "torch collision at 12.5 mm"
    names = [frame["name"] for frame in exception["frames"]]
    assert names[-2:] == [
        "test_json_exception_log_carries_a_structured_traceback",
        "raise_value_error",
    ]
    assert all("locals" not in frame for frame in exception["frames"])


def test_every_json_line_names_its_structlog_logger(capsys: pytest.CaptureFixture[str]) -> None:
    """The name given to ``structlog.get_logger`` is the ``logger`` field of each line."""
    configure_logging("info", json=True)
    structlog.get_logger(LINK_LOGGER).info("link_up", port="/dev/ttyACM0")
    structlog.get_logger(LINK_LOGGER).warning("link_lost", reason="unplugged")
    structlog.get_logger("dthc_bridge.mqtt").info("mqtt_connected")
    lines = json_lines(capsys)
    assert [(line["logger"], line["event"]) for line in lines] == [
        (LINK_LOGGER, "link_up"),
        (LINK_LOGGER, "link_lost"),
        ("dthc_bridge.mqtt", "mqtt_connected"),
    ]
    assert lines[0]["port"] == "/dev/ttyACM0"


def test_stdlib_records_come_out_in_the_same_json_shape(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """An asyncio (stdlib) warning has the structlog line's fields: level, ISO UTC time, name."""
    configure_logging("info", json=True)
    structlog.get_logger(LINK_LOGGER).warning("link_lost")
    logging.getLogger("asyncio").warning("Executing %s took %.3f seconds", "<Handle>", 0.25)
    ours, foreign = json_lines(capsys)
    assert foreign.keys() == ours.keys() == {"event", "level", "logger", "timestamp"}
    assert foreign["event"] == "Executing <Handle> took 0.250 seconds"
    assert foreign["level"] == "warning"
    assert foreign["logger"] == "asyncio"
    assert foreign["timestamp"].endswith("Z")
    assert "T" in foreign["timestamp"]


def test_stdlib_exception_is_a_structured_traceback_too(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A stdlib ``logger.exception`` (the MQTT client's kind) gets the same traceback field."""
    configure_logging("info", json=True)
    try:
        raise_value_error()
    except ValueError:
        logging.getLogger("mqtt").exception("callback failed")
    [line] = json_lines(capsys)
    assert line["logger"] == "mqtt"
    assert line["level"] == "error"
    assert line["exception"][0]["exc_type"] == "ValueError"


def test_level_filter_applies_to_both_sources(capsys: pytest.CaptureFixture[str]) -> None:
    """At ``info`` structlog's and stdlib's debug calls are dropped and their info calls kept."""
    configure_logging("info", json=True)
    structlog.get_logger(LINK_LOGGER).debug("bad_frame")
    logging.getLogger("asyncio").debug("selector")
    structlog.get_logger(LINK_LOGGER).info("link_up")
    logging.getLogger("asyncio").info("connected")
    assert [line["event"] for line in json_lines(capsys)] == ["link_up", "connected"]


def test_console_mode_prints_the_traceback_and_logger_name(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """On a terminal renderer the exception's traceback follows the event line."""
    configure_logging("info", json=False)
    try:
        raise_value_error()
    except ValueError:
        structlog.get_logger(LINK_LOGGER).exception("handler_failed")
    logging.getLogger("asyncio").warning("slow callback")
    err = capsys.readouterr().err
    assert "handler_failed" in err
    assert f"[{LINK_LOGGER}]" in err
    assert "Traceback (most recent call last)" in err
    assert "in raise_value_error" in err
    assert "ValueError: torch collision at 12.5 mm" in err
    assert "[asyncio]" in err
    assert "\x1b[" not in err  # no colour codes when stderr is not a terminal


def test_configuring_twice_prints_each_event_once(capsys: pytest.CaptureFixture[str]) -> None:
    """A second configure_logging replaces the first handler instead of adding one."""
    configure_logging("info", json=False)
    configure_logging("info", json=True)
    structlog.get_logger(LINK_LOGGER).info("link_up")
    logging.getLogger("asyncio").warning("slow callback")
    assert [line["event"] for line in json_lines(capsys)] == ["link_up", "slow callback"]


# --- frame trace -----------------------------------------------------------------------------

VELOCITY_FRAMES = 40
REPLIES = 3


class Wire:
    """A BoardSession over a memory pair; the board end sends one byte per delivery."""

    def __init__(self) -> None:
        self.board: MemoryTransport | None = None

    async def opener(self, on_bytes: BytesCallback, on_lost: LostCallback) -> Transport:
        host, self.board = memory_pair(
            on_bytes, on_lost, lambda data: None, lambda exc: None,
            faults_b_to_a=LinkFaults(one_byte_at_a_time=True),
        )  # fmt: skip
        return host


async def exchange_then_corrupt(session: BoardSession, wire: Wire) -> list[tuple[str, str]]:
    """Send velocity frames, receive replies and one corrupt frame; return all frames sent."""
    assert wire.board is not None
    sent: list[tuple[str, str]] = []
    for i in range(VELOCITY_FRAMES):
        session.send_velocity(i, 50)
        sent.append(("out", fp.encode(fp.ZVelocity(0, i + 1, i, 50)).hex()))
    for seq in range(1, REPLIES + 1):
        frame = fp.encode(fp.Ack(seq, 0xB007))
        wire.board.write(frame)
        sent.append(("in", frame.hex()))
    corrupt = bytearray(fp.encode(fp.Ack(9, 0xB007)))
    corrupt[-2] ^= 0x01  # the CRC's last byte
    wire.board.write(bytes(corrupt))
    sent.append(("in", corrupt.hex()))
    for _ in range(200):
        if session.decoder.stats.crc_errors:
            break
        await asyncio.sleep(0)
    assert session.decoder.stats.crc_errors == 1
    return sent


async def test_frame_trace_dumps_only_the_last_frames_on_a_corrupt_frame(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """With trace_frames, a CRC error logs the last 32 frames in order, ending with the bad one."""
    configure_logging("info", json=True, trace_frames=True)
    wire = Wire()
    session = BoardSession("memory://board", LinkTiming(), LinkStats())
    await session.open(wire.opener)
    sent = await exchange_then_corrupt(session, wire)
    await session.close()
    [dump] = [line for line in json_lines(capsys) if line["event"] == "frame_trace"]
    assert dump["level"] == "warning"
    assert dump["logger"] == LINK_LOGGER
    assert dump["reason"] == "bad_frame"
    assert dump["url"] == "memory://board"
    assert "CRC" in dump["error"] or "crc" in dump["error"]
    frames = dump["frames"]
    assert len(frames) == frametrace.DEFAULT_CAPACITY < len(sent)
    assert [(f["dir"], f["hex"]) for f in frames] == sent[-frametrace.DEFAULT_CAPACITY :]
    assert [f["type"] for f in frames[-REPLIES - 1 :]] == ["Ack"] * REPLIES + ["!CrcMismatch"]
    assert frames[0]["type"] == "ZVelocity"
    assert [f["t_s"] for f in frames] == sorted(f["t_s"] for f in frames)


async def test_frame_trace_dumps_nothing_when_the_switch_is_off(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Without trace_frames the same corrupt frame is counted but no frames are logged."""
    configure_logging("debug", json=True)
    wire = Wire()
    session = BoardSession("memory://board", LinkTiming(), LinkStats())
    await session.open(wire.opener)
    await exchange_then_corrupt(session, wire)
    await session.close()
    events = [line["event"] for line in json_lines(capsys)]
    assert "bad_frame" in events  # the error was seen and logged at debug
    assert "frame_trace" not in events


def test_frame_trace_forgets_frames_once_dumped() -> None:
    """Each frame appears in one dump only: a burst of errors does not repeat the history."""
    trace = frametrace.FrameTrace(capacity=4)
    trace.record_out(fp.encode(fp.Heartbeat(1)))
    trace.record_in(fp.encode(fp.Ack(1, 7))[:3])  # a frame split across deliveries
    assert len(trace) == 1
    trace.record_in(fp.encode(fp.Ack(1, 7))[3:])
    dumps: list[dict[str, Any]] = []

    class Recorder:
        def warning(self, event: str, *args: Any, **kw: Any) -> None:
            dumps.append({"event": event, **kw})

    trace.dump(Recorder(), "bad_frame")
    trace.dump(Recorder(), "bad_frame")
    assert [[f["type"] for f in d["frames"]] for d in dumps] == [["Heartbeat", "Ack"], []]
