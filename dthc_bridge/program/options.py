"""The command-line options every program runner shares (check-program, send, demo)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..code_map import parse_code_map
from ..controller.dialect import Dialect

__all__ = ["add_daemon_options", "add_dialect_options"]


def _dialect(text: str) -> Dialect:
    try:
        return Dialect(text)
    except ValueError:
        names = ", ".join(d.value for d in Dialect)
        raise argparse.ArgumentTypeError(f"{text!r} is not a dialect ({names})") from None


class _CodeAction(argparse.Action):
    """``--code H1=M667`` (repeatable) into one ``{code: line}`` table."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        codes = dict(getattr(namespace, self.dest) or {})
        try:
            codes.update(parse_code_map([str(values)]))
        except ValueError as exc:
            parser.error(f"{option_string}: {exc}")
        setattr(namespace, self.dest, codes)


def add_dialect_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--dialect",
        type=_dialect,
        default=None,
        help=f"the program's dialect ({', '.join(d.value for d in Dialect)}); "
        "default: detected from the program",
    )
    parser.add_argument(
        "--code",
        dest="codes",
        action=_CodeAction,
        default={},
        metavar="CODE=LINE",
        help="map a shop's own code to the daemon's, e.g. H1=M667 (repeatable)",
    )


def add_daemon_options(parser: argparse.ArgumentParser) -> None:
    """The daemon settings a program depends on (its ``[controller]`` keys of the same
    meaning): the material library and its units, and plasma mode at start."""
    parser.add_argument(
        "--materials", type=Path, default=None, help="a QtPlasmaC material file (NAME.cfg)"
    )
    parser.add_argument(
        "--inch-materials", action="store_true", help="the material file's lengths are inches"
    )
    parser.add_argument(
        "--plasma-mode-at-start", action=argparse.BooleanOptionalAction, default=None,
        help="as the daemon's controller.plasma_mode_at_start (default: on, a plasma-only "
        "table; --no-plasma-mode-at-start: a table with other tools, T112 M6 / T0 M6 first)",
    )  # fmt: skip
