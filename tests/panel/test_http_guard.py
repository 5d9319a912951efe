"""The panel's request checks: the Host allow-list (DNS rebinding), the Origin against that
list, JSON bodies bounded in size and depth, the cap on live-update streams, the token's
strength and its cookie."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import pytest
from aiohttp.test_utils import TestClient, TestServer

from dthc_tools.panel.http_guard import (
    BodyRefused,
    HostAllowList,
    TokenCheck,
    host_name,
    parse_json_body,
    token_bits,
)
from dthc_tools.panel.server import PanelLimits, build_app
from tests.panel.test_server import HEADERS, RecordingHub

ATTACKER = "attacker.example"


async def _client(
    hub: RecordingHub, allowed: HostAllowList | None = None, **limits: Any
) -> TestClient[Any, Any]:
    app = build_app(hub, token=None, allowed=allowed, limits=PanelLimits(**limits))
    client = TestClient(TestServer(app))
    await client.start_server()
    return client


@pytest.mark.parametrize(
    ("host", "origin", "status"),
    [
        (ATTACKER, f"http://{ATTACKER}", 421),  # DNS rebinding: the page's own name as Host
        (f"{ATTACKER}:8080", f"http://{ATTACKER}:8080", 421),
        (ATTACKER, None, 421),
        ("127.0.0.1", f"http://{ATTACKER}", 403),  # an allowed Host, a foreign Origin
        ("127.0.0.1", "null", 403),  # a sandboxed frame or a file: page
        ("127.0.0.1", "ftp://127.0.0.1", 403),
    ],
)
async def test_a_forged_host_or_origin_post_is_refused_and_changes_nothing(
    host: str, origin: str | None, status: int
) -> None:
    """A POST carrying everything the page sends (its header, JSON), from a Host or Origin
    the panel was not told of, is refused before any control runs."""
    hub = RecordingHub()
    client = await _client(hub)
    try:
        headers = {**HEADERS, "Host": host, **({"Origin": origin} if origin else {})}
        response = await client.post("/api/control/torch_up", data="{}", headers=headers)
        assert response.status == status
        assert hub.pressed == []
    finally:
        await client.close()


async def test_a_foreign_host_is_refused_for_reads_too() -> None:
    """421 for every GET under a foreign Host: the page, the view, the stream, the history."""
    client = await _client(RecordingHub())
    try:
        for path in ("/", "/api/view", "/events", "/api/cuts", "/static/panel.js"):
            response = await client.get(path, headers={"Host": ATTACKER})
            assert response.status == 421, path
            assert "--allow-host" in (await response.json())["error"]
    finally:
        await client.close()


@pytest.mark.parametrize(
    "host", ["127.0.0.1:8080", "localhost", "LOCALHOST:80", "[::1]:8080", "shop-pc.local:8080"]
)
async def test_the_names_the_panel_was_told_are_served(host: str) -> None:
    hub = RecordingHub()
    client = await _client(hub, HostAllowList.build("127.0.0.1", ["shop-pc.local"]))
    try:
        origin = f"http://{host.lower()}"
        response = await client.post(
            "/api/control/torch_up", data="{}", headers={**HEADERS, "Host": host, "Origin": origin}
        )
        assert response.status == 200
        assert (await client.get("/api/view", headers={"Host": host})).status == 200
        assert hub.pressed == [("torch_up", {})]
    finally:
        await client.close()


def test_host_names_are_parsed_without_port_or_brackets() -> None:
    assert host_name("[::1]:8080") == "::1"
    assert host_name("[::1]") == "::1"
    assert host_name("::1") == "::1"
    assert host_name("Panel.Local.:80") == "panel.local"
    assert host_name("127.0.0.1") == "127.0.0.1"
    allowed = HostAllowList.build("0.0.0.0", ["shop-pc"])  # noqa: S104 - every interface
    assert "0.0.0.0" not in allowed.names  # noqa: S104 - no one's Host
    assert not allowed.loopback_only
    assert HostAllowList.build("[::1]").loopback_only
    assert allowed.allows_origin("https://shop-pc:443")
    assert not allowed.allows_origin("https://shop-pc.attacker.example")


@pytest.mark.parametrize(
    ("body", "limit"),
    [
        ("[" * 14_000, "MAX_JSON_DEPTH"),  # 14 KB of nesting: json.loads recursed to a 500
        ('{"a": ' * 9 + "1" + "}" * 9, "MAX_JSON_DEPTH"),  # 9 levels: loads, but too deep
        ('{"name": "' + "x" * 20_000 + '"}', "MAX_JSON_BYTES"),
    ],
)
async def test_nested_or_large_json_is_a_400_naming_the_limit(body: str, limit: str) -> None:
    hub = RecordingHub()
    client = await _client(hub)
    try:
        response = await client.post("/api/control/material_set", data=body, headers=HEADERS)
        assert response.status == 400
        assert limit in (await response.json())["error"]
        assert hub.pressed == []
    finally:
        await client.close()


def test_the_depth_scan_counts_brackets_outside_strings_only() -> None:
    deep_text = {"note": '[[[[[[[[[[[[[[[[[[[[{{{{{{{{{{\\"[[[['}
    assert parse_json_body(json.dumps(deep_text).encode(), max_depth=1) == deep_text
    eight = "[" * 8 + "]" * 8
    assert parse_json_body(eight.encode(), max_depth=8) == json.loads(eight)
    with pytest.raises(BodyRefused, match="deeper than 7 levels"):
        parse_json_body(eight.encode(), max_depth=7)


async def test_live_update_streams_are_capped() -> None:
    """Beyond MAX_EVENT_STREAMS a stream is answered 503; a closed page frees its slot."""
    client = await _client(RecordingHub(), max_event_streams=2)
    try:
        first = await client.get("/events")
        second = await client.get("/events")
        assert (first.status, second.status) == (200, 200)
        third = await client.get("/events")
        assert third.status == 503
        assert "MAX_EVENT_STREAMS" in (await third.json())["error"]
        first.close()
        for _ in range(40):  # the handler notices within STREAM_CHECK_S
            again = await client.get("/events")
            if again.status == 200:
                again.close()
                break
            await asyncio.sleep(0.1)
        else:
            pytest.fail("a closed stream's slot was never freed")
        second.close()
    finally:
        await client.close()


def test_token_strength_is_counted_in_bits() -> None:
    assert token_bits("0123456789abcdef" * 2) == 128  # 32 hex digits
    assert token_bits("z" * 22) == 132  # token_urlsafe(16)
    assert token_bits("0123456789abcdef" * 2 + "-") == 33 * 6
    assert token_bits("s3cret-token") < 128
    check = TokenCheck("Vh3k9qT1xZ7mP2wR8sY4bN6cJ0fL5aDe")
    assert check.allows("Bearer Vh3k9qT1xZ7mP2wR8sY4bN6cJ0fL5aDe", None)
    assert check.allows("", check.cookie_value)
    assert not check.allows("", check.token)  # the cookie is an HMAC, never the token
    assert not check.allows("Bearer x", "y")
