"""The bench server's web dashboard (docs/decisions/0085): a page at the server's root URL
that watches and steers runs over the same ``/api/v1`` API and keys as every client.

What is served, and from where:

* ``/`` and ``/dashboard/static/...``: the page itself (plain HTML, CSS and JavaScript in
  this package's ``static/`` folder; no build step);
* ``/dashboard/bokeh/...``: BokehJS, the plotting library, from the installed ``bokeh``
  package's own files (nothing is fetched from the internet; a lab network often has no
  route to it). Without ``bokeh`` the page says how to install it (HTTP 503);
* ``/api/v1/bench/axes`` (observer key): each axis's units and limits, for the device
  table (the ``devices`` messages carry bare numbers).

Nothing here grants access: the page and its scripts are public (they hold no data), and
every request the page makes carries the key the user signed in with. A browser cannot put
an ``Authorization`` header on a WebSocket, so :class:`BrowserKeys` lets the page offer its
key as a WebSocket subprotocol (``bearer.KEY`` beside ``scatterlab.v1``) and turns it into
that header before the event stream's own check; the key is never put in a URL, where
proxies and browser history would keep it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import FastAPI, HTTPException
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from instrument.protocol import API_PREFIX

if TYPE_CHECKING:
    from instrument.server.service import BenchService

__all__ = ["STATIC", "SUBPROTOCOL", "BrowserKeys", "bokeh_js_dir", "install_dashboard"]

#: The page's own files.
STATIC = Path(__file__).resolve().parent / "static"
#: The subprotocol the page asks for; the server's answer names it.
SUBPROTOCOL = "scatterlab.v1"
_BEARER = "bearer."
#: BokehJS files the page loads (the core and its plain-JavaScript plotting API).
BOKEH_FILES = ("bokeh.min.js", "bokeh-api.min.js")
_TYPES = {".js": "text/javascript", ".css": "text/css", ".html": "text/html",
          ".svg": "image/svg+xml", ".png": "image/png"}


def bokeh_js_dir() -> Path | None:
    """The folder of BokehJS inside the installed ``bokeh`` package (None: not installed).
    Found without importing bokeh, which would cost the server a second of start-up."""
    spec = importlib.util.find_spec("bokeh")
    if spec is None or not spec.submodule_search_locations:
        return None
    folder = Path(next(iter(spec.submodule_search_locations))) / "server" / "static" / "js"
    return folder if all((folder / f).is_file() for f in BOKEH_FILES) else None


def _served(folder: Path, name: str) -> FileResponse:
    """``folder/name`` when it is a file inside ``folder`` (404 otherwise)."""
    target = (folder / name).resolve()
    if not target.is_relative_to(folder.resolve()) or not target.is_file():
        raise HTTPException(404, f"{name}: no such file")
    return FileResponse(target, media_type=_TYPES.get(target.suffix, "application/octet-stream"),
                        headers={"Cache-Control": "no-cache"})


MISSING_BOKEH = """<!doctype html><meta charset="utf-8"><title>scatterlab dashboard</title>
<h1>The dashboard needs Bokeh</h1>
<p>This server's Python has no <code>bokeh</code> package, which draws the dashboard's plots.
Install it into the server's environment (<code>pip install "bokeh>=3.1"</code>, or
reinstall scatterlab) and restart <code>scatterlab serve</code>. The API under
<code>/api/v1</code> and every other client work without it.</p>"""


def install_dashboard(app: FastAPI, service: BenchService, observer: Any) -> None:
    """Add the page's routes to ``app`` and wrap it in :class:`BrowserKeys`.

    ``service`` is the :class:`~instrument.server.service.BenchService`; ``observer`` the
    dependency that admits observer keys and above (the app's own)."""
    bokeh = bokeh_js_dir()

    @app.get(f"{API_PREFIX}/bench/axes", tags=["dashboard"])
    def bench_axes(caller: Any = observer) -> dict[str, Any]:
        """Each axis's units and soft limits, for labelling positions (the units are the
        driver's, known while the bench is connected; the limits are the profile's)."""
        bench = service.bench
        out = {}
        for role, spec in service.profile.axes.items():
            axis = bench.axes.get(role) if bench is not None else None
            out[role] = {"units": axis.units if axis is not None else None,
                         "limits": list(spec.limits) if spec.limits else None}
        return {"bench": service.profile.name, "axes": out}

    @app.get("/", include_in_schema=False)
    def root() -> RedirectResponse:
        return RedirectResponse("/dashboard/")

    @app.get("/dashboard/", include_in_schema=False)
    def page() -> Response:
        if bokeh is None:
            return HTMLResponse(MISSING_BOKEH, 503)
        return _served(STATIC, "index.html")

    @app.get("/dashboard/static/{name:path}", include_in_schema=False)
    def static(name: str) -> FileResponse:
        return _served(STATIC, name)

    @app.get("/dashboard/bokeh/{name}", include_in_schema=False)
    def bokeh_js(name: str) -> FileResponse:
        if bokeh is None or name not in BOKEH_FILES:
            raise HTTPException(404, f"{name}: not served (bokeh is "
                                f"{'missing' if bokeh is None else 'installed'})")
        return _served(bokeh, name)

    app.add_middleware(BrowserKeys)


class BrowserKeys:
    """ASGI middleware: a WebSocket that offers the subprotocols ``scatterlab.v1`` and
    ``bearer.KEY`` gets ``Authorization: Bearer KEY`` added to its request (unless it sent
    one), and the server's acceptance names ``scatterlab.v1`` (a browser drops a connection
    whose answer names none of the subprotocols it offered). Every other request passes
    through untouched; the key is checked exactly as in a header."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        offered = (scope.get("subprotocols") or []) if scope["type"] == "websocket" else []
        if SUBPROTOCOL not in offered:
            return await self.app(scope, receive, send)
        headers = list(scope.get("headers") or [])
        keys = [p[len(_BEARER):] for p in offered if p.startswith(_BEARER)]
        if keys and not any(k == b"authorization" for k, _ in headers):
            headers.append((b"authorization", f"Bearer {keys[0]}".encode("latin-1")))
        scope = {**scope, "headers": headers,
                 "subprotocols": [p for p in offered if not p.startswith(_BEARER)]}

        async def answer(message: Message) -> None:
            if message["type"] == "websocket.accept" and not message.get("subprotocol"):
                message = {**message, "subprotocol": SUBPROTOCOL}
            await send(message)
        return await self.app(scope, receive, answer)
