"""Which controls the state allows, and where a press goes."""

from __future__ import annotations

import re
from typing import Any

import pytest

from dthc_bridge.mqtt.roles import PANEL_REQUESTS
from dthc_tools.panel.controls import (
    CONTROLS,
    NO_SENDER,
    ControlError,
    LiveView,
    enabled,
    route,
)


def online(state: str = "idle", **more: Any) -> LiveView:
    return LiveView(broker=True, daemon=True, board="online", state={"state": state, **more})


def running(**progress: Any) -> LiveView:
    view = online("cutting", thc_enabled=True)
    view.sender = True
    view.progress = {"running": True, "waiting_cycle_start": False, "operator_paused": False,
                     **progress}  # fmt: skip
    return view


def allowed(view: LiveView) -> set[str]:
    return {name for name, reason in enabled(view).items() if reason is None}


def test_offline_disables_every_control_with_the_reason() -> None:
    for view, reason in [
        (LiveView(), "the broker is unreachable"),
        (LiveView(broker=True), "the daemon is offline"),
        (LiveView(broker=True, daemon=True, board="offline"), "the board is offline"),
    ]:
        reasons = enabled(view)
        board_free = {"material_set", "material_delete", "material_select", "consumables_reset"}
        for name in CONTROLS:
            if name in board_free and reason == "the board is offline":
                continue  # the library is the daemon's: it is edited without the board
            assert reasons[name] == reason, name


def test_what_an_idle_table_allows() -> None:
    library = {"material_set", "material_delete", "material_select", "consumables_reset"}
    assert allowed(online()) == library
    waiting = online()
    waiting.sender = True  # a sender waits for the operator
    assert allowed(waiting) == {
        "torch_up", "torch_down", "height_up", "height_down", "thc_on", "ohmic_test",
        "probe_test", "jog_up", "jog_down", *library,
    }  # fmt: skip
    assert enabled(online())["cycle_start"] == "nothing waits for cycle start"
    assert enabled(waiting)["rearm"] == "nothing to re-arm (no fault)"
    faulted = online("faulted")
    assert enabled(faulted)["rearm"] == NO_SENDER
    faulted.sender = True
    assert "rearm" in allowed(faulted)


def test_torch_and_height_controls_go_through_the_sender_never_to_the_daemon() -> None:
    """The broker lets only the sender's user send requests that can light the torch or
    move Z: every such control is routed to the sender, and none reaches the daemon."""
    for name in ("torch_up", "torch_down", "height_up", "height_down", "thc_on", "thc_off",
                 "rearm", "cycle_start", "pause", "ohmic_test", "probe_test", "jog_up",
                 "jog_down"):  # fmt: skip
        assert route(name, {}, running())[0] == "sender", name
        with pytest.raises(ControlError):
            route(name, {}, online("s1_wait_cycle_start"))  # no sender: nothing is sent
    for name, control in CONTROLS.items():
        if control.role == "daemon":
            assert control.request in PANEL_REQUESTS, name
    assert route("stop", {}, online("cutting")) == ("daemon", "abort", {})


def test_a_running_program_allows_pause_and_stop_then_cycle_start_once_paused() -> None:
    view = running()
    assert {"pause", "stop", "thc_off"} <= allowed(view)
    assert "cycle_start" not in allowed(view)
    paused = running(operator_paused=True)
    assert "cycle_start" in allowed(paused)
    assert enabled(paused)["pause"] == "paused already"
    assert "cycle_start" in allowed(running(waiting_cycle_start=True))


def test_presses_go_to_the_sender_while_it_runs_and_only_a_stop_to_the_daemon_without_it() -> None:
    assert route("pause", {}, running()) == ("sender", "pause", {})
    assert route("cycle_start", {}, running()) == ("sender", "cycle_start", {})
    assert route("stop", {}, online("cutting")) == ("daemon", "abort", {})
    with pytest.raises(ControlError, match="pause: no program runs"):
        route("pause", {}, online())
    assert route("torch_up", {"volts": 50}, running()) == ("sender", "torch_up", {"volts": 1.0})
    assert route("height_down", {}, running()) == ("sender", "height_override", {"mm": -0.1})
    assert route("thc_off", {}, running()) == ("sender", "thc", {"on": False})
    with pytest.raises(ControlError, match="launch: no such control"):
        route("launch", {}, running())
    with pytest.raises(ControlError, match="material number: required"):
        route("material_set", {"name": "x"}, online())


def paused(**where: Any) -> LiveView:
    view = online("faulted")
    view.sender = True
    view.progress = {"running": False, "restart_line": 6,
                     "paused_at": {"line": 7, "x_mm": 126.0, "y_mm": 100.0, **where}}  # fmt: skip
    return view


