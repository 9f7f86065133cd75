"""The HTTP and WebSocket front of the bench service (FastAPI; docs/decisions/0081).

Every endpoint is under :data:`~instrument.protocol.API_PREFIX`; the OpenAPI schema is at
``/openapi.json`` and the event messages' schema at ``/api/v1/events/schema``.

Order of checks for every request, so that a refused one changes nothing: the body's size
(413), the key (401), the role (403), the body's shape (422, by the models below), the
control lease (409), then the service's own checks (guard, queue state), which raise
before they act. Every state-changing request (any method but GET) is written to the
audit log with who, what, the status and the result, refused ones included.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
import weakref
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Annotated, Any, Literal, cast

from fastapi import Depends, FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.types import Message as ASGIMessage

from instrument.protocol import API_PREFIX, PROTOCOL_VERSION, Message, encode, role_allows
from instrument.run.catalog import Catalog
from instrument.server.audit import AuditLog
from instrument.server.dashboard import install_dashboard
from instrument.server.db import SERVER_DB_NAME
from instrument.server.fanout import LoopFanout, RawSink
from instrument.server.hub import ClientBuffer
from instrument.server.keys import KeyStore
from instrument.server.plans import MAX_PLAN_BYTES
from instrument.server.points import MAX_POINTS_PAGE, RunPoints
from instrument.server.service import BenchService, Caller, ServiceError

__all__ = ["MAX_BODY_BYTES", "create_app"]

#: The largest request body accepted (a plan text at its limit, with JSON's escaping).
MAX_BODY_BYTES = MAX_PLAN_BYTES + (1 << 20)

_Name = Annotated[str, Field(min_length=1, max_length=200)]
_Role = Annotated[str, Field(min_length=1, max_length=40)]


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class AddItem(_Body):
    """A plan (its TOML text) or, with ``stop``, a stop marker."""

    plan: Annotated[str, Field(max_length=MAX_PLAN_BYTES)] | None = None
    name: _Name | None = None
    stop: bool = False


class Propose(_Body):
    plan: Annotated[str, Field(min_length=1, max_length=MAX_PLAN_BYTES)]
    name: _Name | None = None


class MoveItem(_Body):
    index: Annotated[int, Field(ge=0, le=1_000_000)]


class PauseBody(_Body):
    now: bool = False


class ResumeBody(_Body):
    answer: Literal["resume", "retry", "skip"] = "resume"


class RoleBody(_Body):
    role: _Role


class JogBody(_Body):
    role: _Role
    step: Annotated[float, Field(allow_inf_nan=False)]


class MoveBody(_Body):
    targets: Annotated[dict[_Role, Annotated[float, Field(allow_inf_nan=False)]],
                       Field(min_length=1, max_length=16)]


class LightBody(_Body):
    on: bool


class CameraBody(_Body):
    """Camera settings to change (at least one); each is checked against the camera's
    own range by its driver."""

    exposure_us: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    gain: Annotated[float, Field(allow_inf_nan=False)] | None = None


_SettingValue = bool | int | float | str


class DeviceSettingsBody(_Body):
    """Fields of one device to set, in the order to apply them (``instrument.server.
    device_settings`` lists them by device kind); an action (``auto_range``, ``zero``)
    takes ``true``."""

    changes: Annotated[dict[Annotated[str, Field(min_length=1, max_length=40)],
                            _SettingValue], Field(min_length=1, max_length=8)]


class TakeControl(_Body):
    timeout_s: Annotated[float, Field(gt=0, le=86400)] | None = None
    force: bool = False


class AddKey(_Body):
    name: _Name
    role: Literal["observer", "operator", "admin"]
    expires: Annotated[float, Field(gt=0)] | None = None


class _SizeLimit:
    """Refuse bodies over ``limit`` bytes (413) before any handler reads them, whether
    the client declared the length or sent it in chunks."""

    def __init__(self, app: ASGIApp, limit: int,
                 on_refuse: Callable[[str, str], object] | None = None) -> None:
        self.app = app
        self.limit = limit
        self.on_refuse = on_refuse

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.limit):
            return await self._refuse(scope, send)
        chunks: list[bytes] = []
        total = 0
        while True:
            msg = await receive()
            if msg["type"] != "http.request":
                break
            total += len(msg.get("body", b""))
            if total > self.limit:
                return await self._refuse(scope, send)
            chunks.append(msg.get("body", b""))
            if not msg.get("more_body"):
                break
        body = b"".join(chunks)
        done = False

        async def replay() -> ASGIMessage:
            nonlocal done
            if not done:
                done = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()
        return await self.app(scope, replay, send)

    async def _refuse(self, scope: Scope, send: Send) -> None:
        resp = JSONResponse({"detail": f"request body over {self.limit} bytes"}, 413)
        if self.on_refuse is not None:
            await asyncio.to_thread(self.on_refuse, scope["method"], scope["path"])
        await resp(scope, _empty_receive, send)


class _KeepSend:
    """Keep the ASGI server's own ``send`` of a WebSocket connection in its scope, before
    any middleware wraps it: the event stream writes frames to the connection's transport
    when the server is uvicorn (:class:`~instrument.server.fanout.RawSink`)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            scope[_RAW_SEND] = send
        await self.app(scope, receive, send)


