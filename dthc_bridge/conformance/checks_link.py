"""Checks of the session and reliability rules (PROTOCOL.md §2-§4).

handshake, protocol_version, command_replies, duplicate_seq, corrupt_frames and
boot_id_reset. None of them moves Z beyond a no-op move to where it stands, and none
switches the torch on.
"""

from __future__ import annotations

import asyncio
import os
import random
import signal
import struct
from collections import Counter

from cobs.cobs import encode as cobs_encode

import firmware_protocol as fp
from firmware_protocol import Capability, NakCode, StatusBit

from ..link import LinkDown, RequestTimeout
from ..transport import TransportError
from .context import SuiteContext, mm
from .errors import describe_reply
from .options import (
    BOOT_WINDOW_S,
    HANDSHAKE_ATTEMPTS,
    HANDSHAKE_TIMEOUT_S,
    LISTEN_BEFORE_HELLO_S,
    REPLY_SETTLE_S,
    RESET_SETTLE_S,
    RESET_WAIT_S,
    SINGLE_ATTEMPT_TIMEOUT_S,
    SUITE_LEASE_MS,
)
from .rawlink import REPLY_TYPES
from .report import CheckResult, Value, failed, passed, skipped

__all__ = [
    "check_boot_id_reset",
    "check_command_replies",
    "check_corrupt_frames",
    "check_duplicate_seq",
    "check_handshake",
    "check_protocol_version",
    "validate_hello_info",
]

INTERACTIVE_RESET_WAIT_S = 60.0
RESET_POLL_S = 0.05
# After resending an executed Z_MOVE, wait this long for motion that must not happen.
DUPLICATE_MOVE_SETTLE_S = 0.3
# Over-long garbage for the resync test: more than a maximal encoded frame, no delimiter.
GARBAGE_BYTES = fp.MAX_ENCODED_FRAME + 42
# The smallest frame a host sends is 4 bytes; CONFIGURE (the largest) decodes to 20.
MIN_MAX_FRAME = 20


def _hello(seq: int, major: int = fp.PROTOCOL_MAJOR, minor: int = fp.PROTOCOL_MINOR) -> fp.Hello:
    return fp.Hello(seq, major, minor, random.getrandbits(32))


def validate_hello_info(info: fp.HelloInfo) -> list[str]:
    """What in a HELLO_INFO breaks PROTOCOL.md §6.2 (empty when every field is valid)."""
    problems = []
    if info.reset_reason not in set(fp.ResetReason):
        problems.append(f"reset_reason {info.reset_reason} is not in the table")
    if info.boot_id in (0, 0xFFFFFFFF):
        problems.append(f"boot id 0x{info.boot_id:08x} looks constant, not random")
    if any(not 0x20 <= ord(c) <= 0x7E for c in info.serial):
        problems.append(f"serial {info.serial!r} is not printable ASCII")
    if not 100 <= info.sample_rate_hz <= 20_000:
        problems.append(f"sample_rate_hz {info.sample_rate_hz} outside 100..20000")
    if not 1 <= info.batch_size <= fp.MAX_BATCH_SIZE:
        problems.append(f"batch_size {info.batch_size} outside 1..{fp.MAX_BATCH_SIZE}")
    if info.z_min_um >= info.z_max_um:
        problems.append(f"Z limits {mm(info.z_min_um)}..{mm(info.z_max_um)} mm are empty")
    if not MIN_MAX_FRAME <= info.max_frame <= fp.MAX_FRAME:
        problems.append(f"max_frame {info.max_frame} outside {MIN_MAX_FRAME}..{fp.MAX_FRAME}")
    if not fp.LEASE_MIN_MS <= info.lease_ms <= fp.LEASE_MAX_MS:
        problems.append(f"lease_ms {info.lease_ms} outside {fp.LEASE_MIN_MS}..{fp.LEASE_MAX_MS}")
    return problems


def capability_names(capabilities: int) -> str:
    names = [c.name for c in Capability if c.name is not None and capabilities & c]
    return ",".join(names) or "none"


