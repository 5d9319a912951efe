"""The grbl port's receiver splits a sender's bytes as grbl 1.1 does: real-time bytes at
once wherever they fall, one line per LF or CR, control characters dropped, an overlong
line flagged and not cut into two."""

from __future__ import annotations

from dthc_tools.grbl_port.receiver import Line, RealTime, Receiver


def test_real_time_bytes_are_taken_out_of_a_line_and_come_first() -> None:
    receiver = Receiver()
    assert receiver.feed(b"G1 X1?0 F") == [RealTime(ord("?"))]
    assert receiver.feed(b"100!\n") == [RealTime(ord("!")), Line("G1 X10 F100")]
    assert receiver.feed(b"\x91\x18~") == [RealTime(0x91), RealTime(0x18), RealTime(ord("~"))]


def test_each_line_end_is_one_line_and_control_characters_are_dropped() -> None:
    receiver = Receiver()
    assert receiver.feed(b"M3\r\nG4\x07 P1\n") == [Line("M3"), Line(""), Line("G4 P1")]


def test_an_overlong_line_is_flagged_whole_and_the_next_one_is_whole_again() -> None:
    receiver = Receiver(max_line_bytes=8)
    out = receiver.feed(b"G1 X123456789 Y1\nM5\n")
    assert out == [Line("G1 X1234", overflow=True), Line("M5")]


def test_a_reset_drops_a_partly_received_line() -> None:
    receiver = Receiver()
    receiver.feed(b"G1 X10")
    receiver.reset()
    assert receiver.feed(b"M5\n") == [Line("M5")]
