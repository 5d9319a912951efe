"""The panel's web side without a broker: no GET changes anything, a control needs the
panel's header, same-origin JSON and the token when one is set; the stream starts with the
view; the history is served as JSON and CSV."""

from __future__ import annotations

import argparse
import json
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from dthc_bridge.mqtt.broker import BrokerSettings
from dthc_tools.panel.cli import parse_listen, serve
from dthc_tools.panel.controls import ControlError
from dthc_tools.panel.history import CutHistory, CutRecorder
from dthc_tools.panel.http_guard import is_loopback
from dthc_tools.panel.hub import PanelHub
from dthc_tools.panel.server import build_app
from dthc_tools.sender.daemon_client import DaemonClient
from tests.panel.test_history import g200_s1_cut

HEADERS = {"Content-Type": "application/json", "X-DTHC-Panel": "1"}
TOKEN = "Vh3k9qT1xZ7mP2wR8sY4bN6cJ0fL5aDe"  # noqa: S105 - a test's token, 32 of base64url


class RecordingHub(PanelHub):
    """A hub whose presses are recorded instead of published (no broker here)."""

    def __init__(self) -> None:
        super().__init__(
            DaemonClient(BrokerSettings(host="127.0.0.1", port=1), role="panel"), CutHistory()
        )
        self.pressed: list[tuple[str, dict[str, Any]]] = []

    async def control(self, name: str, args: Any) -> dict[str, Any]:
        if name == "refused":
            raise ControlError("refused: the daemon says no")
        if name == "buggy":
            raise RuntimeError("a bug")
        self.pressed.append((name, dict(args)))
        return {"pressed": name}


async def client_for(hub: PanelHub, token: str | None = None) -> TestClient[Any, Any]:
    client = TestClient(TestServer(build_app(hub, token=token)))
    await client.start_server()
    return client


@pytest.fixture
def hub() -> RecordingHub:
    return RecordingHub()


@pytest.fixture
async def client(hub: RecordingHub) -> AsyncIterator[TestClient[Any, Any]]:
    client = await client_for(hub)
    yield client
    await client.close()


async def test_a_control_from_the_page_is_pressed_and_answered(
    client: TestClient[Any, Any], hub: RecordingHub
) -> None:
    response = await client.post("/api/control/torch_up", data="{}", headers=HEADERS)
    assert response.status == 200
    assert await response.json() == {"ok": True, "data": {"pressed": "torch_up"}}
    refused = await client.post("/api/control/refused", data="{}", headers=HEADERS)
    assert await refused.json() == {"ok": False, "error": "refused: the daemon says no"}
    failed = await client.post("/api/control/buggy", data="{}", headers=HEADERS)
    assert failed.status == 500  # still one answer, in JSON, for the page to show
    assert (await failed.json())["error"] == "buggy: the panel failed: RuntimeError('a bug')"
    assert hub.pressed == [("torch_up", {})]


@pytest.mark.parametrize(
    ("headers", "body", "status", "error"),  # status and error: the refusal's
    [
        ({"Content-Type": "application/json"}, "{}", 403, "X-DTHC-Panel header is missing"),
        ({**HEADERS, "Origin": "http://evil.example"}, "{}", 403, "cross-site request refused"),
        ({**HEADERS, "Content-Type": "text/plain"}, "{}", 415, "JSON body"),
        ({**HEADERS, "Content-Type": "application/x-www-form-urlencoded"}, "a=1", 415, "JSON"),
        (HEADERS, "{not json", 400, "torch_up: the body is not JSON"),
        (HEADERS, "[1]", 400, "torch_up: the body is not a JSON object"),
    ],
)
async def test_a_request_that_is_not_the_panels_changes_nothing(  # noqa: PLR0917
    client: TestClient[Any, Any], hub: RecordingHub, headers: dict[str, str], body: str,
    status: int, error: str,
) -> None:  # fmt: skip
    response = await client.post("/api/control/torch_up", data=body, headers=headers)
    assert response.status == status
    assert error in (await response.json())["error"]
    assert hub.pressed == []


async def test_no_get_changes_state(client: TestClient[Any, Any], hub: RecordingHub) -> None:
    for path in ("/api/control/torch_up", "/api/control/stop"):
        assert (await client.get(path)).status == 405
    assert hub.pressed == []