async def check_handshake(ctx: SuiteContext) -> list[CheckResult]:
    """HELLO is answered by a valid HELLO_INFO; the board streams SAMPLES from power-on."""
    link = ctx.link
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    mark = link.mark()
    # Not a byte before the board speaks: it may be in its bootloader (BOOT_WINDOW_S).
    await link.wait_for(lambda _msg: True, BOOT_WINDOW_S, since=mark)
    await asyncio.sleep(LISTEN_BEFORE_HELLO_S)
    batches_before = len(link.messages(fp.Samples, since=mark))
    link.write(b"\x00")  # ends any partial frame the board holds
    try:
        reply = await link.request(
            _hello(link.next_seq()),
            timeout_s=HANDSHAKE_TIMEOUT_S,
            attempts=HANDSHAKE_ATTEMPTS,
            accepts=(fp.HelloInfo, fp.Nak),
        )
    except RequestTimeout:
        s = link.decoder.stats
        figure = (
            f"no HELLO_INFO after {HANDSHAKE_ATTEMPTS} attempts: {s.frames_ok} valid frames, "
            f"{s.crc_errors} CRC errors, {s.framing_errors} framing errors, "
            f"{s.bytes_in} bytes in {loop.time() - t0:.1f} s"
        )
        if s.crc_errors and not s.frames_ok:
            hint = (
                "every frame from the board failed its CRC: the frame CRC must be "
                "CRC-16/CCITT-FALSE (check value 0x29B1), sent high byte first"
            )
        elif not s.bytes_in:
            hint = "nothing arrived from the board: check the cable, the port and the baud rate"
        else:
            hint = "the board sends valid frames but does not answer HELLO"
        return [failed("handshake", figure, hint=hint, values=dict(s.as_dict()))]
    if not isinstance(reply, fp.HelloInfo):
        return [failed("handshake", f"HELLO answered with {describe_reply(reply)}")]
    ctx.info = reply
    problems = validate_hello_info(reply)
    if not batches_before:
        problems.append("no SAMPLES before HELLO (a board streams from power-on)")
    if reply.proto_major == fp.PROTOCOL_MAJOR:
        status = await ctx.status()
        if not status.status & StatusBit.SESSION:
            problems.append("STATUS after HELLO does not show a session")
        if status.boot_id != reply.boot_id:
            problems.append("STATUS boot id differs from HELLO_INFO's")
        ctx.session_open = True
    values: dict[str, Value] = {
        "serial": reply.serial,
        "boot_id": f"{reply.boot_id:08x}",
        "protocol": f"{reply.proto_major}.{reply.proto_minor}",
        "firmware": f"{reply.fw_major}.{reply.fw_minor}.{reply.fw_patch}",
        "reset_reason": reply.reset_reason,
        "sample_rate_hz": reply.sample_rate_hz,
        "batch_size": reply.batch_size,
        "lease_ms": reply.lease_ms,
        "max_frame": reply.max_frame,
        "capabilities": capability_names(reply.capabilities),
        "batches_before_hello": batches_before,
    }
    figure = (
        f"serial {reply.serial!r}, firmware {values['firmware']}, boot id {values['boot_id']}, "
        f"{reply.sample_rate_hz} Hz x {reply.batch_size}, lease {reply.lease_ms} ms, "
        f"Z {mm(reply.z_min_um)}..{mm(reply.z_max_um)} mm"
    )
    if problems:
        return [failed("handshake", "; ".join(problems), values=values)]
    return [passed("handshake", figure, values=values)]


async def check_protocol_version(ctx: SuiteContext) -> list[CheckResult]:
    """Same major version; a HELLO of another major is still answered with HELLO_INFO."""
    info = ctx.require_info()
    link = ctx.link
    board = f"{info.proto_major}.{info.proto_minor}"
    host = f"{fp.PROTOCOL_MAJOR}.{fp.PROTOCOL_MINOR}"
    values: dict[str, Value] = {"board": board, "host": host}
    if info.proto_major != fp.PROTOCOL_MAJOR:
        return [
            failed(
                "protocol_version",
                f"board speaks protocol {board}, this host {host}: majors differ",
                hint="update the firmware or dthc-bridge so both speak the same major version",
                values=values,
            )
        ]
    foreign = fp.PROTOCOL_MAJOR + 1
    reply = await link.request(_hello(link.next_seq(), foreign, 0), accepts=(fp.HelloInfo, fp.Nak))
    problems = []
    if not isinstance(reply, fp.HelloInfo):
        problems.append(f"HELLO {foreign}.0 answered with {describe_reply(reply)}, not HELLO_INFO")
    elif reply.proto_major != info.proto_major:
        problems.append(f"HELLO_INFO to HELLO {foreign}.0 claims protocol {reply.proto_major}")
    # Open the session again (a foreign HELLO leaves none); it also clears duplicate memory.
    again = await link.request(_hello(link.next_seq()), accepts=(fp.HelloInfo, fp.Nak))
    ctx.session_open = isinstance(again, fp.HelloInfo) and again.proto_major == info.proto_major
    if not isinstance(again, fp.HelloInfo) or again.boot_id != info.boot_id:
        problems.append(f"second HELLO answered with {describe_reply(again)}")
    elif not (await ctx.status()).status & StatusBit.SESSION:
        problems.append("no session after a second HELLO")
    if problems:
        return [failed("protocol_version", "; ".join(problems), values=values)]
    figure = f"board {board}, host {host}; HELLO {foreign}.0 answered with HELLO_INFO {board}"
    return [passed("protocol_version", figure, values=values)]