_RAW_SEND = "scatterlab.server_send"


async def _empty_receive() -> ASGIMessage:
    return {"type": "http.disconnect"}


def create_app(service: BenchService, *, open_local: bool = True) -> FastAPI:
    """The application for ``service``.

    ``open_local``: when no valid key exists, every request acts as the local admin
    ("local"). Only for a server bound to loopback (``scatterlab serve`` refuses any other
    address without keys); as soon as one key exists, every request needs one.
    """
    keys = KeyStore(service.db)
    audit = AuditLog(service.db)
    run_points = RunPoints()
    service.hub.listen(run_points.on_message)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        yield
        await asyncio.to_thread(service.close)

    app = FastAPI(title="scatterlab bench server", version=str(PROTOCOL_VERSION),
                  lifespan=lifespan,
                  description="One process owns the bench: a plan queue, run control, "
                  "manual moves through the guard, and an event stream at "
                  f"{API_PREFIX}/events (WebSocket; message schema at "
                  f"{API_PREFIX}/events/schema).")

    def identify(authorization: str | None) -> tuple[Caller | None, str]:
        """The caller a header names, or None and why not."""
        if authorization is None or not authorization.startswith("Bearer "):
            if open_local and not keys.any_valid():
                return Caller("local", "admin"), ""
            return None, "no key: send 'Authorization: Bearer KEY'"
        key = keys.check(authorization[len("Bearer "):].strip())
        if key is None:
            return None, "wrong, revoked or expired key"
        return Caller(key.name, key.role), ""

    def need(role: str) -> Any:  # FastAPI's Depends marker
        def dep(request: Request) -> Caller:
            caller, why = identify(request.headers.get("authorization"))
            if caller is None:
                request.state.audit_who = ("(no valid key)", "")
                raise ServiceError(401, why)
            request.state.audit_who = (caller.name, caller.role)
            if not role_allows(caller.role, role):
                raise ServiceError(403, f"{caller.role} keys may not do this ({role} or "
                                   "higher is needed)")
            return caller
        return Depends(dep)

    @app.exception_handler(ServiceError)
    async def service_error(request: Request, err: ServiceError) -> JSONResponse:
        request.state.audit_result = err.message
        body: dict[str, Any] = {"detail": err.message}
        if err.reasons:
            body["reasons"] = err.reasons
        headers = {"WWW-Authenticate": "Bearer"} if err.status == 401 else None
        return JSONResponse(body, err.status, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, err: RequestValidationError) -> JSONResponse:
        reasons = [f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in err.errors()]
        request.state.audit_result = "malformed request: " + "; ".join(reasons)[:300]
        return JSONResponse({"detail": "malformed request", "reasons": reasons}, 422)

    @app.middleware("http")
    async def audited(request: Request,
                      call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        response = await call_next(request)
        if request.method not in ("GET", "HEAD", "OPTIONS"):
            who, role = getattr(request.state, "audit_who", ("(no valid key)", ""))
            result = getattr(request.state, "audit_result", "") or (
                "ok" if response.status_code < 400 else "refused")
            await asyncio.to_thread(audit.write, who, role,
                                    f"{request.method} {request.url.path}",
                                    response.status_code, result)
        return response

    app.add_middleware(_SizeLimit, limit=MAX_BODY_BYTES, on_refuse=lambda method, path:
                       audit.write("(unchecked)", "", f"{method} {path}", 413,
                                   "body too large"))
    app.add_middleware(_KeepSend)
    fanouts: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, LoopFanout] = \
        weakref.WeakKeyDictionary()
    app.state.fanouts = fanouts  # the event stream's clients, by event loop (tests look)

    def ctl(request: Request, caller: Caller) -> None:
        """Refuse (409) when another operator holds control; the lease is taken or renewed
        only when the request succeeds (:func:`done`), so a refused one leaves it as it was."""
        service.check_control(caller)
        request.state.lease_for = caller

    def done(request: Request, message: str, **extra: Any) -> dict[str, Any]:
        request.state.audit_result = message
        caller = getattr(request.state, "lease_for", None)
        if caller is not None:
            service.take_control(caller)
        return {"ok": True, "message": message, **extra}

    p = API_PREFIX
    observer, operator, admin = need("observer"), need("operator"), need("admin")
    control = need("operator")  # and the control lease, checked in the handler

    # queries ------------------------------------------------------------------------
    @app.get(f"{p}/status")
    def status(caller: Caller = observer) -> dict[str, Any]:
        return {"protocol": PROTOCOL_VERSION, "you": {"name": caller.name,
                                                      "role": caller.role},
                **service.status()}

    @app.get(f"{p}/queue")
    def queue_list(caller: Caller = observer) -> dict[str, Any]:
        return {"running": service.queue_running,
                "items": [i.summary() for i in service.queue.items()]}

    @app.get(f"{p}/queue/history")
    def history(limit: int = 200, caller: Caller = observer) -> list[dict[str, Any]]:
        return [vars(h) for h in service.queue.history(max(1, min(limit, 10_000)))]

    @app.get(f"{p}/runs")
    def runs(limit: int = 100, caller: Caller = observer) -> list[dict[str, Any]]:
        with Catalog(service.runs_dir) as cat:
            cat.refresh_live()
            return [vars(r) for r in cat.find(limit=max(1, min(limit, 10_000)))]

    @app.get(f"{p}/runs/files/{{path:path}}")
    def run_file(path: str, caller: Caller = observer) -> FileResponse:
        target = (service.runs_dir / path).resolve()
        if not target.is_relative_to(service.runs_dir) or \
                target.name.startswith(SERVER_DB_NAME):
            raise ServiceError(403, f"{path}: outside the runs folder; only files under "
                               f"{service.runs_dir} may be read")
        if not target.is_file():
            raise ServiceError(404, f"{path}: no such file in the runs folder")
        return FileResponse(target, filename=target.name)

    @app.get(f"{p}/runs/current/points")
    def current_points(since: int = 0, limit: int = MAX_POINTS_PAGE,
                       caller: Caller = observer) -> dict[str, Any]:
        """The current run's points published so far, from ordinal ``since`` (a client
        that connects mid-run draws the plot from the first point; see
        :mod:`instrument.server.points`)."""
        return run_points.page(since, limit)

    @app.get(f"{p}/events/schema")
    def events_schema(caller: Caller = observer) -> dict[str, Any]:
        from instrument.protocol import schema
        return schema()

    @app.get(f"{p}/bench/profile")
    def bench_profile(caller: Caller = observer) -> dict[str, Any]:
        """The bench profile's text: a client builds and dry-runs plans against it."""
        return {"name": service.profile.name, "text": service.profile.source_text}

    @app.get(f"{p}/control")
    def control_get(caller: Caller = observer) -> dict[str, Any]:
        return cast(dict[str, Any], service.status()["control"])

    # queue --------------------------------------------------------------------------
    @app.post(f"{p}/queue")
    def queue_add(body: AddItem, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        if body.stop:
            if body.plan is not None:
                raise ServiceError(422, "give either a plan or stop, not both")
            item = service.add_stop(caller)
        elif body.plan is None:
            raise ServiceError(422, "give a plan (its TOML text) or stop = true")
        else:
            item = service.add_plan(caller, body.plan, body.name)
        return done(request, f"added item {item.id} ({item.name})", item=item.summary())

    @app.post(f"{p}/queue/propose")
    def queue_propose(body: Propose, request: Request, caller: Caller = observer) -> dict[str, Any]:
        item = service.add_plan(caller, body.plan, body.name, propose=True)
        return done(request, f"proposed item {item.id} ({item.name}); an operator approves "
                    "or denies it", item=item.summary())

    @app.post(f"{p}/queue/{{item_id}}/approve")
    def queue_approve(item_id: int, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        item = service.approve(caller, item_id)
        return done(request, f"approved item {item.id} ({item.name})", item=item.summary())

    @app.post(f"{p}/queue/{{item_id}}/deny")
    def queue_deny(item_id: int, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        item = service.deny(caller, item_id)
        return done(request, f"denied item {item.id} ({item.name})")

    @app.post(f"{p}/queue/{{item_id}}/move")
    def queue_move(item_id: int, body: MoveItem, request: Request,
                   caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        item = service.move_item(caller, item_id, body.index)
        return done(request, f"moved item {item.id} to place {body.index}")

    @app.delete(f"{p}/queue/{{item_id}}")
    def queue_remove(item_id: int, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        item = service.remove(caller, item_id)
        return done(request, f"removed item {item.id} ({item.name})")

    @app.post(f"{p}/queue/start")
    def queue_start(request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        service.start_queue(caller)
        return done(request, "queue started")

    @app.post(f"{p}/queue/stop")
    def queue_stop(request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        service.stop_queue(caller)
        return done(request, "queue stopped: the run in progress goes on to its end")

    # run control --------------------------------------------------------------------
    @app.post(f"{p}/run/pause")
    def run_pause(request: Request, body: PauseBody | None = None,
                  caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.pause(caller, now=bool(body and body.now)))

    @app.post(f"{p}/run/resume")
    def run_resume(request: Request, body: ResumeBody | None = None,
                   caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.resume(caller, body.answer if body else "resume"))

    @app.post(f"{p}/run/abort")
    def run_abort(request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.abort(caller))

    # manual commands ----------------------------------------------------------------
    @app.post(f"{p}/bench/home")
    def bench_home(body: RoleBody, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.home(caller, body.role))

    @app.post(f"{p}/bench/jog")
    def bench_jog(body: JogBody, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.jog(caller, body.role, body.step))

    @app.post(f"{p}/bench/move")
    def bench_move(body: MoveBody, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.move_axes(caller, dict(body.targets)))

    @app.post(f"{p}/bench/light")
    def bench_light(body: LightBody, request: Request, caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.light(caller, body.on))

    @app.post(f"{p}/bench/camera")
    def bench_camera(body: CameraBody, request: Request,
                     caller: Caller = control) -> dict[str, Any]:
        ctl(request, caller)
        return done(request, service.camera_settings(caller, exposure_us=body.exposure_us,
                                                     gain=body.gain))

    @app.post(f"{p}/bench/devices/{{role}}/settings", status_code=202)
    def bench_device_settings(role: str, body: DeviceSettingsBody, request: Request,
                              caller: Caller = control) -> dict[str, Any]:
        """Change a lock-in's, filter wheel's or power meter's settings between runs. The
        answer (202) comes at once with ``request_id``; the ``device_settings`` event with
        that id says when the change is applied or why it failed (a wheel move or an
        auto-range takes seconds)."""
        ctl(request, caller)
        accepted = service.device_settings(caller, role, body.changes)
        return done(request, accepted["message"], request_id=accepted["request_id"])

    @app.post(f"{p}/bench/stop-all")
    def bench_stop_all(request: Request, caller: Caller = operator) -> dict[str, Any]:
        # any operator, whoever holds control: the safety path is never refused
        return done(request, service.stop_all(caller))

    @app.post(f"{p}/bench/connect")
    def bench_connect(request: Request, caller: Caller = admin) -> dict[str, Any]:
        return done(request, service.connect(caller))

    @app.post(f"{p}/bench/disconnect")
    def bench_disconnect(request: Request, caller: Caller = admin) -> dict[str, Any]:
        return done(request, service.disconnect(caller))

    # control lease ------------------------------------------------------------------
    @app.post(f"{p}/control/take")
    def control_take(request: Request, body: TakeControl | None = None,
                     caller: Caller = operator) -> dict[str, Any]:
        lease = service.take_control(caller, force=bool(body and body.force),
                                     timeout_s=body.timeout_s if body else None)
        return done(request, f"control held by {lease['holder']}", **lease)

    @app.post(f"{p}/control/release")
    def control_release(request: Request, caller: Caller = operator) -> dict[str, Any]:
        service.release_control(caller)
        return done(request, "control released")

    # keys and audit -----------------------------------------------------------------
    @app.get(f"{p}/keys")
    def keys_list(caller: Caller = admin) -> list[dict[str, Any]]:
        now = time.time()
        return [{**vars(k), "state": k.state(now)} for k in keys.list()]

    @app.post(f"{p}/keys")
    def keys_add(body: AddKey, request: Request, caller: Caller = admin) -> dict[str, Any]:
        try:
            key, token = keys.add(body.name, body.role, expires=body.expires)
        except ValueError as err:
            raise ServiceError(422, str(err)) from err
        return done(request, f"key {key.id} for {key.name} ({key.role}) added", id=key.id,
                    token=token)

    @app.delete(f"{p}/keys/{{key_id}}")
    def keys_revoke(key_id: int, request: Request, caller: Caller = admin) -> dict[str, Any]:
        try:
            key = keys.revoke(key_id)
        except KeyError as err:
            raise ServiceError(404, str(err.args[0])) from err
        return done(request, f"key {key.id} of {key.name} revoked")

    @app.get(f"{p}/audit")
    def audit_rows(limit: int = 200, caller: Caller = admin) -> list[dict[str, Any]]:
        return [vars(r) for r in audit.rows(limit=max(1, min(limit, 100_000)))]

    # event stream -------------------------------------------------------------------
    @app.websocket(f"{p}/events")
    async def events(ws: WebSocket) -> None:
        caller, why = await asyncio.to_thread(identify, ws.headers.get("authorization"))
        if caller is None:
            await ws.close(code=1008, reason=why)  # refused before the handshake: HTTP 403
            return
        await ws.accept()
        loop = asyncio.get_running_loop()
        sink = RawSink.of(ws.scope.get(_RAW_SEND))
        if sink is not None:  # uvicorn: one flush per batch writes every client's frames
            fanout = fanouts.get(loop)
            if fanout is None:
                fanout = fanouts[loop] = LoopFanout(loop)
            buf = ClientBuffer(wake=fanout.request)
        else:  # another ASGI server: a task per client, a send per message
            wake = asyncio.Event()
            buf = ClientBuffer(wake=lambda: loop.call_soon_threadsafe(wake.set))
        service.hub.attach(buf)
        try:
            st = await asyncio.to_thread(service.status)
            await ws.send_text(encode(Message(0, "hello", time.time(), {
                "protocol": PROTOCOL_VERSION, "bench": service.profile.name,
                "role": caller.role, "name": caller.name, "status": st})))
            closed = asyncio.ensure_future(_until_closed(ws))
            if sink is not None:
                cut = asyncio.Event()
                fanout.add(buf, sink, cut.set)  # what came since the hello goes out now
                waiter = asyncio.ensure_future(cut.wait())
                await asyncio.wait({waiter, closed}, return_when=asyncio.FIRST_COMPLETED)
                waiter.cancel()
                if cut.is_set():
                    await ws.close(code=1013, reason="fell too far behind: reconnect")
            while sink is None and not closed.done():
                waiter = asyncio.ensure_future(wake.wait())
                await asyncio.wait({waiter, closed}, return_when=asyncio.FIRST_COMPLETED)
                waiter.cancel()
                wake.clear()
                if buf.cut_off:
                    await ws.close(code=1013, reason="fell too far behind: reconnect")
                    break
                for text in buf.take():
                    await ws.send_text(text)
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass  # the client went away: nothing to tell it; its buffer is detached below
        finally:
            if sink is not None:
                fanout.remove(buf)
            service.hub.detach(buf)

    install_dashboard(app, service, observer)  # the web page at / (docs/decisions/0085)
    return app


async def _until_closed(ws: WebSocket) -> None:
    """Read (and ignore) what the client sends until it goes away."""
    with contextlib.suppress(WebSocketDisconnect, RuntimeError):
        while True:
            msg = await ws.receive()
            if msg["type"] == "websocket.disconnect":
                return

