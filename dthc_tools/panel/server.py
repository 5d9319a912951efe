"""The panel's web side (aiohttp): the page, its live stream, its controls, the cut history.

    GET  /                       the page (static HTML, CSS and our own JavaScript)
    GET  /events                 server-sent events: {"kind": "view"|"telemetry"|..., "data"}
    GET  /api/view               the live view now (links, state, progress, controls enabled)
    GET  /api/cuts               the cut history, newest last (summaries)
    GET  /api/cuts/{n}           one cut with its trace;  /api/cuts/{n}.csv  as CSV
    POST /api/control/{name}     press a control: {"ok": true, "data"} or {"ok": false, "error"}

No GET changes anything. A POST must be same-origin JSON with the panel's own header (a
form or script of another site can send neither without a CORS preflight, which is never
granted), and carry the token when one is configured (required off localhost)."""

from __future__ import annotations

import asyncio
import hmac
from collections.abc import Awaitable, Callable
from pathlib import Path
from urllib.parse import urlsplit

import structlog
from aiohttp import web
from aiohttp.typedefs import Middleware

from dthc_tools.sender.daemon_client import DaemonError

from .controls import ControlError
from .hub import PanelHub

__all__ = ["PANEL_HEADER", "build_app"]

log = structlog.get_logger("dthc_tools.panel.server")

STATIC = Path(__file__).with_name("static")
PANEL_HEADER = "X-DTHC-Panel"  # a custom header: cross-site requests cannot set it unasked
KEEPALIVE_S = 15.0  # a comment line on an idle stream, so proxies and browsers keep it
MAX_BODY_BYTES = 16_384
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


def build_app(hub: PanelHub, *, token: str | None) -> web.Application:
    app = web.Application(middlewares=[_guard(token)], client_max_size=MAX_BODY_BYTES)
    routes = web.RouteTableDef()

    @routes.get("/")
    async def index(_request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html")

    @routes.get("/api/view")
    async def view(_request: web.Request) -> web.Response:
        return web.json_response({**hub.snapshot(), "token_required": token is not None})

    @routes.get("/events")
    async def events(request: web.Request) -> web.StreamResponse:
        response = web.StreamResponse(
            headers={**SECURITY_HEADERS, "Content-Type": "text/event-stream"}
        )
        await response.prepare(request)
        async with hub.page() as queue:
            while True:
                try:
                    message = await asyncio.wait_for(queue.get(), KEEPALIVE_S)
                except TimeoutError:
                    await response.write(b": keepalive\n\n")
                    continue
                if not message:  # the panel is shutting down
                    return response
                await response.write(f"data: {message}\n\n".encode())

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

    @routes.post("/api/control/{name}")
    async def control(request: web.Request) -> web.Response:
        name = request.match_info["name"]
        try:
            args = await request.json() if request.can_read_body else {}
        except ValueError:
            return _refuse(400, f"{name}: the body is not JSON")
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


def _guard(token: str | None) -> Middleware:
    @web.middleware
    async def guard(request: web.Request, handler: Handler) -> web.StreamResponse:
        if request.method not in ("GET", "HEAD"):
            refusal = _check_post(request, token)
            if refusal is not None:
                return refusal
        response = await handler(request)
        if not response.prepared:
            response.headers.update(SECURITY_HEADERS)
        return response

    return guard


def _check_post(request: web.Request, token: str | None) -> web.Response | None:
    """Why a state-changing request is refused (None: it may go on)."""
    origin = request.headers.get("Origin")
    if origin is not None and urlsplit(origin).netloc != request.host:
        return _refuse(403, f"cross-site request refused (Origin {origin})")
    if request.headers.get(PANEL_HEADER) != "1":
        return _refuse(403, f"the {PANEL_HEADER} header is missing: requests come from the panel")
    if request.content_type != "application/json":
        return _refuse(415, "controls take a JSON body (application/json)")
    if token is not None:
        scheme, _, given = request.headers.get("Authorization", "").partition(" ")
        if scheme != "Bearer" or not hmac.compare_digest(given.encode(), token.encode()):
            return _refuse(401, "a valid panel token is required for controls")
    return None
