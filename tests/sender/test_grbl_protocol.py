"""grbl's protocol as the backend reads and writes it, without a port."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dthc_tools.sender.grbl_backend import anti_dive_speed
from dthc_tools.sender.grbl_protocol import (
    CharCounter,
    FirmwareInfo,
    LineRefused,
    SpeedMeter,
    error_text,
    for_grbl,
    parse_status,
)


def test_a_classic_status_report_reads_by_field_name() -> None:
    report = parse_status("<Run|MPos:10.000,-2.500,0.000|Bf:12,101|FS:1500,0|Ov:100,100,100>")
    assert report.state == "Run"
    assert report.mpos == (10.0, -2.5, 0.0)
    assert (report.planner_free, report.rx_free) == (12, 101)
    assert report.feed == 1500.0
    assert report.overrides == (100, 100, 100)


def test_hold_substates_and_unknown_grblhal_fields() -> None:
    report = parse_status("<Hold:1|MPos:1.000,2.000,3.000|FS:0,0|A:F|TLR:0|Pn:P>")
    assert (report.state, report.substate, report.hold_complete) == ("Hold", 1, False)
    assert report.other == {"A": "F", "TLR": "0", "Pn": "P"}
    assert parse_status("<Hold:0|MPos:0,0,0>").hold_complete


def test_work_position_from_wpos_or_mpos_minus_the_last_wco() -> None:
    with_wco = parse_status("<Idle|MPos:110.000,220.000,0.000|WCO:100.000,200.000,0.000>")
    assert with_wco.work_position(None) == (10.0, 20.0, 0.0)
    later = parse_status("<Idle|MPos:111.000,221.000,0.000>")  # WCO comes every few reports
    assert later.work_position(with_wco.wco) == (11.0, 21.0, 0.0)
    wpos = parse_status("<Run|WPos:5.000,6.000,0.000|F:900>")
    assert wpos.work_position(None) == (5.0, 6.0, 0.0)
    assert wpos.feed == 900.0


@pytest.mark.parametrize(
    "text", ["Run|MPos:1,2,3", "<|MPos:1,2>", "<Run|MPos:1,x,3>", "<Run|MPos:nan,1,2>"]
)
def test_a_bad_status_report_is_refused_by_name(text: str) -> None:
    with pytest.raises(ValueError, match=r"status|MPos"):
        parse_status(text)


def test_dollar_i_tells_the_planner_and_the_receive_buffer() -> None:
    classic = FirmwareInfo(banner="Grbl 1.1f ['$' for help]")
    for line in ("[VER:1.1f.20170801:]", "[OPT:V,15,128]"):
        classic.read(line)
    assert (classic.version, classic.planner_blocks, classic.rx_buffer) == (
        "1.1f.20170801",
        15,
        128,
    )
    assert classic.line_limit == 80
    hal = FirmwareInfo(banner="GrblHAL 1.1f ['$' or '$HELP' for help]")
    for line in ("[VER:1.1f.20260801:]", "[OPT:VNML+,35,1024,3,0]", "[FIRMWARE:grblHAL]"):
        hal.read(line)
    assert (hal.planner_blocks, hal.rx_buffer, hal.is_grblhal, hal.line_limit) == (
        35,
        1024,
        True,
        256,
    )


def test_lines_for_grbl_lose_comments_and_spaces_but_never_keep_z_or_the_torch() -> None:
    assert for_grbl("g1 x10.5 y-2 f1500 (cut)") == "G1X10.5Y-2F1500"
    assert for_grbl("G2 X10 Y0 I5 J0 ; arc") == "G2X10Y0I5J0"
    assert for_grbl("(only a comment)") == ""
    for bad, word in (("G0 X1 Z5", "Z words"), ("M3 S1000", "M3"), ("G1 X1 S300", "S300"),
                      ("M05", "M05")):  # fmt: skip
        with pytest.raises(LineRefused, match=word):
            for_grbl(bad)


def test_character_counting_keeps_the_receive_buffer_from_overflowing() -> None:
    counter = CharCounter(128)
    sizes = [len("G1X100.000Y200.000F1500") + 1] * 10
    in_flight: list[int] = []
    for size in sizes:
        while not counter.fits(size):
            counter.acknowledged()
            in_flight.pop(0)
        counter.sent(size)
        in_flight.append(size)
        assert counter.used == sum(in_flight) < 128
    assert len(counter) == len(in_flight) == 5


@given(st.lists(st.integers(1, 80), min_size=1, max_size=60), st.integers(0, 9))
def test_counting_never_exceeds_the_buffer(sizes: list[int], acks_every: int) -> None:
    counter = CharCounter(128)
    for n, size in enumerate(sizes):
        if acks_every and n % acks_every == 0:
            counter.acknowledged()
        while not counter.fits(size):
            counter.acknowledged()
        counter.sent(size)
        assert 0 < counter.used < 128


def test_speed_is_measured_over_the_window_not_a_single_report() -> None:
    meter = SpeedMeter(window_s=0.1)
    assert meter.add(0.00, 0.0, 0.0) is None
    assert meter.add(0.05, 1.25, 0.0) is None  # 50 ms: not yet a window
    assert meter.add(0.10, 2.5, 0.0) == pytest.approx(25.0)
    assert meter.add(0.15, 3.75, 0.0) == pytest.approx(25.0)


def test_the_anti_dive_sees_zero_when_held_and_the_lower_of_measured_and_fs() -> None:
    assert anti_dive_speed(parse_status("<Hold:1|MPos:0,0,0|FS:1500,0>"), 20.0) == 0.0
    assert anti_dive_speed(parse_status("<Hold:0|MPos:0,0,0|FS:1500,0>"), 0.0) == 0.0
    assert anti_dive_speed(parse_status("<Idle|MPos:0,0,0|FS:0,0>"), None) == 0.0
    corner = parse_status("<Run|MPos:0,0,0|FS:600,0>")  # FS falls first at a corner
    assert anti_dive_speed(corner, 24.0) == pytest.approx(10.0)
    assert anti_dive_speed(parse_status("<Run|MPos:0,0,0|FS:1500,0>"), 12.0) == 12.0
    assert anti_dive_speed(parse_status("<Run|MPos:0,0,0>"), None) is None


def test_error_codes_read_as_words() -> None:
    assert "feed" in error_text(22)
    assert error_text(999) == "an error the firmware did not document"


def test_linuxcnc_only_modal_words_posts_write_are_dropped_not_refused_by_grbl() -> None:
    """A PlasmaC/SheetCam preamble's G97, G64 P Q, M52 P1: grbl 1.1 answers error:20,
    and neither changes what XY does; a P that belongs to another G on the line stays."""
    assert for_grbl("N10 G20 G40 G90 G94 G97 G92.1") == "N10G20G40G90G94G92.1"
    assert for_grbl("N60 G64 P0.01 Q0.001") == ""  # nothing left for grbl
    assert for_grbl("G64") == ""
    assert for_grbl("G4 G64 P0.5") == "G4P0.5"
    assert for_grbl("N20 M52 P1") == ""  # adaptive feed: grbl has none
    assert for_grbl("G43 H0") == ""  # a tool length offset: Z is the board's
    assert for_grbl("G90 G1 X5 F100") == "G90G1X5F100"
