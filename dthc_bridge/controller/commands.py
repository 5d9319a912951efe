"""Typed plasma commands: what the G-code dialects and the MQTT requests turn into.

The controller consumes only these; the dialect parsers (``gcode.py``) and the MQTT
gateway produce them. Units are in the field names. Parameter objects validate their
ranges on construction and raise :class:`CommandError` naming the offending word.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from ..cut_params import CommandError, CutParams, check_range

__all__ = [
    "Abort",
    "Command",
    "CommandError",
    "CutParams",
    "CycleStart",
    "DefineMaterial",
    "HeightOverride",
    "JogZ",
    "LegacyMode",
    "OhmicTest",
    "OperatingMode",
    "PlasmaMode",
    "ProbeAndStart",
    "ProbeSurface",
    "ProbeTest",
    "ProgramZMove",
    "Rearm",
    "ResumePoint",
    "SelectCurrent",
    "SelectMaterial",
    "SetCutParams",
    "SetWorkZ",
    "ThcEnable",
    "ThcHold",
    "ThcMode",
    "TorchEnable",
    "TorchStart",
    "TorchStop",
    "VelocityReduction",
    "VoltageAdjust",
    "VoltageMode",
    "check_range",
]


class ThcMode(IntEnum):
    """LinuxCNC PlasmaC operating modes."""

    VOLTAGE_ONLY = 0  # arc OK derived from the arc voltage, voltage THC
    ARC_OK_AND_VOLTAGE = 1  # arc-OK input, voltage THC
    ARC_OK_AND_UPDOWN = 2  # arc-OK input, THC from an external box's up/down outputs


@dataclass(frozen=True, slots=True)
class PlasmaMode:
    """A tool change. MASSO: T112 M6 enters plasma mode, any other tool leaves it. PlasmaC:
    T0 is the plasma torch (``torch=True``), so selecting it never leaves plasma mode."""

    tool: int
    torch: bool | None = None  # set by dialects where the torch is not tool 112

    @property
    def enabled(self) -> bool:
        return self.torch if self.torch is not None else self.tool == 112


@dataclass(frozen=True, slots=True)
class SetCutParams:
    """G200 with parameters: sets (and overwrites) the cut parameters; G200 mode active."""

    params: CutParams


@dataclass(frozen=True, slots=True)
class LegacyMode:
    """G200 with no parameters: no automatic sequence, everything by G-code."""


@dataclass(frozen=True, slots=True)
class TorchStart:
    """M3: with G200 active, the automatic start sequence; answered when XY may move.

    ``relay``: the program does its own start sequence (relay dialect): M3 only switches the
    torch on and is answered at arc OK. In MASSO legacy mode (bare G200) every M3 is one."""

    relay: bool = False


@dataclass(frozen=True, slots=True)
class TorchStop:
    """M5: torch off, then safe height."""


@dataclass(frozen=True, slots=True)
class ThcEnable:
    """M667 [F] / M666; G100 P7 A1/A0; PlasmaC M63/M65 P2 (on), M62/M64 P2 (off)."""

    enabled: bool
    z_feed_mm_min: float | None = None  # M667 F, remembered until overwritten
    synchronized: bool = False  # PlasmaC M62/M63: with the next motion; M64/M65: at once


@dataclass(frozen=True, slots=True)
class VoltageAdjust:
    """Torch up / torch down during a cut: the target voltage moves by ``delta_v``."""

    delta_v: float


@dataclass(frozen=True, slots=True)
class ResumePoint:
    """RosettaCNC G100 P0: a safe start/resume point; its track is recorded and published."""

    line: int | None = None


@dataclass(frozen=True, slots=True)
class SelectCurrent:
    """RosettaCNC G100 P4 A: plasma current set point."""

    current_a: float


@dataclass(frozen=True, slots=True)
class VoltageMode:
    """RosettaCNC G100 P5: A0 B<volts> fixed, A1 auto-acquired after torch activation."""

    auto: bool
    volts: float | None = None


@dataclass(frozen=True, slots=True)
class ProbeAndStart:
    """RosettaCNC G100 P6 A B C D E F H [I]: probe, pierce, start, optionally THC."""

    z_feed_mm_min: float  # A
    touch_target_z_mm: float  # B: probe no further than this machine Z
    touch_feed_mm_min: float  # C
    pierce_height_mm: float  # D
    pierce_delay_s: float  # E
    arc_ok_timeout_s: float  # F
    cut_height_mm: float  # H
    mode: int = 0  # I: 0 probe+THC (comparator off until P7 A1), 1 no THC, 2 reset, 3 set


@dataclass(frozen=True, slots=True)
class OperatingMode:
    """LinuxCNC PlasmaC operating mode 0, 1 or 2."""

    mode: ThcMode


@dataclass(frozen=True, slots=True)
class VelocityReduction:
    """PlasmaC M67/M68 E3 Q: run the cut at Q percent of the programmed feed."""

    percent: float
    synchronized: bool = True  # M67 with motion, M68 at once


@dataclass(frozen=True, slots=True)
class TorchEnable:
    """PlasmaC M62/M64 P3 (torch disabled: motion goes on with the torch off, the hole
    over-cut) and M63/M65 P3 (enabled). 62/63 with the next motion, 64/65 at once."""

    enabled: bool
    synchronized: bool = False


@dataclass(frozen=True, slots=True)
class SelectMaterial:
    """PlasmaC M190 P<n>: the material's cut parameters, feed and current; -1 = the
    material in force before the program. ``word``: what errors name (the panel's
    ``material_select`` request); None: the M190 line."""

    number: int
    word: str | None = None


@dataclass(frozen=True, slots=True)
class DefineMaterial:
    """A PlasmaC magic comment ``(o=0, ph=..., ...)``: the comment's text, checked by
    :func:`dthc_bridge.materials.parse_magic_comment` when parsed."""

    comment: str


@dataclass(frozen=True, slots=True)
class ProgramZMove:
    """A Z word of the program (``G0 Z20``, ``G1 Z1.5 F300``, ``G53 G0 Z-5``): Z belongs to
    the board. In work coordinates (``G92``/``G10 L20`` origin) unless ``machine``."""

    z_mm: float
    feed_mm_min: float | None = None  # None: rapid
    machine: bool = False


@dataclass(frozen=True, slots=True)
class ProbeSurface:
    """A probe the program does itself (``G38.2 Z-50 F300``, Mach3 ``G31``): the board probes
    down with the touch-off sensors and stops on contact. ``z_mm`` is the work Z to probe to
    at most; ``require_contact`` is G38.2 (no contact is an error) against G38.3. ``away``:
    G38.4/G38.5, up from the work until the sensors release (a FireControl-style lift off the
    float switch); ``require_contact`` then means the release is required (G38.4)."""

    z_mm: float
    feed_mm_min: float
    require_contact: bool = True
    away: bool = False


@dataclass(frozen=True, slots=True)
class SetWorkZ:
    """``G92 Z<v>`` / ``G10 L20 P1 Z<v>``: the current Z now reads ``z_mm`` in work
    coordinates; ``G92.1`` (``z_mm=None``) clears the origin."""

    z_mm: float | None


@dataclass(frozen=True, slots=True)
class CycleStart:
    """The operator's cycle start (resumes an S1 stop after pierce)."""


