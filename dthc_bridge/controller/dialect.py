"""The G-code dialects a program may be written in, and what each changes.

The daemon's parser is one vocabulary; a dialect only decides the few places where the
programs of different controllers disagree:

* ``masso``: ``T112 M6`` is plasma mode, any other tool leaves it; ``#`` starts a comment
  (an option of the MASSO post); ``G4 P`` is in milliseconds (the post's dwell).
* ``plasmac`` (LinuxCNC PlasmaC / QtPlasmaC, NGC): ``T0`` is the plasma torch, ``T1`` the
  scribe and ``T2`` the spotting torch; ``#`` starts a parameter; magic comments
  ``(o=…)`` define materials; Z moves are stripped unless ``#<keep-z-motion> = 1``.
* ``rosetta`` (RosettaCNC): as MASSO for tools; ``G100`` does the plasma functions.
* ``relay`` (grbl-style posts, DXF/SVG tools, FireControl-style programs): the program
  writes the whole start sequence itself (probe, ``G92``, Z moves, ``G4``), and ``M3`` is a
  bare torch relay, answered at arc OK. Shop codes (FireControl's ``H1``/``H0``) map to the
  daemon's commands through a code table (:mod:`dthc_bridge.program.dialects`).
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["Dialect"]


class Dialect(StrEnum):
    MASSO = "masso"
    PLASMAC = "plasmac"
    ROSETTA = "rosetta"
    RELAY = "relay"

    @property
    def hash_is_comment(self) -> bool:
        """MASSO posts may put comments after ``#``; NGC dialects use it for parameters."""
        return self is Dialect.MASSO

    @property
    def dwell_unit_s(self) -> float:
        """Seconds per unit of ``G4 P``: MASSO's post writes milliseconds."""
        return 0.001 if self is Dialect.MASSO else 1.0
