"""The panel's words: every state, input, lock and parameter the daemon can publish has
operator's words and units, and the parameters in force read as an operator says them."""

from __future__ import annotations

import dataclasses

from dthc_bridge.controller.commands import CutParams
from dthc_bridge.controller.sequence import State
from dthc_bridge.controller.thc import Lock
from dthc_bridge.materials import Material
from dthc_tools.panel.labels import (
    INPUTS,
    LOCKS,
    MATERIAL_FIELDS,
    PARAMS,
    STATES,
    describe_params,
    labels_document,
    state_label,
)
from firmware_protocol import InputBit


def test_every_daemon_name_has_the_operators_words() -> None:
    """A state, input, lock, parameter or material field added to the daemon without words
    here fails this test (the page would show a program's name to the operator)."""
    assert {str(state) for state in State} <= set(STATES)
    assert {bit.name.lower() for bit in InputBit} | {"torch_on"} == set(INPUTS)
    assert {str(lock) for lock in Lock} <= set(LOCKS)
    assert {field.name for field in dataclasses.fields(CutParams)} == set(PARAMS)
    material_fields = {field.name for field in dataclasses.fields(Material)}
    assert material_fields - {"number", "thickness"} <= set(MATERIAL_FIELDS)
    for words in (*STATES.values(), *INPUTS.values(), *LOCKS.values()):
        assert "_" not in words, words


def test_states_read_as_the_operator_says_them() -> None:
    assert state_label("s1_wait_cycle_start") == "Waiting for cycle start (S1)"
    assert state_label("cutting") == "Cutting"
    assert state_label("a_new_state") == "A new state"  # readable, never hidden
    assert state_label(None) == "Unknown"


def test_the_parameters_in_force_in_words_and_units() -> None:
    """The daemon's ``params`` as the operator reads them: "Touch-off feed 300 mm/min",
    "Cut voltage auto" (None), booleans in words; an unknown key still shows, last."""
    rows = describe_params({
        "cut_voltage_v": None, "touch_feed_mm_min": 300.0, "cut_height_mm": 1.5,
        "pierce_delay_ms": 300.0, "ohmic": True, "stop_after_pierce": False, "new_thing": 2,
    })  # fmt: skip
    shown = [(row["label"], row["text"]) for row in rows]
    assert shown == [
        ("Touch-off feed", "300 mm/min"),
        ("Pierce delay", "300 ms"),
        ("Cut height", "1.50 mm"),
        ("Cut voltage", "auto"),
        ("Touch-off by", "ohmic contact"),
        ("Stop after pierce (S1)", "no"),
        ("New thing", "2"),
    ]
    assert describe_params({"cut_voltage_v": 132.0})[0]["text"] == "132.0 V"
    assert describe_params({"ohmic": False})[0]["text"] == "float switch"
    assert describe_params(None) == []


def test_the_history_figures_say_what_they_measure() -> None:
    """The height figure is named for what it measures (relative to the probed point, warp
    included) and the arc voltage error is the headline; both explained."""
    history = labels_document()["history"]
    assert history["volts_rms_v"]["label"] == "Arc voltage error, RMS"
    assert history["height_rms_mm"]["label"] == "Z travel from probed height, RMS"
    assert "warp" in history["height_rms_mm"]["hint"]
    assert "target" in history["volts_rms_v"]["hint"]