@dataclass(frozen=True, slots=True)
class Rearm:
    """Leave the faulted state after an error has been seen (touch-off follows)."""


@dataclass(frozen=True, slots=True)
class HeightOverride:
    """``height_override`` {mm} (a step, 0.1 mm units) or {reset: true}: the cut height
    raised or lowered on the fly, within half the cut height either way."""

    step_mm: float
    reset: bool = False


@dataclass(frozen=True, slots=True)
class Abort:
    """The operator's stop (``abort`` request): a running cut ends through the fault path
    (torch off, safe height, re-arm before the next cut); the command waiting on it, an M3
    in its pierce or a G200 S1 stop, is answered with the error."""


@dataclass(frozen=True, slots=True)
class ThcHold:
    """The operator paused the program (``thc_hold`` request): Z holds while ``on``, without
    changing M667/M666; a new cut starts released. A cut running when it comes (lit or in
    its start sequence) is ended: torch off, safe height, the sender told to pause
    (docs/DESIGN.md invariant 7)."""

    on: bool


@dataclass(frozen=True, slots=True)
class OhmicTest:
    """Switch ohmic sensing on with the torch in the air: contact means a shorted torch."""


@dataclass(frozen=True, slots=True)
class ProbeTest:
    """The operator's probe test (``probe_test`` request, idle only): a touch-off where the
    torch stands, as a cut's, then back to the Z it started from; the surface found is the
    plate's (height above the plate reads from it)."""


@dataclass(frozen=True, slots=True)
class JogZ:
    """The operator's Z jog (``jog_z`` request, idle only): ``mm`` up (+) or down (-) from
    where Z is, inside the travel, at ``feed_mm_min`` (None: the set-up speed)."""

    mm: float
    feed_mm_min: float | None = None


Command = (
    PlasmaMode
    | SetCutParams
    | LegacyMode
    | TorchStart
    | TorchStop
    | ThcEnable
    | VoltageAdjust
    | ResumePoint
    | SelectCurrent
    | VoltageMode
    | ProbeAndStart
    | OperatingMode
    | VelocityReduction
    | CycleStart
    | Rearm
    | Abort
    | HeightOverride
    | ThcHold
    | OhmicTest
    | ProbeTest
    | JogZ
    | TorchEnable
    | SelectMaterial
    | DefineMaterial
    | ProgramZMove
    | ProbeSurface
    | SetWorkZ
)
