"""The panel's controls: which request each one is, and whether the state allows it now.

One table, read by the server (where a press goes) and sent to the page with every view
(which buttons are enabled, and why not). The daemon and the sender stay the authority: a
control that reaches them when their state does not allow it is refused there with their
reason, which the page shows."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from dthc_tools.sender.sender import PAUSED_BY_OPERATOR

from .labels import state_label

__all__ = ["CONTROLS", "Control", "ControlError", "LiveView", "enabled", "route"]

TORCH_STEP_V = 1.0
HEIGHT_STEP_MM = 0.1
PATH_STEP_MM = 5.0
IDLE_STATES = frozenset({"idle", "faulted"})
PAUSED_CONTROLS = frozenset(
    {"path_back", "path_forward", "recovery_offset", "resume_here", "restart_cut"}
)
# Tests and jogs of an idle torch: the sender forwards them only while its program is not
# running (stopped, or paused by the operator), the daemon only outside a cut.
IDLE_TORCH = frozenset({"ohmic_test", "probe_test", "jog_up", "jog_down"})
# Forwarded by an online sender (running, or waiting for the operator after an error).
VIA_SENDER = frozenset(
    {"torch_up", "torch_down", "height_up", "height_down", "thc_on", "thc_off", "rearm",
     *IDLE_TORCH}
)  # fmt: skip
NO_SENDER = "no sender is online (the panel reaches the torch only through the sender)"
PROGRAM_RUNS = "the program is running (pause it first)"
JOG_MAX_MM = 10.0  # one jog press at most (the daemon's bound)
JOG_STEP_MM = 1.0


class ControlError(Exception):
    """A press the panel cannot deliver (no sender runs, an argument is wrong)."""


@dataclass
class LiveView:
    """What the panel knows of the table, from the retained topics and the connection."""

    broker: bool = False  # the panel's own connection
    daemon: bool = False  # its availability says online
    board: str = "unknown"  # online / offline / connecting / incompatible
    state: Mapping[str, Any] | None = None  # the daemon's state document
    sender: bool = False  # a sender is online (its availability)
    progress: Mapping[str, Any] | None = None  # the sender's progress document
    materials: Mapping[str, Any] | None = None

    @property
    def sequence(self) -> str:
        return str((self.state or {}).get("state", "unknown"))

    @property
    def running(self) -> bool:
        """A sender runs a program."""
        return self.sender and bool((self.progress or {}).get("running"))

    @property
    def paused_at(self) -> Mapping[str, Any] | None:
        """A sender's program stopped after an error, the torch found on its path."""
        at = (self.progress or {}).get("paused_at")
        return at if self.sender and isinstance(at, Mapping) else None

    @property
    def operator_stopped(self) -> bool:
        """The operator paused a lit cut: the program stopped where the torch went out, and
        cycle start resumes it there (through the start sequence)."""
        error = str((self.progress or {}).get("error") or "")
        return self.paused_at is not None and error.endswith(PAUSED_BY_OPERATOR)


@dataclass(frozen=True)
class Control:
    role: str  # "daemon" or "sender": who answers it
    request: str
    args: Callable[[Mapping[str, Any]], dict[str, Any]]
    needs_board: bool = True


def _none(_args: Mapping[str, Any]) -> dict[str, Any]:
    return {}


def _fixed(**values: Any) -> Callable[[Mapping[str, Any]], dict[str, Any]]:
    return lambda _args: dict(values)


def _material(args: Mapping[str, Any]) -> dict[str, Any]:
    """The material's fields as the page sent them; the daemon validates each one."""
    if "number" not in args:
        raise ControlError("material number: required")
    return dict(args)


def _distance(
    word: str, sign: float, default_mm: float, max_mm: float
) -> Callable[[Mapping[str, Any]], dict[str, Any]]:
    """``mm`` (a distance, the page's step: 0 to ``max_mm``) signed by ``sign``, with the
    page's ``feed_mm_min`` passed on for the one who moves to check."""

    def args(given: Mapping[str, Any]) -> dict[str, Any]:
        mm = given.get("mm", default_mm)
        if isinstance(mm, bool) or not isinstance(mm, int | float) or not 0 < mm <= max_mm:
            raise ControlError(f"{word} mm: {mm!r} must be a distance of 0 to {max_mm:g} mm")
        out: dict[str, Any] = {"mm": sign * float(mm)}
        if "feed_mm_min" in given:
            out["feed_mm_min"] = given["feed_mm_min"]
        return out

    return args


def _path(sign: float) -> Callable[[Mapping[str, Any]], dict[str, Any]]:
    """Paused motion: back or forward along the path (the sender checks the feed)."""
    return _distance("path", sign, PATH_STEP_MM, 1000.0)


def _offset(given: Mapping[str, Any]) -> dict[str, Any]:
    """The new offset off the path; the sender checks the numbers and the bound."""
    return {key: given[key] for key in ("x_mm", "y_mm", "feed_mm_min") if key in given}


def _jog(sign: float) -> Callable[[Mapping[str, Any]], dict[str, Any]]:
    """Z up (+) or down (-) (the daemon checks the feed)."""
    return _distance("jog", sign, JOG_STEP_MM, JOG_MAX_MM)


def _material_number(args: Mapping[str, Any]) -> dict[str, Any]:
    if "number" not in args:
        raise ControlError("material number: required")
    return {"number": args["number"]}


