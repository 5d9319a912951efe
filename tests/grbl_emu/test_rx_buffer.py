"""The serial receive buffer: character counting never overruns it; flooding does."""

from __future__ import annotations

from dthc_tools.grbl_emu import EmulatorConfig, Flavor

from .emu_helpers import Emu


def _program(n: int) -> list[str]:
    """Short zig-zag moves: the planner fills and the parser blocks, as in a real cut."""
    return [f"G1 X{5 + (i % 2) * 3:.3f} Y{2.0 + i * 0.5:.3f} F2400" for i in range(n)]


def _stream_counting(emu: Emu, lines: list[str], rx_bytes: int) -> list[str]:
    """grbl's character-counting protocol: unanswered bytes stay below the buffer size."""
    pending: list[int] = []
    answers: list[str] = []
    queue = [line + "\n" for line in lines]
    while queue or pending:
        while queue and sum(pending) + len(queue[0]) < rx_bytes:
            pending.append(len(queue[0]))
            answers += emu.send(queue.pop(0))
        answers += emu.run(0.002)
        while len(answers) > len(lines) - len(queue) - len(pending):
            pending.pop(0)
        assert emu.t < 120.0
    return answers


def test_character_counting_never_overflows_the_rx_buffer() -> None:
    """A counting client keeps the buffer full without losing a byte: every line is ok."""
    emu = Emu()
    lines = _program(120)
    answers = _stream_counting(emu, lines, 128)
    assert answers == ["ok"] * len(lines)
    emu.run_until("Idle", 5.0)
    assert emu.position() == (5.0 + (119 % 2) * 3, 2.0 + 119 * 0.5)
    stats = emu.fw.stats
    assert stats.rx_overflow == 0
    assert stats.rx_high_water > 64  # the buffer was really used
    assert stats.planner_high_water == 15


def test_character_counting_on_grblhal_uses_its_bigger_buffer() -> None:
    """The same client against grblHAL's 1024 bytes: no loss either."""
    emu = Emu(EmulatorConfig(flavor=Flavor.GRBLHAL))
    lines = _program(200)
    assert _stream_counting(emu, lines, 1024) == ["ok"] * len(lines)
    assert emu.fw.stats.rx_overflow == 0
    assert emu.fw.stats.rx_high_water > 128


def test_flooding_a_busy_controller_loses_bytes_and_corrupts_lines() -> None:
    """Sending without counting while the planner is full overruns the buffer: bytes are
    lost (counted), and what is left of the lines is refused or runs somewhere else."""
    emu = Emu()
    lines = _program(120)
    answers = emu.send("".join(line + "\n" for line in lines))
    answers += emu.run(60.0)
    stats = emu.fw.stats
    assert stats.rx_overflow > 0
    assert stats.lines < len(lines)  # whole lines disappeared
    assert len(answers) == stats.lines


def test_realtime_bytes_never_enter_the_buffer_even_when_it_is_full() -> None:
    """``?`` is served with the buffer full; it neither takes room nor gets lost. The
    buffer holds one byte less than its size, as grbl's ring buffer does."""
    emu = Emu(EmulatorConfig(planner_blocks=1))
    emu.send("G1 X100 F600\nG1 X0\n")  # one line planned, one waiting for the planner
    fill = "G1 X1 F600 (" + "a" * 52 + ")\n" + "G1 X2 F600 (" + "b" * 47 + ")\n"
    assert len(fill) == 127
    emu.send(fill)
    assert emu.fields()["Bf"] == "0,1"
    emu.send(b"????")
    assert emu.fw.stats.rx_overflow == 0
    assert emu.fw.stats.status_reports == 5
    emu.send("G")
    assert emu.fw.stats.rx_overflow == 1


def test_bytes_arriving_one_at_a_time_give_the_same_answers() -> None:
    """A link that delivers single bytes (a slow UART, a split USB packet) changes nothing."""
    whole, trickle = Emu(), Emu()
    lines = _program(40)
    text = "".join(line + "\n" for line in lines[:5]) + "$G\n?"
    expected = whole.send(text)
    answers: list[str] = []
    for byte in text.encode():
        answers += trickle.send(bytes([byte]))
    assert answers == expected
    assert trickle.fw.stats.rx_overflow == 0
