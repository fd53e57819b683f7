"""The monitor's web side: a starlette app serving the page, its static assets (shipped in the
package) and one server-sent-events stream of batched changes.

Every batch is one JSON object: ``ts`` (the server's time, ms since the epoch), ``v`` (the
fleet version it brings the page to), ``stats`` (events taken and what was dropped, by why),
and either ``snapshot`` (the whole state: a page's first batch, or one that fell behind) or
``changes``. Batches go out every :data:`BATCH` seconds at most, so a busy fleet costs the
browser one update a tenth of a second, however many events arrive. ``/api/state`` is the
whole state once, as JSON, for scripts (``ktbt fleet run --monitor`` reads it to check that
what the page shows is what the peers' logs say).

The page is built with text nodes only; a Content-Security-Policy allowing no inline script,
no other origin and no framing is sent as well, so even markup that slipped into the DOM
could not run.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from ktbt_proto.tools.monitor.state import FleetState

STATIC = Path(__file__).resolve().parent / "static"
BATCH = 0.1
"""Seconds between two batches to one page."""
HEADERS = {
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
        "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


class _Headers:
    """Adds :data:`HEADERS` to every response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                extra = [(k.lower().encode(), v.encode()) for k, v in HEADERS.items()]
                message["headers"] = [*message.get("headers", []), *extra]
            await send(message)

        await self.app(scope, receive, with_headers)


class _HostCheck:
    """The Host check (against DNS rebinding) on connections over TCP. One over a unix socket
    (``--uds``; no client address) comes from a process on this machine, never from a page in
    a browser, and passes whatever Host it names."""

    def __init__(self, app: ASGIApp, allowed_hosts: list[str]) -> None:
        self.app = app
        self.checked = TrustedHostMiddleware(app, allowed_hosts=allowed_hosts)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket") and not scope.get("client"):
            await self.app(scope, receive, send)
        else:
            await self.checked(scope, receive, send)


def create_app(
    fleet: FleetState,
    hosts: list[str] | None = None,
    tree: Callable[[str], str | None] | None = None,
    stopping: Callable[[], bool] = lambda: False,
) -> Starlette:
    """The app over ``fleet``. ``hosts``: the Host headers accepted (the loopback names when
    bound to loopback, so another site's page cannot reach it by DNS rebinding); ``None``:
    any. ``tree``: a peer's control tree as text (``Listener.tree``), served on
    ``/api/tree/<peer>`` and fetched in a worker thread, never blocking the event loop. The
    fleet is read in worker threads too: its lock is taken by zenoh's callbacks, and a page
    must never freeze the others while one holds it. ``stopping``: true once the server is
    stopping; an open page's stream then ends within a batch, so the stop neither waits for
    the page nor cancels its stream (uvicorn logs that as an error with a traceback)."""

    async def peer_tree(request: Request) -> Response:
        name = request.path_params["peer"]
        text = await asyncio.to_thread(tree, name) if tree is not None else None
        return JSONResponse({"peer": name, "tree": text})

    async def whole_state(request: Request) -> Response:
        version, snapshot = await asyncio.to_thread(fleet.snapshot)
        stats = await asyncio.to_thread(fleet.stats)
        return JSONResponse({"v": version, "stats": stats, **snapshot})

    async def index(request: Request) -> Response:
        return FileResponse(STATIC / "index.html", media_type="text/html; charset=utf-8")

    async def stream(request: Request) -> Response:
        async def batches() -> AsyncIterator[str]:
            version: int | None = None
            yield "retry: 1000\n\n"
            while not stopping():
                body: dict[str, object]
                if version is not None:
                    reached, changes = await asyncio.to_thread(fleet.changes_since, version)
                if version is None or changes is None:
                    version, state = await asyncio.to_thread(fleet.snapshot)
                    body = {"snapshot": state}
                elif changes:
                    version, body = reached, {"changes": changes}
                else:
                    body = {}
                stats = await asyncio.to_thread(fleet.stats)
                body.update(ts=int(time.time() * 1000), v=version, stats=stats)
                yield f"data: {json.dumps(body, separators=(',', ':'))}\n\n"
                await asyncio.sleep(BATCH)

        return StreamingResponse(batches(), media_type="text/event-stream")

    middleware = [Middleware(_Headers)]
    if hosts is not None:
        middleware.append(Middleware(_HostCheck, allowed_hosts=hosts))
    return Starlette(
        routes=[
            Route("/", index),
            Route("/api/stream", stream),
            Route("/api/state", whole_state),
            Route("/api/tree/{peer}", peer_tree),
            Mount("/static", StaticFiles(directory=STATIC), name="static"),
        ],
        middleware=middleware,
    )