async def test_a_token_is_required_when_configured(hub: RecordingHub) -> None:
    """With a token every endpoint but the page shell needs it, as a Bearer header or as
    the cookie the page's login POST gets."""
    client = await client_for(hub, token=TOKEN)
    try:
        assert (await client.get("/")).status == 200  # the shell: no table data
        assert (await client.get("/static/panel.js")).status == 200
        for path in ("/api/view", "/api/cuts", "/api/cuts/1", "/api/cuts/1.csv", "/events"):
            assert (await client.get(path)).status == 401, path
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        view = await (await client.get("/api/view", headers=bearer)).json()
        assert view["token_required"] is True
        for given in ("", "Bearer wrong", TOKEN, f"Basic {TOKEN}"):
            response = await client.post(
                "/api/control/stop", data="{}", headers={**HEADERS, "Authorization": given}
            )
            assert response.status == 401
        assert hub.pressed == []
        good = await client.post("/api/control/stop", data="{}", headers={**HEADERS, **bearer})
        assert good.status == 200
        assert hub.pressed == [("stop", {})]
    finally:
        await client.close()


async def test_the_page_logs_in_once_and_its_cookie_opens_every_endpoint(
    hub: RecordingHub,
) -> None:
    """The login POST answers the cookie (HttpOnly, SameSite=Strict, not the token itself);
    a wrong token gets none; the cookie then opens reads, the stream and controls."""
    client = await client_for(hub, token=TOKEN)
    try:
        wrong = await client.post("/api/login", json={"token": "x" * 40}, headers=HEADERS)
        assert wrong.status == 401
        assert "dthc_panel" not in wrong.cookies
        assert (await client.get("/api/view")).status == 401
        login = await client.post("/api/login", json={"token": TOKEN}, headers=HEADERS)
        assert login.status == 200
        cookie = login.headers["Set-Cookie"]
        assert "HttpOnly" in cookie
        assert "SameSite=Strict" in cookie
        assert TOKEN not in cookie
        assert (await client.get("/api/view")).status == 200
        stream = await client.get("/events")
        assert stream.status == 200
        stream.close()
        pressed = await client.post("/api/control/stop", data="{}", headers=HEADERS)
        assert pressed.status == 200
        assert hub.pressed == [("stop", {})]
    finally:
        await client.close()


async def test_the_page_is_served_with_a_strict_policy(client: TestClient[Any, Any]) -> None:
    page = await client.get("/")
    assert page.status == 200
    assert "script-src 'self'" in page.headers["Content-Security-Policy"]
    assert page.headers["X-Frame-Options"] == "DENY"
    assert '<canvas id="chart"' in await page.text()
    script = await client.get("/static/panel.js")
    assert script.status == 200


async def test_the_stream_starts_with_the_view(client: TestClient[Any, Any]) -> None:
    response = await client.get("/events")
    assert response.headers["Content-Type"].startswith("text/event-stream")
    line = await response.content.readline()
    assert line.startswith(b"data: ")
    message = json.loads(line[len(b"data: ") :])
    assert message["kind"] == "view"
    assert message["data"]["controls"]["stop"] == "the broker is unreachable"
    response.close()


async def test_the_history_as_json_and_csv(client: TestClient[Any, Any], hub: RecordingHub) -> None:
    record = g200_s1_cut(CutRecorder())[-1]
    assert record is not None
    hub.history.add(record)
    listed = await (await client.get("/api/cuts")).json()
    assert [c["number"] for c in listed] == [1]
    assert "trace" not in listed[0]
    full = await (await client.get("/api/cuts/1")).json()
    assert len(full["trace"]) == 4
    csv = await client.get("/api/cuts/1.csv")
    assert csv.headers["Content-Disposition"] == 'attachment; filename="cut-1.csv"'
    assert (await csv.text()).startswith("t_s,state,voltage_v")
    assert (await client.get("/api/cuts/9")).status == 404