async def check_command_replies(ctx: SuiteContext) -> list[CheckResult]:
    """Every sequenced command gets exactly one reply with its seq: the one §6.1 names."""
    link = ctx.link
    info = ctx.require_info()
    status = await ctx.status()
    window = ctx.require_window()
    ohmic = ctx.capable(Capability.OHMIC)
    current = ctx.capable(Capability.CURRENT_OUT)
    here_um = window.check(min(max(status.z_um, window.low_um), window.high_um))
    ack, nak_range = "ACK", "NAK OUT_OF_RANGE"
    # Without the capability a board may refuse (NAK UNSUPPORTED) or accept a harmless "off".
    maybe = "ACK or NAK UNSUPPORTED"
    plan: list[tuple[fp.Message, str]] = [
        (fp.Heartbeat(0), ack),
        (fp.SetLease(0, SUITE_LEASE_MS), ack),
        (fp.SetLease(0, fp.LEASE_MIN_MS - 1), nak_range),
        (fp.Torch(0, False), ack),
        (fp.OhmicSense(0, False), ack if ohmic else maybe),
        (fp.SetCurrent(0, status.current_da), ack if current else maybe),
        (fp.Configure(0, 0, info.batch_size, 0, 0, 0, 0, 0.01), nak_range),
        (fp.ZStop(0), ack),
        (fp.ZMove(0, here_um, ctx.feed_um_s), ack),
        (fp.FaultReset(0, 0), ack),
        (fp.Query(0, fp.QueryWhat.STATUS), "STATUS"),
        (fp.Query(0, fp.QueryWhat.HELLO_INFO), "HELLO_INFO"),
        (fp.ClockQuery(0), "CLOCK"),
    ]
    mark = link.mark()
    loop = asyncio.get_running_loop()
    problems: list[str] = []
    rtts: list[float] = []
    sent: list[tuple[int, str]] = []
    move_seq = 0
    for planned, expected in plan:
        name = fp.message_type(planned).name
        command = planned._replace(seq=link.next_seq())
        t = loop.time()
        try:
            reply = await link.request(command, timeout_s=SINGLE_ATTEMPT_TIMEOUT_S, attempts=1)
        except RequestTimeout:
            problems.append(f"{name}: no reply within {SINGLE_ATTEMPT_TIMEOUT_S} s")
            continue
        rtts.append((loop.time() - t) * 1e3)
        sent.append((command.seq, name))
        got = describe_reply(reply).split(" (")[0]
        if got not in expected.split(" or "):
            problems.append(f"{name}: {describe_reply(reply)}, expected {expected}")
        if isinstance(reply, fp.Ack | fp.Nak | fp.Status) and reply.boot_id != info.boot_id:
            problems.append(f"{name}: reply carries boot id {reply.boot_id:08x}")
        if isinstance(command, fp.ZMove):
            move_seq = command.seq
    # The no-op move ends with MOTION_DONE; QUERY(MOTION_DONE) then re-sends it.
    done = await link.wait_for_type(
        fp.MotionDone, 2.0, since=mark, where=lambda m: m.seq == move_seq
    )
    if done is None:
        problems.append("Z_MOVE: no MOTION_DONE")
    else:
        query = fp.Query(link.next_seq(), fp.QueryWhat.MOTION_DONE)
        again = await link.request(
            query, timeout_s=SINGLE_ATTEMPT_TIMEOUT_S, attempts=1, accepts=(fp.MotionDone, fp.Nak)
        )
        sent.append((query.seq, "QUERY(MOTION_DONE)"))
        if not isinstance(again, fp.MotionDone) or again.result != done[1].result:
            problems.append(f"QUERY(MOTION_DONE): {describe_reply(again)}")
    await asyncio.sleep(REPLY_SETTLE_S)
    replies = Counter(
        r.msg.seq
        for r in link.since(mark)
        if isinstance(r.msg, (*REPLY_TYPES, fp.MotionDone)) and r.msg.seq
    )
    for seq, name in sent:
        expected_count = 2 if seq == move_seq else 1  # ACK, then MOTION_DONE
        if replies[seq] != expected_count:
            problems.append(f"{name}: {replies[seq]} replies with its seq")
    values: dict[str, Value] = {
        "commands": len(sent),
        "reply_ms_max": round(max(rtts), 3) if rtts else None,
        "reply_ms_median": round(sorted(rtts)[len(rtts) // 2], 3) if rtts else None,
    }
    if problems:
        return [failed("command_replies", "; ".join(problems), values=values)]
    figure = (
        f"{len(sent)} commands, each answered once with its seq as §6.1 says; "
        f"round trip median {values['reply_ms_median']} ms, max {values['reply_ms_max']} ms"
    )
    return [passed("command_replies", figure, values=values)]


async def check_duplicate_seq(ctx: SuiteContext) -> list[CheckResult]:
    """A retransmitted seq is answered again with the remembered reply and not re-executed."""
    link = ctx.link
    before = await ctx.status()
    problems: list[str] = []
    values: dict[str, Value] = {}
    # A command whose repetition would show, then one that undoes it, then the first again.
    if ctx.capable(Capability.OHMIC):
        what = "OHMIC_SENSE on"
        first: fp.Message = fp.OhmicSense(link.next_seq(), True)
        await ctx.expect_ack(first, once=True)
        await ctx.expect_ack(fp.OhmicSense(link.next_seq(), False), once=True)
    else:
        what = "Z_MOVE up 0.5 mm"
        here_um = before.z_um
        first = fp.ZMove(link.next_seq(), ctx.require_window().check(here_um + 500), ctx.feed_um_s)
        await ctx.move_z(first.target_um, seq=first.seq)
        await ctx.move_z(here_um)
    mark = link.mark()
    reply = (await link.exchange(fp.encode(first), first, SINGLE_ATTEMPT_TIMEOUT_S, 1)).msg
    if not isinstance(reply, fp.Ack):
        problems.append(f"resent {what}: {describe_reply(reply)}, expected the remembered ACK")
    if isinstance(first, fp.OhmicSense):
        after = await ctx.status()
        values["ohmic_sense_after"] = bool(after.status & StatusBit.OHMIC_SENSE)
        if after.status & StatusBit.OHMIC_SENSE:
            problems.append("resent OHMIC_SENSE on was executed again: ohmic sense is on")
            await ctx.expect_ack(fp.OhmicSense(0, False))
    else:
        await asyncio.sleep(DUPLICATE_MOVE_SETTLE_S)
        after = await ctx.status()
        moved_um = after.z_um - before.z_um
        values["z_moved_um"] = moved_um
        if abs(moved_um) > 50 or link.messages(fp.MotionDone, since=mark):
            problems.append(f"resent Z_MOVE was executed again: Z moved {mm(moved_um)} mm")
            await ctx.move_z(before.z_um)
    # A NAK is remembered too: resend a refused SET_LEASE.
    refused = fp.SetLease(link.next_seq(), fp.LEASE_MIN_MS - 1)
    nak = await link.request(refused, timeout_s=SINGLE_ATTEMPT_TIMEOUT_S, attempts=1)
    nak_again = (await link.exchange(fp.encode(refused), refused, SINGLE_ATTEMPT_TIMEOUT_S, 1)).msg
    if not (isinstance(nak, fp.Nak) and nak_again == nak):
        problems.append(
            f"resent refused SET_LEASE: {describe_reply(nak_again)} "
            f"after {describe_reply(nak)}, expected the same NAK"
        )
    final = await ctx.status()
    counted = (final.rx_duplicates - before.rx_duplicates) & 0xFFFF
    values["rx_duplicates_delta"] = counted
    values["action"] = what
    if counted != 2:
        problems.append(f"STATUS.rx_duplicates rose by {counted}, expected 2")
    if problems:
        return [failed("duplicate_seq", "; ".join(problems), values=values)]
    figure = (
        f"resent {what} re-acknowledged and not executed again; resent NAK repeated; "
        f"rx_duplicates +{counted}"
    )
    return [passed("duplicate_seq", figure, values=values)]


def _bad_crc_frame(body: bytes) -> bytes:
    """A frame with ``body`` and a wrong CRC (fp.encode_frame makes the right one)."""
    frame = bytearray(body + struct.pack(">H", fp.crc16(body)))
    frame[-1] ^= 0x5A
    return bytes(cobs_encode(bytes(frame))) + b"\x00"


async def check_corrupt_frames(ctx: SuiteContext) -> list[CheckResult]:
    """Corrupt and malformed frames are dropped and counted; the board stays in sync."""
    link = ctx.link
    before = await ctx.status()
    problems: list[str] = []
    mark = link.mark()
    # 1. OHMIC_SENSE on with a wrong CRC: no reply, not executed.
    bad_crc_seq = link.next_seq()
    link.write(_bad_crc_frame(bytes((fp.MsgType.OHMIC_SENSE, bad_crc_seq, 1))))
    # 2. Invalid COBS (a code byte pointing past the frame end) and 3. a 2-byte frame.
    link.write(b"\x05\x01\x02\x00")
    link.write(b"\x02\x01\x00")  # decodes to one byte: shorter than any frame
    # 4. Over-long garbage without a delimiter, then the delimiter that ends the discard.
    rng = random.Random(7)
    link.write(bytes(rng.randrange(1, 256) for _ in range(GARBAGE_BYTES)) + b"\x00")
    # 5. Valid CRC, unknown type; 6. valid CRC, TORCH with a 2-byte payload (saying "off").
    unknown = fp.Heartbeat(link.next_seq())
    unknown_reply = await _nak_for(ctx, fp.encode_frame(bytes((0x7E, unknown.seq))), unknown)
    torch = fp.Torch(link.next_seq(), False)
    torch_reply = await _nak_for(
        ctx, fp.encode_frame(bytes((fp.MsgType.TORCH, torch.seq, 0, 0))), torch
    )
    after = await ctx.status()  # in sync: a valid query right after is answered
    crc_delta = (after.rx_crc_errors - before.rx_crc_errors) & 0xFFFF
    framing_delta = (after.rx_framing_errors - before.rx_framing_errors) & 0xFFFF
    if any(r.msg.seq == bad_crc_seq for r in link.since(mark) if isinstance(r.msg, fp.Ack)):
        problems.append("a frame with a wrong CRC was acknowledged")
    if after.status & StatusBit.OHMIC_SENSE:
        problems.append("a frame with a wrong CRC was executed (ohmic sense on)")
        await ctx.expect_ack(fp.OhmicSense(0, False))
    if unknown_reply != f"NAK {NakCode.UNKNOWN_TYPE.name}":
        problems.append(f"unknown type 0x7E: {unknown_reply}, expected NAK UNKNOWN_TYPE")
    if torch_reply != f"NAK {NakCode.BAD_LENGTH.name}":
        problems.append(f"TORCH with 2 payload bytes: {torch_reply}, expected NAK BAD_LENGTH")
    if crc_delta < 1:
        problems.append(f"rx_crc_errors rose by {crc_delta}, expected 1")
    if framing_delta < 3:
        problems.append(f"rx_framing_errors rose by {framing_delta}, expected at least 3")
    values: dict[str, Value] = {
        "rx_crc_errors_delta": crc_delta,
        "rx_framing_errors_delta": framing_delta,
    }
    if problems:
        return [failed("corrupt_frames", "; ".join(problems), values=values)]
    figure = (
        f"bad CRC, bad COBS, short and {GARBAGE_BYTES}-byte frames dropped "
        f"(CRC errors +{crc_delta}, framing errors +{framing_delta}); "
        "unknown type and bad length NAKed; in sync"
    )
    return [passed("corrupt_frames", figure, values=values)]


async def _nak_for(ctx: SuiteContext, frame: bytes, msg: fp.Message) -> str:
    try:
        received = await ctx.link.exchange(frame, msg, attempts=2)
    except RequestTimeout:
        return "no reply"
    return describe_reply(received.msg).split(" (")[0]


async def check_boot_id_reset(ctx: SuiteContext) -> list[CheckResult]:
    """After a reset the board has a new boot id, no session and the torch off."""
    info = ctx.require_info()
    link = ctx.link
    opts = ctx.options
    if opts.reset_signal_pid is not None:
        how = f"SIGUSR2 to process {opts.reset_signal_pid}"
        wait_s = RESET_WAIT_S
    elif opts.interactive and ctx.operator is not None:
        how = "reset button"
        wait_s = INTERACTIVE_RESET_WAIT_S
    else:
        return [
            skipped(
                "boot_id_reset",
                "skipped: no way to reset the board",
                hint="pass --reset-signal-pid PID (the mock board) or run with --interactive "
                "and press the board's reset button when asked",
            )
        ]
    await link.stop_keepalive()
    ctx.session_open = False
    if opts.reset_signal_pid is not None:
        try:
            os.kill(opts.reset_signal_pid, signal.SIGUSR2)
        except OSError as exc:
            return [failed("boot_id_reset", f"cannot signal {opts.reset_signal_pid}: {exc}")]
    else:
        assert ctx.operator is not None
        ctx.operator.tell(f"Press the board's reset button now (waiting up to {wait_s:.0f} s).")
    new = await _wait_new_boot(ctx, info.boot_id, wait_s)
    values: dict[str, Value] = {"old_boot_id": f"{info.boot_id:08x}", "how": how}
    if new is None:
        return [
            failed(
                "boot_id_reset",
                f"boot id still {info.boot_id:08x} {wait_s:.0f} s after the reset ({how})",
                hint="a board must pick a fresh random boot id at every start",
                values=values,
            )
        ]
    values["new_boot_id"] = f"{new.boot_id:08x}"
    problems = validate_hello_info(new)
    if new.boot_id == info.boot_id:
        problems.append("same boot id")
    heartbeat = await link.request(fp.Heartbeat(0))
    if not (isinstance(heartbeat, fp.Nak) and heartbeat.code == NakCode.NO_SESSION):
        problems.append(f"HEARTBEAT after reset: {describe_reply(heartbeat)}, not NAK NO_SESSION")
    status = await ctx.status()
    if status.status & (StatusBit.TORCH_ON | StatusBit.SESSION):
        problems.append("torch on or a session open after the reset")
    if problems:
        return [failed("boot_id_reset", "; ".join(problems), values=values)]
    reason = _reset_reason(new.reset_reason)
    figure = (
        f"boot id {info.boot_id:08x} -> {new.boot_id:08x} after {how} "
        f"(reset reason {reason}); no session, torch off"
    )
    return [passed("boot_id_reset", figure, values=values)]


def _reset_reason(code: int) -> str:
    try:
        return fp.ResetReason(code).name
    except ValueError:
        return str(code)


async def _wait_new_boot(ctx: SuiteContext, old: int, wait_s: float) -> fp.HelloInfo | None:
    """Poll QUERY(HELLO_INFO) (allowed without a session) until the boot id changes;
    reopen the link if the reset took the port away (USB re-enumeration). Each query waits
    for a frame from the board since the last one: a board in its bootloader is silent, and
    a byte sent to it then keeps it there (BOOT_WINDOW_S)."""
    link = ctx.link
    loop = asyncio.get_running_loop()
    deadline = loop.time() + wait_s
    await asyncio.sleep(RESET_SETTLE_S)
    mark = link.mark()
    while loop.time() < deadline:
        try:
            if link.lost_reason is not None:
                await link.close()
                await link.open()
                mark = link.mark()
            heard = await link.wait_for(lambda _msg: True, deadline - loop.time(), since=mark)
            if heard is None:
                break
            mark = link.mark()
            reply = await link.request(fp.Query(0, fp.QueryWhat.HELLO_INFO), attempts=1)
            if isinstance(reply, fp.HelloInfo) and reply.boot_id != old:
                return reply
        except (RequestTimeout, LinkDown, TransportError):
            pass  # the port may be gone while the board restarts: keep trying
        await asyncio.sleep(RESET_POLL_S)
    return None
