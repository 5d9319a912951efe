"""The text grbl sends: welcome banner, ``$I`` build info, ``$`` help, status reports.

Pure formatting: the firmware decides what to report, these functions decide how it reads
on the wire (grbl 1.1's field order and number formats: positions with 3 decimals in mm or 4
in inches, feed rates without decimals in mm/min or with one in in/min, spindle in rpm).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from dthc_bridge.program.modal import MM_PER_INCH

from .config import EmulatorConfig, Flavor

__all__ = ["HELP", "UNLOCK_HINT", "StatusFields", "banner", "build_info", "status_report"]

HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
UNLOCK_HINT = "[MSG:'$H'|'$X' to unlock]"


def banner(config: EmulatorConfig) -> str:
    """The welcome message, with the blank line grbl sends before it."""
    return "\r\n" + config.defaults.banner


def build_info(config: EmulatorConfig, user_text: str) -> list[str]:
    """``$I`` lines (before the ``ok``); ``[OPT:]`` carries planner blocks and RX bytes."""
    d = config.defaults
    lines = [
        f"[VER:{d.version}:{user_text}]",
        f"[OPT:{d.option_codes},{config.planner_blocks},{config.rx_buffer_bytes}"
        + (",3,0]" if config.flavor is Flavor.GRBLHAL else "]"),
    ]
    if config.flavor is Flavor.GRBLHAL:
        lines += ["[FIRMWARE:grblHAL]", "[DRIVER:emulated]"]
    return lines


@dataclass(frozen=True, slots=True)
class StatusFields:
    """What one status report says."""

    state: str  # "Idle", "Run", "Hold:0", ...
    mpos_mm: tuple[float, float, float]
    wco_mm: tuple[float, float, float]
    report_mpos: bool
    inches: bool
    buffer: tuple[int, int] | None  # free planner blocks, free RX bytes
    line_number: int  # 0: no Ln field
    feed_mm_min: float
    spindle_rpm: float
    include_wco: bool
    overrides: tuple[int, int, int]


def _vec(values: Sequence[float], inches: bool) -> str:
    if inches:
        return ",".join(f"{v / MM_PER_INCH:.4f}" for v in values)
    return ",".join(f"{v:.3f}" for v in values)


def status_report(f: StatusFields) -> str:
    """``<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0|Ov:100,100,100>``."""
    if f.report_mpos:
        position = f"MPos:{_vec(f.mpos_mm, f.inches)}"
    else:
        wpos = tuple(m - w for m, w in zip(f.mpos_mm, f.wco_mm, strict=True))
        position = f"WPos:{_vec(wpos, f.inches)}"
    fields = [f.state, position]
    if f.buffer is not None:
        fields.append(f"Bf:{f.buffer[0]},{f.buffer[1]}")
    if f.line_number > 0:
        fields.append(f"Ln:{f.line_number}")
    feed = f"{f.feed_mm_min / MM_PER_INCH:.1f}" if f.inches else f"{f.feed_mm_min:.0f}"
    fields.append(f"FS:{feed},{f.spindle_rpm:.0f}")
    if f.include_wco:
        fields.append(f"WCO:{_vec(f.wco_mm, f.inches)}")
    fields.append("Ov:{},{},{}".format(*f.overrides))
    return "<" + "|".join(fields) + ">"