def test_listen_addresses() -> None:
    assert parse_listen("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert parse_listen("[::1]:0") == ("::1", 0)
    with pytest.raises(SystemExit, match="expected HOST:PORT"):
        parse_listen("8080")
    assert is_loopback("localhost")
    assert is_loopback("::1")
    assert not is_loopback("0.0.0.0")  # noqa: S104 - every interface: not loopback
    assert not is_loopback("shop-pc.local")


def _serve_args(**changes: Any) -> argparse.Namespace:
    args = argparse.Namespace(
        listen="0.0.0.0:8080", token_file=None, allow_host=[], broker="mqtt://x:1",
        base_topic="dthc", board_id="t", protocol="5", history=None,
    )  # fmt: skip
    vars(args).update(changes)
    return args


async def test_listening_beyond_localhost_needs_a_token(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Refused at start, one line on stderr and exit 2: no token beyond localhost (listening
    there, or an --allow-host name there), an empty one, a short one, a file others read."""
    monkeypatch.delenv("DTHC_PANEL_TOKEN", raising=False)
    token_file = tmp_path / "token"
    token_file.write_text("\n")
    token_file.chmod(0o600)
    short = "0123456789abcdef0123456789abcde"  # 31 hex digits: 124 bits
    cases = [
        (_serve_args(), "beyond localhost (0.0.0.0) every endpoint needs a token"),
        (
            _serve_args(listen="127.0.0.1:8080", allow_host=["shop-pc.local"]),
            "beyond localhost (shop-pc.local) every endpoint needs a token",
        ),
        (_serve_args(token_file=token_file), "the token is empty"),
        (_serve_args(token_file=token_file, short=short), "about 124 bits (31 characters)"),
        (_serve_args(token_file=token_file, mode=0o640), "mode 0640 lets group or others"),
        (_serve_args(env=short), "DTHC_PANEL_TOKEN: the token holds about 124 bits"),
    ]
    for args, reason in cases:
        token_file.write_text(f"{vars(args).pop('short', '')}\n")
        token_file.chmod(vars(args).pop("mode", 0o600))
        if "env" in vars(args):
            monkeypatch.setenv("DTHC_PANEL_TOKEN", vars(args).pop("env"))
        assert await serve(args) == 2
        err = capsys.readouterr().err
        assert reason in err, err
        assert err.count("\n") == 1


PATH = {"program": "part.nc", "bounds": [0, 0, 300, 200], "moves": [
    {"cut": None, "line": 5, "points": [[0, 0], [50, 100]]},
    {"cut": 0, "line": 7, "points": [[50, 100], [300, 100]]},
]}  # fmt: skip


async def test_the_toolpath_reaches_open_pages_and_new_ones(
    client: TestClient[Any, Any], hub: RecordingHub
) -> None:
    """The sender's ``sender/path`` (retained, once per program) goes to every open page as
    it comes, to a page opened later right after the view, and is served on /api/path."""
    assert await (await client.get("/api/path")).json() == {}
    async with hub.page() as queue:
        hub._on_path("dthc/table1/sender/path", PATH)
        kinds = [json.loads(queue.get_nowait())["kind"] for _ in range(queue.qsize())]
        assert kinds == ["view", "path"]
    assert await (await client.get("/api/path")).json() == PATH
    response = await client.get("/events")
    messages = [json.loads((await response.content.readline())[len(b"data: ") :])]
    await response.content.readline()  # the blank line between events
    messages.append(json.loads((await response.content.readline())[len(b"data: ") :]))
    assert [m["kind"] for m in messages] == ["view", "path"]
    assert messages[1]["data"] == PATH
    response.close()
    hub._on_path("dthc/table1/sender/path", {"program": "bad"})  # no moves: no preview
    assert hub.path is None


async def test_the_page_gets_the_operators_words(
    client: TestClient[Any, Any], hub: RecordingHub
) -> None:
    """/api/labels: the words for states, inputs and figures; every view carries the
    parameters in force already worded."""
    labels = await (await client.get("/api/labels")).json()
    assert labels["states"]["s1_wait_cycle_start"] == "Waiting for cycle start (S1)"
    assert labels["inputs"]["estop"] == "E-stop"
    hub._on_state("dthc/table1/state", {"state": "idle", "params": {
        "touch_feed_mm_min": 300.0, "cut_voltage_v": None}})  # fmt: skip
    shown = hub.snapshot()["params_shown"]
    assert [(row["label"], row["text"]) for row in shown] == [
        ("Touch-off feed", "300 mm/min"), ("Cut voltage", "auto"),
    ]  # fmt: skip


async def test_a_view_is_pushed_when_the_table_changes_not_at_every_measurement(
    hub: RecordingHub,
) -> None:
    """The state's measured values (volts, Z, height) change at every poll during a cut;
    pages get them from the telemetry, so they leave the view and a new one is pushed only
    when something the view shows changes."""
    async with hub.page() as queue:
        for volts in (120.0, 121.0, 122.5):
            cutting = {"state": "cutting", "voltage_v": volts, "z_mm": volts / 10,
                       "consumables": {"pierces": 3, "arc_on_s": 60.0 + volts / 1000}}  # fmt: skip
            hub._on_state("dthc/table1/state", {**cutting, "thc_enabled": True})
        hub._on_state("dthc/table1/state", {"state": "to_safe_height", "thc_enabled": True})
        kinds = [json.loads(queue.get_nowait())["kind"] for _ in range(queue.qsize())]
    assert kinds == ["view", "view", "view"]  # the first, cutting, then to_safe_height
    assert "voltage_v" not in hub.snapshot()["state"]
    hub._on_state("dthc/table1/state", {"consumables": {"pierces": 3, "arc_on_s": 60.9}})
    assert hub.snapshot()["state"]["consumables"] == {"pierces": 3, "arc_on_s": 60}