# The panel reaches the torch and Z only through the sender (the broker's ACL lets the
# panel's user send the daemon nothing that can light the torch or move Z: see
# dthc_bridge/mqtt/roles.py); the sender forwards these to the daemon (sender/remote.py).
CONTROLS: dict[str, Control] = {
    "torch_up": Control("sender", "torch_up", _fixed(volts=TORCH_STEP_V)),
    "torch_down": Control("sender", "torch_down", _fixed(volts=TORCH_STEP_V)),
    "height_up": Control("sender", "height_override", _fixed(mm=HEIGHT_STEP_MM)),
    "height_down": Control("sender", "height_override", _fixed(mm=-HEIGHT_STEP_MM)),
    "thc_on": Control("sender", "thc", _fixed(on=True)),
    "thc_off": Control("sender", "thc", _fixed(on=False)),
    "cycle_start": Control("sender", "cycle_start", _none),
    "pause": Control("sender", "pause", _none),
    "stop": Control("sender", "stop", _none),
    "rearm": Control("sender", "rearm", _none),
    "path_back": Control("sender", "path_move", _path(-1.0)),
    "path_forward": Control("sender", "path_move", _path(+1.0)),
    "recovery_offset": Control("sender", "recovery_offset", _offset),
    "resume_here": Control("sender", "resume", _none),
    "restart_cut": Control("sender", "restart", _none),
    "material_set": Control("daemon", "material_set", _material, needs_board=False),
    "material_delete": Control("daemon", "material_delete", _material_number, needs_board=False),
    # The next cut's material (a program's own G200 or material change still wins).
    "material_select": Control("daemon", "material_select", _material_number, needs_board=False),
    "consumables_reset": Control("daemon", "consumables_reset", _none, needs_board=False),
    "ohmic_test": Control("sender", "ohmic_test", _none),
    "probe_test": Control("sender", "probe_test", _none),
    "jog_up": Control("sender", "jog_z", _jog(+1.0)),
    "jog_down": Control("sender", "jog_z", _jog(-1.0)),
}


def _offline_reason(view: LiveView, control: Control) -> str | None:
    if not view.broker:
        return "the broker is unreachable"
    if not view.daemon:
        return "the daemon is offline"
    if control.needs_board and view.board != "online":
        return f"the board is {view.board}"
    return None


def _state_reason(name: str, view: LiveView) -> str | None:
    """Why the state does not allow ``name`` now (None: it does)."""
    progress = view.progress or {}
    sequence = view.sequence
    if name in VIA_SENDER and not view.sender:
        return NO_SENDER
    if name == "cycle_start":
        if view.operator_stopped:
            return None
        if view.running:  # the sender says: the daemon's state runs ahead of its progress
            waiting = progress.get("waiting_cycle_start") or progress.get("operator_paused")
            return None if waiting else "nothing waits for cycle start"
        return "nothing waits for cycle start"
    if name == "pause":
        if not view.running:
            return "no program runs"
        return "paused already" if progress.get("operator_paused") else None
    if name == "stop":  # a paused program: ends it (the torch is out already)
        running = view.running or view.paused_at is not None
        return None if running or sequence not in IDLE_STATES else "nothing runs"
    if name == "rearm":
        return None if sequence == "faulted" else "nothing to re-arm (no fault)"
    if name in IDLE_TORCH:
        if view.running and not progress.get("operator_paused"):
            return PROGRAM_RUNS
        if sequence not in IDLE_STATES:
            return f"the torch is busy: {state_label(sequence).lower()}"
        return None
    if name in PAUSED_CONTROLS:
        if view.paused_at is not None:
            if name == "restart_cut" and not progress.get("restart_line"):
                return "no line to restart from"
            return None
        if name in ("path_back", "path_forward", "recovery_offset") and view.running:
            # During an operator's pause a move first ends the cut where the torch is.
            return None if progress.get("operator_paused") else "pause the program first"
        return "no program is paused"
    if name == "thc_on":
        return "the THC is on" if (view.state or {}).get("thc_enabled") else None
    if name == "thc_off":
        return None if (view.state or {}).get("thc_enabled") else "the THC is off"
    return None


def enabled(view: LiveView) -> dict[str, str | None]:
    """Every control: None when the state allows it, else the reason it is disabled."""
    out: dict[str, str | None] = {}
    for name, control in CONTROLS.items():
        out[name] = _offline_reason(view, control) or _state_reason(name, view)
    return out


def route(name: str, args: Mapping[str, Any], view: LiveView) -> tuple[str, str, dict[str, Any]]:
    """Where a press goes: (role, request name, arguments). ControlError for an unknown
    control, a wrong argument, or a sender control with no sender to answer it."""
    control = CONTROLS.get(name)
    if control is None:
        raise ControlError(f"{name}: no such control")
    request_args = control.args(args)
    role, request = control.role, control.request
    if name in PAUSED_CONTROLS:
        if not view.sender:
            raise ControlError(f"{name}: no sender is online")
        return role, request, request_args
    if name in VIA_SENDER:
        if not view.sender:
            raise ControlError(f"{name}: {NO_SENDER}")
        return role, request, request_args
    if name == "cycle_start" and view.operator_stopped:
        return role, request, request_args  # resumes where the torch stands
    if name == "stop" and view.paused_at is not None and not view.running:
        return "sender", "quit", {}  # the program paused after an error or a pause: end it
    if role == "sender" and not view.running:
        # Without a program running there is no motion to hold. A stop still reaches the
        # daemon itself (it only ever puts the torch out), whoever drives the table.
        if name == "stop":
            return "daemon", "abort", {}
        raise ControlError(f"{name}: no program runs (no sender is online)")
    return role, request, request_args
