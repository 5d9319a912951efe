"""The panel's words: what the operator reads for each state, parameter, input and lock.

One table, in the operator's words and units ("Touch-off feed 300 mm/min", "Waiting for
cycle start (S1)", "Cut voltage: auto"), not the program's names (``touch_feed_mm_min``,
``s1_wait_cycle_start``). The page gets it once (``GET /api/labels``) and the parameters in
force already worded with every view (:func:`describe_params`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

__all__ = [
    "HISTORY",
    "INPUTS",
    "LOCKS",
    "MATERIAL_FIELDS",
    "PARAMS",
    "STATES",
    "Quantity",
    "describe_params",
    "labels_document",
    "state_label",
]

# The cut sequence's states (dthc_bridge.controller.sequence.State) as the operator says them.
STATES: dict[str, str] = {
    "idle": "Idle",
    "to_probe_height": "Moving down to probe",
    "probing": "Touching off the plate",
    "creep_up": "Backing off the plate",
    "to_pierce_height": "Rising to pierce height",
    "torch_on": "Torch on",
    "arc_wait": "Waiting for arc OK",
    "arc_retry_delay": "No arc: retrying",
    "pierce_delay": "Piercing",
    "s1_raise": "Pierced: raising (S1)",
    "s1_wait_cycle_start": "Waiting for cycle start (S1)",
    "s1_lower": "Lowering to cut (S1)",
    "puddle_jump": "Puddle jump",
    "to_cut_height": "Going to cut height",
    "cutting": "Cutting",
    "pause_at_end": "Pause at end of cut",
    "to_safe_height": "Raising to safe height",
    "faulted": "Stopped: re-arm needed",
    "ohmic_test": "Ohmic test",
    "probe_test": "Probe test",
    "jog_z": "Jogging Z",
    "program_z_move": "Moving Z (program)",
    "program_probe": "Probing (program)",
    "unknown": "Unknown",
}

# The board's inputs (firmware_protocol.InputBit, lower case) as lights, in panel order.
INPUTS: dict[str, str] = {
    "torch_on": "Torch on",
    "arc_ok": "Arc OK",
    "ohmic": "Ohmic",
    "float": "Float",
    "breakaway": "Breakaway",
    "estop": "E-stop",
    "z_limit_min": "Z limit min",
    "z_limit_max": "Z limit max",
    "thc_up": "THC up",
    "thc_down": "THC down",
}

# Why the THC holds Z (dthc_bridge.controller.thc.Lock).
LOCKS: dict[str, str] = {
    "disabled": "THC off",
    "frozen": "THC delay",
    "velocity": "slowing (anti-dive)",
    "void": "void / kerf crossing",
    "no_speed": "no XY speed",
    "held": "paused",
}


@dataclass(frozen=True)
class Quantity:
    """How one value reads: a label, a unit and its digits; the words for None, yes, no."""

    label: str
    unit: str = ""
    digits: int = 1
    none: str = "-"
    yes: str = "yes"
    no: str = "no"
    hint: str = ""

    def text(self, value: Any) -> str:
        if value is None:
            return self.none
        if isinstance(value, bool):
            return self.yes if value else self.no
        if isinstance(value, int | float):
            number = f"{value:.{self.digits}f}"
            return f"{number} {self.unit}" if self.unit else number
        return str(value)


# The cut parameters in force (the daemon's state ``params``: CutParams, MASSO's G200 words).
PARAMS: dict[str, Quantity] = {
    "touch_feed_mm_min": Quantity("Touch-off feed", "mm/min", 0, hint="G200 F"),
    "pierce_height_mm": Quantity("Pierce height", "mm", 1, hint="G200 P"),
    "pierce_delay_ms": Quantity("Pierce delay", "ms", 0, hint="G200 D"),
    "cut_height_mm": Quantity("Cut height", "mm", 2, hint="G200 C"),
    "cut_voltage_v": Quantity(
        "Cut voltage", "V", 1, none="auto", hint="G200 V; auto: sampled once the cut is at speed"
    ),
    "anti_dive_percent": Quantity("Anti-dive below", "% of feed", 0, hint="G200 A"),
    "ohmic": Quantity("Touch-off by", yes="ohmic contact", no="float switch", hint="G200 O"),
    "stop_after_pierce": Quantity("Stop after pierce (S1)", hint="G200 S"),
}

# A material's fields (the materials topic, dthc_bridge.materials.Material), for its editor.
MATERIAL_FIELDS: dict[str, Quantity] = {
    "name": Quantity("Name"),
    "kerf_width": Quantity("Kerf width", "mm", 2),
    "thc": Quantity("THC", yes="on", no="off"),
    "pierce_height": Quantity("Pierce height", "mm", 1),
    "pierce_delay_s": Quantity("Pierce delay", "s", 2),
    "puddle_jump_height_percent": Quantity("Puddle jump height", "% of pierce", 0),
    "puddle_jump_delay_s": Quantity("Puddle jump delay", "s", 2),
    "cut_height": Quantity("Cut height", "mm", 2),
    "cut_speed": Quantity("Cut feed", "mm/min", 0),
    "cut_amps": Quantity("Cut current", "A", 0),
    "cut_volts": Quantity("Cut voltage", "V", 1, hint="0 = auto"),
    "pause_at_end_s": Quantity("Pause at end", "s", 2),
    "gas_pressure": Quantity("Gas pressure", "bar", 1),
    "cut_mode": Quantity("Cut mode", digits=0),
}

# The cut history's figures: what each measures (the page's headers and tooltips).
HISTORY: dict[str, Quantity] = {
    "volts_rms_v": Quantity(
        "Arc voltage error, RMS",
        "V",
        2,
        hint="How far the arc voltage was from the THC's target while it was cutting with the "
        "THC in control (not locked): the THC's own tracking error. About 7.5 V per mm of "
        "height, so 1 V is roughly 0.13 mm off the plate.",
    ),
    "height_rms_mm": Quantity(
        "Z travel from probed height, RMS",
        "mm",
        2,
        hint="The torch's height, while cutting, relative to the point probed at the cut's "
        "start, minus the cut height: on a flat sheet how far the THC strayed; on a warped "
        "sheet it includes the plate's own warp, which the THC follows on purpose.",
    ),
    "height_max_mm": Quantity("Z travel from probed height, max", "mm", 2),
    "arc_start_s": Quantity("Arc start", "s", 2, hint="torch on to arc OK"),
    "pierce_s": Quantity("Pierce", "s", 2, hint="arc OK to motion"),
    "arc_on_s": Quantity("Arc on", "s", 1),
    "target_v": Quantity("Target voltage", "V", 1),
}


def state_label(state: str | None) -> str:
    """A sequence state in the operator's words (an unknown one: its name, readable)."""
    if not state:
        return STATES["unknown"]
    return STATES.get(state) or state.replace("_", " ").capitalize()


def describe_params(params: Mapping[str, Any] | None) -> list[dict[str, str]]:
    """The parameters in force as rows: ``{"label", "text", "hint"}``, in table order; a
    parameter the table does not know is shown by its name (still readable, never hidden)."""
    given = dict(params or {})
    keys = [key for key in PARAMS if key in given] + [key for key in given if key not in PARAMS]
    rows = []
    for key in keys:
        quantity = PARAMS.get(key)
        if quantity is None:  # a parameter newer than this table: its name, its value
            rows.append({"label": key.replace("_", " ").capitalize(), "text": str(given[key]),
                         "hint": key})  # fmt: skip
            continue
        rows.append({"label": quantity.label, "text": quantity.text(given[key]),
                     "hint": quantity.hint})  # fmt: skip
    return rows


def labels_document() -> dict[str, Any]:
    """Everything above, for the page."""
    return {
        "states": STATES,
        "inputs": INPUTS,
        "locks": LOCKS,
        "params": {key: asdict(q) for key, q in PARAMS.items()},
        "material_fields": {key: asdict(q) for key, q in MATERIAL_FIELDS.items()},
        "history": {key: asdict(q) for key, q in HISTORY.items()},
    }
