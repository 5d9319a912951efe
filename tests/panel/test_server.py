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
from dthc_tools.panel.cli import is_loopback, parse_listen, serve
from dthc_tools.panel.controls import ControlError
from dthc_tools.panel.history import CutHistory, CutRecorder
from dthc_tools.panel.hub import PanelHub
from dthc_tools.panel.server import build_app
from dthc_tools.sender.daemon_client import DaemonClient
from tests.panel.test_history import g200_s1_cut

HEADERS = {"Content-Type": "application/json", "X-DTHC-Panel": "1"}


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
    client = await client_for(hub, token="s3cret-token")  # noqa: S106 - a test's token
    try:
        view = await (await client.get("/api/view")).json()
        assert view["token_required"] is True
        for given in ("", "Bearer wrong", "s3cret-token"):
            response = await client.post(
                "/api/control/stop", data="{}", headers={**HEADERS, "Authorization": given}
            )
            assert response.status == 401
        assert hub.pressed == []
        good = await client.post(
            "/api/control/stop",
            data="{}",
            headers={**HEADERS, "Authorization": "Bearer s3cret-token"},
        )
        assert good.status == 200
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


async def test_listening_beyond_localhost_needs_a_token(tmp_path: Path) -> None:
    args = argparse.Namespace(
        listen="0.0.0.0:8080", token_file=None, broker="mqtt://x:1",
        base_topic="dthc", board_id="t", protocol="5", history=None,
    )  # fmt: skip
    with pytest.raises(SystemExit, match="beyond localhost the controls need a token"):
        await serve(args)
    empty = tmp_path / "token"
    empty.write_text("\n")
    args.token_file = empty
    with pytest.raises(SystemExit, match="the file is empty"):
        await serve(args)
