"""A shop's own codes mapped to the daemon's (``H1=M667``): the ``[controller] codes``
table of the configuration and the runners' ``--code`` option, parsed in one place.

Beside the configuration, so reading a config file needs only the G-code tokeniser, not
the program planner or the NGC evaluator that rewrite lines with the table.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from .controller.words import GcodeSyntaxError, tokenize

__all__ = ["code_key", "parse_code_map"]


def parse_code_map(pairs: Sequence[str]) -> dict[str, str]:
    """``["H1=M667", "H0=M666"]`` → ``{"H1": "M667", "H0": "M666"}``; errors name the pair."""
    codes: dict[str, str] = {}
    for pair in pairs:
        code, sep, target = (part.strip() for part in pair.partition("="))
        if not sep or re.fullmatch(r"[A-Za-z]-?\d+(?:\.\d+)?", code) is None or not target:
            raise ValueError(f"{pair!r}: expected CODE=LINE, for example H1=M667")
        try:
            tokenize(target)
        except GcodeSyntaxError as exc:
            raise ValueError(f"{pair!r}: {exc}") from None
        codes[code_key(code[0], float(code[1:]))] = target
    return codes


def code_key(letter: str, value: float) -> str:
    """The table's key of a word: ``H1``, ``H1.5``; ``h01`` and ``H1.0`` are ``H1``."""
    return f"{letter.upper()}{value:g}"