def test_paused_motion_is_offered_while_a_program_is_paused_and_goes_to_the_sender() -> None:
    assert {"path_back", "path_forward", "recovery_offset", "resume_here",
            "restart_cut", "rearm"} <= allowed(paused())  # fmt: skip
    assert enabled(online())["path_back"] == "no program is paused"
    assert enabled(running())["path_forward"] == "pause the program first"
    assert "path_back" in allowed(running(operator_paused=True))
    assert route("path_back", {"mm": 20, "feed_mm_min": 1200}, paused()) == (
        "sender", "path_move", {"mm": -20.0, "feed_mm_min": 1200},
    )  # fmt: skip
    assert route("path_forward", {}, paused()) == ("sender", "path_move", {"mm": 5.0})
    assert route("recovery_offset", {"x_mm": -3, "y_mm": 4}, paused()) == (
        "sender", "recovery_offset", {"x_mm": -3, "y_mm": 4},
    )  # fmt: skip
    assert route("resume_here", {}, paused()) == ("sender", "resume", {})
    with pytest.raises(ControlError, match="path mm: -5 must be a distance"):
        route("path_back", {"mm": -5}, paused())
    gone = paused()
    gone.sender = False
    with pytest.raises(ControlError, match="resume_here: no sender is online"):
        route("resume_here", {}, gone)


def test_tests_and_jogs_go_through_the_sender_and_only_while_no_program_runs() -> None:
    """Ohmic test, probe test and Z jog move Z or energise the torch circuit: they go to the
    sender (which forwards them), never to the daemon; the page disables them with the
    reason while a program runs unpaused or the torch is busy, and without a sender."""
    idle = online()
    idle.sender = True
    assert route("ohmic_test", {}, idle) == ("sender", "ohmic_test", {})
    assert route("probe_test", {}, idle) == ("sender", "probe_test", {})
    assert route("jog_up", {"mm": 2}, idle) == ("sender", "jog_z", {"mm": 2.0})
    assert route("jog_down", {"mm": 0.5, "feed_mm_min": 600}, idle) == (
        "sender", "jog_z", {"mm": -0.5, "feed_mm_min": 600},
    )  # fmt: skip
    assert route("jog_down", {}, idle) == ("sender", "jog_z", {"mm": -1.0})
    for bad in (0, -1, 10.5, True, "3"):
        with pytest.raises(ControlError, match=r"jog mm: .* must be a distance of 0 to 10 mm"):
            route("jog_up", {"mm": bad}, idle)
    with pytest.raises(ControlError, match=re.escape(NO_SENDER)):
        route("ohmic_test", {}, online())
    for name in ("ohmic_test", "probe_test", "jog_up", "jog_down"):
        assert enabled(online())[name] == NO_SENDER
        assert enabled(running())[name] == "the program is running (pause it first)"
        assert enabled(running(waiting_cycle_start=True))[name] == (
            "the program is running (pause it first)"
        )
        paused_cutting = running(operator_paused=True)  # the torch still going up
        assert enabled(paused_cutting)[name] == "the torch is busy: cutting"
        paused_idle = running(operator_paused=True)
        paused_idle.state = {"state": "idle"}
        assert enabled(paused_idle)[name] is None


def test_material_select_and_consumables_reset_go_to_the_daemon_without_a_board() -> None:
    """Choosing the next cut's material and resetting the consumables' counters light
    nothing: the panel sends them to the daemon itself, board or no board."""
    board_gone = LiveView(broker=True, daemon=True, board="offline")
    assert enabled(board_gone)["material_select"] is None
    assert enabled(board_gone)["consumables_reset"] is None
    assert route("material_select", {"number": 3, "x": 1}, board_gone) == (
        "daemon", "material_select", {"number": 3},
    )  # fmt: skip
    assert route("consumables_reset", {"anything": 1}, board_gone) == (
        "daemon", "consumables_reset", {},
    )  # fmt: skip
    with pytest.raises(ControlError, match="material number: required"):
        route("material_select", {}, board_gone)


def test_a_cut_paused_from_the_page_resumes_with_cycle_start_and_stop_ends_it() -> None:
    """Pausing a lit cut stops the program where the torch went out (the sender's
    ``paused_at``, its error 'paused: paused by the operator'): cycle start resumes it there
    (the sender's cycle_start), Stop ends it (the sender's quit). A program stopped by an
    error is not resumed by cycle start (resume here or restart, after a look)."""
    stopped = paused(cut=1)
    stopped.state = {"state": "idle"}
    assert stopped.progress is not None
    stopped.progress = {**stopped.progress, "error": "paused: paused by the operator"}
    assert stopped.operator_stopped
    assert {"cycle_start", "stop", "resume_here", "ohmic_test"} <= allowed(stopped)
    assert route("cycle_start", {}, stopped) == ("sender", "cycle_start", {})
    assert route("stop", {}, stopped) == ("sender", "quit", {})
    by_error = paused()
    by_error.progress = {**(by_error.progress or {}), "error": "arc lost"}
    assert not by_error.operator_stopped
    assert enabled(by_error)["cycle_start"] == "nothing waits for cycle start"
    assert route("stop", {}, by_error) == ("sender", "quit", {})
