"""The panel's web side (aiohttp): the page, its live stream, its controls, the cut history.

    GET  /                       the page (static HTML, CSS and our own JavaScript)
    GET  /events                 server-sent events: {"kind": "view"|"telemetry"|..., "data"}
    GET  /api/view               the live view now (links, state, progress, controls enabled)
    GET  /api/labels             the operator's words for states, inputs, parameters, figures
    GET  /api/path               the running program's toolpath (the sender's), or {}
    GET  /api/cuts               the cut history, newest last (summaries)
    GET  /api/cuts/{n}           one cut with its trace;  /api/cuts/{n}.csv  as CSV
    POST /api/control/{name}     press a control: {"ok": true, "data"} or {"ok": false, "error"}
    POST /api/login              {"token"}: sets the session cookie (HttpOnly, SameSite=Strict)

No GET changes anything. Every request must name an allowed Host (421 otherwise: DNS
rebinding) and, when it has an Origin, an allowed one (403). A POST must be JSON with the
panel's own header (a form or script of another site can send neither without a CORS
preflight, which is never granted). With a token (required beyond localhost) every endpoint
but the page shell and the login needs it: ``Authorization: Bearer`` or the login cookie.
A body is read within BODY_TIMEOUT_S and bounded in size and depth; at most
MAX_EVENT_STREAMS live-update streams are open (503 beyond). The head of each request has
its own deadline, and connections their cap, in connections.py."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import structlog
from aiohttp import web
from aiohttp.typedefs import Middleware

from dthc_bridge.mqtt.cancellation import honour_cancellation
from dthc_tools.sender.daemon_client import DaemonError

from .connections import HEADER_TIMEOUT_S, MAX_CONNECTIONS, ConnectionLimits, request_started
from .controls import ControlError
from .http_guard import (
    MAX_JSON_BYTES,
    MAX_JSON_DEPTH,
    SESSION_COOKIE,
    BodyRefused,
    HostAllowList,
    TokenCheck,
    parse_json_body,
)
from .hub import PanelHub
from .labels import labels_document

__all__ = ["PANEL_HEADER", "PanelLimits", "build_app"]

log = structlog.get_logger("dthc_tools.panel.server")

STATIC = Path(__file__).with_name("static")
PANEL_HEADER = "X-DTHC-Panel"  # a custom header: cross-site requests cannot set it unasked
KEEPALIVE_S = 15.0  # a comment line on an idle stream, so proxies and browsers keep it
# aiohttp does not cancel a handler whose client left: an idle stream looks this often.
STREAM_CHECK_S = 1.0
BODY_TIMEOUT_S = 10.0  # a POST's body, from its head on
MAX_EVENT_STREAMS = 32  # live-update streams open at once: pages, tabs, a wall screen or two
# Served without the token: the page shell holds no table data (every figure comes from
# /api/* and /events), and it carries the form the token is typed into.
PUBLIC_PATHS = ("/", "/api/login")
PUBLIC_PREFIX = "/static/"
SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
        "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'"
    ),
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


@dataclass(frozen=True)
class PanelLimits:
    """What one client may hold of the panel; tests shrink them."""

    header_timeout_s: float = HEADER_TIMEOUT_S
    body_timeout_s: float = BODY_TIMEOUT_S
    max_connections: int = MAX_CONNECTIONS
    max_event_streams: int = MAX_EVENT_STREAMS
    max_json_bytes: int = MAX_JSON_BYTES
    max_json_depth: int = MAX_JSON_DEPTH

    @property
    def connections(self) -> ConnectionLimits:
        return ConnectionLimits(self.header_timeout_s, self.max_connections)


def build_app(
    hub: PanelHub,
    *,
    token: str | None,
    allowed: HostAllowList | None = None,
    limits: PanelLimits | None = None,
) -> web.Application:
    """The panel's app. ``allowed``: the Host names it answers (default: localhost's);
    ``token``: required by every endpoint but the page shell when set."""
    allowed = allowed or HostAllowList.build("127.0.0.1")
    limits = limits or PanelLimits()
    check = TokenCheck(token) if token is not None else None
    app = web.Application(
        middlewares=[_guard(allowed, check)], client_max_size=limits.max_json_bytes
    )
    routes = web.RouteTableDef()
    streams = [0]  # live-update streams open now

    @routes.get("/")
    async def index(_request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html")

    @routes.get("/api/view")
    async def view(_request: web.Request) -> web.Response:
        return web.json_response({**hub.snapshot(), "token_required": token is not None})

    @routes.get("/api/labels")
    async def labels(_request: web.Request) -> web.Response:
        return web.json_response(labels_document())

    @routes.get("/api/path")
    async def path(_request: web.Request) -> web.Response:
        return web.json_response(hub.path or {})

    @routes.get("/events")
    async def events(request: web.Request) -> web.StreamResponse:
        if streams[0] >= limits.max_event_streams:
            refusal = _refuse(
                503, f"{limits.max_event_streams} live-update streams are open "
                "(MAX_EVENT_STREAMS): close a page and reload",
            )  # fmt: skip
            refusal.headers["Retry-After"] = "5"
            return refusal
        streams[0] += 1
        try:
            response = web.StreamResponse(
                headers={**SECURITY_HEADERS, "Content-Type": "text/event-stream"}
            )
            await response.prepare(request)
            loop = asyncio.get_running_loop()
            quiet_since = loop.time()
            async with hub.page() as queue:
                while True:
                    honour_cancellation()  # 3.11's wait_for may swallow it (cancellation.py)
                    try:
                        message = await asyncio.wait_for(queue.get(), STREAM_CHECK_S)
                    except TimeoutError:
                        if request.transport is None or request.transport.is_closing():
                            return response  # the page is gone: its slot is free again
                        if loop.time() - quiet_since >= KEEPALIVE_S:
                            await response.write(b": keepalive\n\n")
                            quiet_since = loop.time()
                        continue
                    if not message:  # the panel is shutting down
                        return response
                    await response.write(f"data: {message}\n\n".encode())
                    quiet_since = loop.time()
        finally:
            streams[0] -= 1

    @routes.get("/api/cuts")
    async def cuts(_request: web.Request) -> web.Response:
        return web.json_response([record.summary() for record in hub.history.records])

    @routes.get(r"/api/cuts/{number:\d+}")
    async def cut(request: web.Request) -> web.Response:
        record = hub.history.get(int(request.match_info["number"]))
        if record is None:
            raise web.HTTPNotFound(text="no such cut")
        return web.json_response({**record.summary(), "trace": record.trace})

    @routes.get(r"/api/cuts/{number:\d+}.csv")
    async def cut_csv(request: web.Request) -> web.Response:
        number = int(request.match_info["number"])
        record = hub.history.get(number)
        if record is None:
            raise web.HTTPNotFound(text="no such cut")
        return web.Response(
            text=record.as_csv(), content_type="text/csv",
            headers={"Content-Disposition": f'attachment; filename="cut-{number}.csv"'},
        )  # fmt: skip

    @routes.post("/api/login")
    async def login(request: web.Request) -> web.Response:
        """The page's token, once: answered with the cookie its requests carry from then on
        (an EventSource cannot set an Authorization header)."""
        args = await _read_json(request, limits)
        if isinstance(args, web.Response):
            return args
        given = args.get("token") if isinstance(args, dict) else None
        if check is None:
            return web.json_response({"ok": True, "data": {"token_required": False}})
        if not isinstance(given, str) or not check.matches(given):
            return _refuse(401, "the panel token is wrong")
        response = web.json_response({"ok": True, "data": {"token_required": True}})
        response.set_cookie(
            SESSION_COOKIE, check.cookie_value, httponly=True, samesite="Strict",
            secure=request.secure, path="/",
        )  # fmt: skip
        return response

    @routes.post("/api/control/{name}")
    async def control(request: web.Request) -> web.Response:
        name = request.match_info["name"]
        args = await _read_json(request, limits, name)
        if isinstance(args, web.Response):
            return args
        if not isinstance(args, dict):
            return _refuse(400, f"{name}: the body is not a JSON object")
        try:
            data = await hub.control(name, args)
        except (ControlError, DaemonError) as exc:
            return web.json_response({"ok": False, "error": str(exc)})
        except Exception as exc:  # a bug of ours: the page still gets its one answer
            log.exception("control_failed", name=name)
            return _refuse(500, f"{name}: the panel failed: {exc!r}")
        return web.json_response({"ok": True, "data": data})

    routes.static("/static", STATIC)
    app.add_routes(routes)
    return app


def _refuse(status: int, error: str) -> web.Response:
    return web.json_response({"ok": False, "error": error}, status=status)


async def _read_json(request: web.Request, limits: PanelLimits, name: str = "") -> Any:
    """The request's JSON body ({} when it has none), or the refusal to send: 400 naming the
    limit it breaks, 408 when it is not all there within BODY_TIMEOUT_S. A refused body may
    be left unread, so the connection closes after the answer."""
    prefix = f"{name}: " if name else ""
    body = bytearray()
    try:
        if (request.content_length or 0) > limits.max_json_bytes:
            raise BodyRefused(f"the body is over {limits.max_json_bytes} bytes (MAX_JSON_BYTES)")
        async with asyncio.timeout(limits.body_timeout_s):
            while chunk := await request.content.read(limits.max_json_bytes + 1 - len(body)):
                body += chunk
                if len(body) > limits.max_json_bytes:
                    break
        return parse_json_body(
            bytes(body), max_bytes=limits.max_json_bytes, max_depth=limits.max_json_depth
        )
    except BodyRefused as exc:
        refusal = _refuse(400, f"{prefix}{exc}")
    except TimeoutError:
        refusal = _refuse(408, f"{prefix}the body did not arrive within "
                          f"{limits.body_timeout_s:g} s (BODY_TIMEOUT_S)")  # fmt: skip
    refusal.force_close()
    return refusal


def _guard(allowed: HostAllowList, check: TokenCheck | None) -> Middleware:
    @web.middleware
    async def guard(request: web.Request, handler: Handler) -> web.StreamResponse:
        connection = request_started(request)
        try:
            refusal = _check_request(request, allowed, check)
            if refusal is None and request.method not in ("GET", "HEAD"):
                refusal = _check_post(request)
            response = refusal or await handler(request)
            if not response.prepared:
                response.headers.update(SECURITY_HEADERS)
            return response
        finally:
            if connection is not None:  # the next request's head has its deadline
                connection.wait_for_head()

    return guard


def _check_request(
    request: web.Request, allowed: HostAllowList, check: TokenCheck | None
) -> web.Response | None:
    """Why any request is refused (None: it may go on): a Host the panel was not told of
    (421), an Origin it was not told of (403), no token where one is needed (401)."""
    host = request.headers.get("Host", "")
    if not allowed.allows_host(host):
        return _refuse(421, f"this panel is not served as {host!r} (--allow-host NAME)")
    origin = request.headers.get("Origin")
    if origin is not None and not allowed.allows_origin(origin):
        return _refuse(403, f"cross-site request refused (Origin {origin})")
    public = request.path in PUBLIC_PATHS or request.path.startswith(PUBLIC_PREFIX)
    if check is not None and not public:
        given = request.headers.get("Authorization", "")
        if not check.allows(given, request.cookies.get(SESSION_COOKIE)):
            return _refuse(401, "a valid panel token is required")
    return None


def _check_post(request: web.Request) -> web.Response | None:
    """Why a state-changing request is refused (None: it may go on)."""
    if request.headers.get(PANEL_HEADER) != "1":
        return _refuse(403, f"the {PANEL_HEADER} header is missing: requests come from the panel")
    if request.content_type != "application/json":
        return _refuse(415, "controls take a JSON body (application/json)")
    return None
