"""Hypothesis strategies that build any valid protocol message from the layout table."""

from __future__ import annotations

from typing import Any

from hypothesis import strategies as st

from firmware_protocol import LAYOUTS, Message, Samples
from firmware_protocol.codec import _SAMPLES_OFFSET
from firmware_protocol.constants import MAX_FRAME

_CODE: dict[str, st.SearchStrategy[Any]] = {
    "B": st.integers(0, 0xFF),
    "H": st.integers(0, 0xFFFF),
    "I": st.integers(0, 0xFFFFFFFF),
    "i": st.integers(-(2**31), 2**31 - 1),
    "Q": st.integers(0, 2**64 - 1),
    "?": st.booleans(),
    "f": st.floats(width=32, allow_nan=False),
    "16s": st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=16),
}

MAX_SAMPLES = (MAX_FRAME - 2 - _SAMPLES_OFFSET) // 2


def _codes(fmt: str) -> list[str]:
    return ["16s" if c == "s" else c for c in fmt.replace("16s", "s")]


def message_strategy(cls: type[Any]) -> st.SearchStrategy[Message]:
    _, fmt = LAYOUTS[cls]
    parts = [st.integers(0, 0xFF)] + [_CODE[c] for c in _codes(fmt)]
    if cls is Samples:
        parts.append(st.lists(st.integers(0, 0xFFFF), max_size=MAX_SAMPLES).map(tuple))
    return st.tuples(*parts).map(lambda values: cls(*values))


any_message: st.SearchStrategy[Message] = st.one_of([message_strategy(c) for c in LAYOUTS])
