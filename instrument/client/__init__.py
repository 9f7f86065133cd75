"""The bench server's Python client: Qt-free, usable from the CLI, the GUI and a notebook.

>>> from instrument.client import BenchClient
>>> with BenchClient("http://127.0.0.1:8765", key="sl_...") as bench:
...     bench.add_plan(open("examples/brdf_inplane.toml").read())
...     bench.start_queue()
...     for msg in bench.events():
...         if msg.type == "run_finished":
...             break

The address and key default to the ``SCATTERLAB_SERVER`` and ``SCATTERLAB_KEY``
environment variables. Every refusal raises :class:`ClientError` with the server's status,
its sentence and its reasons; nothing else is raised for an answer the server gave.
"""

from __future__ import annotations

import os
import ssl
from collections.abc import Iterator
from typing import Any, cast

import httpx

from instrument.protocol import API_PREFIX, Message, decode

__all__ = ["ENV_KEY", "ENV_SERVER", "BenchClient", "ClientError", "EventStream",
           "server_from_env"]

ENV_SERVER = "SCATTERLAB_SERVER"
ENV_KEY = "SCATTERLAB_KEY"
#: CA bundle to trust for a server whose certificate is self-signed.
ENV_CA = "SCATTERLAB_CA"


def server_from_env() -> str | None:
    return os.environ.get(ENV_SERVER) or None


class ClientError(RuntimeError):
    """The server refused or failed a request (``status`` 0: it could not be reached)."""

    def __init__(self, status: int, message: str, reasons: list[str] | None = None) -> None:
        self.status = status
        self.message = message
        self.reasons = list(reasons or [])
        lines = "".join(f"\n  - {r}" for r in self.reasons)
        super().__init__(f"{message}{lines}" if status == 0 else
                         f"{message} (HTTP {status}){lines}")


class BenchClient:
    """A connection to a bench server at ``url`` (``http://host:port`` or ``https://…``)."""

    def __init__(self, url: str | None = None, key: str | None = None, *,
                 timeout_s: float = 30.0, ca: str | None = None) -> None:
        url = url or server_from_env()
        if not url:
            raise ClientError(0, f"no server address: give --server URL or set {ENV_SERVER}")
        self.url = url.rstrip("/")
        self.key = key if key is not None else os.environ.get(ENV_KEY) or None
        self._ca = ca or os.environ.get(ENV_CA) or None
        headers = {"Authorization": f"Bearer {self.key}"} if self.key else {}
        self._http = httpx.Client(base_url=self.url + API_PREFIX, headers=headers,
                                  timeout=timeout_s, verify=self._ssl_context() or True)

    def _ssl_context(self) -> ssl.SSLContext | None:
        if not self.url.startswith("https") or self._ca is None:
            return None
        return ssl.create_default_context(cafile=self._ca)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> BenchClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # plumbing ---------------------------------------------------------------------------
    def request(self, method: str, path: str, body: dict[str, Any] | None = None,
                params: dict[str, Any] | None = None) -> Any:
        """One request; the decoded JSON answer, or :class:`ClientError`."""
        try:
            r = self._http.request(method, path, json=body, params=params)
        except httpx.HTTPError as err:
            raise ClientError(0, f"cannot reach the server at {self.url}: {err}") from err
        if r.status_code >= 400:
            try:
                data = r.json()
                message, reasons = str(data.get("detail", r.reason_phrase)), \
                    data.get("reasons", [])
            except ValueError:
                message, reasons = r.text or r.reason_phrase, []
            raise ClientError(r.status_code, message, reasons)
        return r.json()

    # queries ----------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        return cast(dict[str, Any], self.request("GET", "/status"))

    def queue(self) -> dict[str, Any]:
        return cast(dict[str, Any], self.request("GET", "/queue"))

    def history(self, limit: int = 200) -> list[dict[str, Any]]:
        return cast(list[dict[str, Any]],
                    self.request("GET", "/queue/history", params={"limit": limit}))

    def runs(self, limit: int = 100) -> list[dict[str, Any]]:
        return cast(list[dict[str, Any]], self.request("GET", "/runs", params={"limit": limit}))

    def download(self, path: str, to: str | os.PathLike[str]) -> None:
        """Copy the run file ``path`` (relative to the server's runs folder) to ``to``."""
        try:
            with self._http.stream("GET", f"/runs/files/{path}") as r:
                if r.status_code >= 400:
                    r.read()
                    raise ClientError(r.status_code, r.json().get("detail", r.reason_phrase))
                with open(to, "wb") as f:
                    for chunk in r.iter_bytes():
                        f.write(chunk)
        except httpx.HTTPError as err:
            raise ClientError(0, f"cannot reach the server at {self.url}: {err}") from err

    # queue ------------------------------------------------------------------------------
    def add_plan(self, plan_text: str, name: str | None = None) -> dict[str, Any]:
        return cast(dict[str, Any],
                    self.request("POST", "/queue", {"plan": plan_text, "name": name})["item"])

    def add_stop(self) -> dict[str, Any]:
        return cast(dict[str, Any], self.request("POST", "/queue", {"stop": True})["item"])

    def propose(self, plan_text: str, name: str | None = None) -> dict[str, Any]:
        return cast(dict[str, Any],
                    self.request("POST", "/queue/propose",
                                 {"plan": plan_text, "name": name})["item"])

    def approve(self, item_id: int) -> str:
        return cast(str, self.request("POST", f"/queue/{int(item_id)}/approve")["message"])

    def deny(self, item_id: int) -> str:
        return cast(str, self.request("POST", f"/queue/{int(item_id)}/deny")["message"])

    def remove(self, item_id: int) -> str:
        return cast(str, self.request("DELETE", f"/queue/{int(item_id)}")["message"])

    def move(self, item_id: int, index: int) -> str:
        return cast(str,
                    self.request("POST", f"/queue/{int(item_id)}/move",
                                 {"index": index})["message"])

    def start_queue(self) -> str:
        return cast(str, self.request("POST", "/queue/start")["message"])

    def stop_queue(self) -> str:
        return cast(str, self.request("POST", "/queue/stop")["message"])

    # run control ------------------------------------------------------------------------
    def pause(self, *, now: bool = False) -> str:
        return cast(str, self.request("POST", "/run/pause", {"now": now})["message"])

    def resume(self, answer: str = "resume") -> str:
        return cast(str, self.request("POST", "/run/resume", {"answer": answer})["message"])

    def abort(self) -> str:
        return cast(str, self.request("POST", "/run/abort")["message"])

    # manual commands and control --------------------------------------------------------
    def home(self, role: str) -> str:
        return cast(str, self.request("POST", "/bench/home", {"role": role})["message"])

    def jog(self, role: str, step: float) -> str:
        return cast(str,
                    self.request("POST", "/bench/jog", {"role": role, "step": step})["message"])

    def move_to(self, **targets: float) -> str:
        return cast(str, self.request("POST", "/bench/move", {"targets": targets})["message"])

    def light(self, on: bool) -> str:
        return cast(str, self.request("POST", "/bench/light", {"on": on})["message"])

    def camera_settings(self, *, exposure_us: float | None = None,
                        gain: float | None = None) -> str:
        """Set the camera's exposure (µs) and/or gain (its own units) between runs."""
        body = {k: v for k, v in (("exposure_us", exposure_us), ("gain", gain))
                if v is not None}
        return cast(str, self.request("POST", "/bench/camera", body)["message"])

    def device_settings(self, role: str, **changes: bool | int | float | str
                        ) -> dict[str, Any]:
        """Ask the server to set the device ``role``'s fields (``sensitivity_v=1e-3``,
        ``position=3``, ``auto_range=True``…); returns ``{"request_id", "message"}`` at
        once: the ``device_settings`` event with that id says when it is applied."""
        r = self.request("POST", f"/bench/devices/{role}/settings", {"changes": changes})
        return {"request_id": int(r["request_id"]), "message": str(r["message"])}

    def stop_all(self) -> str:
        return cast(str, self.request("POST", "/bench/stop-all")["message"])

    def take_control(self, timeout_s: float | None = None, *, force: bool = False
                     ) -> dict[str, Any]:
        return cast(dict[str, Any],
                    self.request("POST", "/control/take", {"timeout_s": timeout_s, "force": force}))

    def release_control(self) -> str:
        return cast(str, self.request("POST", "/control/release")["message"])

    def connect_bench(self) -> str:
        return cast(str, self.request("POST", "/bench/connect")["message"])

    def disconnect_bench(self) -> str:
        return cast(str, self.request("POST", "/bench/disconnect")["message"])

    # keys and audit (admin) -------------------------------------------------------------
    def keys(self) -> list[dict[str, Any]]:
        return cast(list[dict[str, Any]], self.request("GET", "/keys"))

    def add_key(self, name: str, role: str, expires: float | None = None) -> dict[str, Any]:
        return cast(dict[str, Any],
                    self.request("POST", "/keys", {"name": name, "role": role, "expires": expires}))

    def revoke_key(self, key_id: int) -> str:
        return cast(str, self.request("DELETE", f"/keys/{int(key_id)}")["message"])

    def audit(self, limit: int = 200) -> list[dict[str, Any]]:
        return cast(list[dict[str, Any]], self.request("GET", "/audit", params={"limit": limit}))

    def run_points(self, since: int = 0) -> dict[str, Any]:
        """One page of the current run's points published so far, from ordinal ``since``:
        ``{"run", "since", "next", "total", "items"}`` (``GET /runs/current/points``)."""
        return cast(dict[str, Any],
                    self.request("GET", "/runs/current/points", params={"since": int(since)}))

    def all_run_points(self) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
        """The current run (None before the first) and every point it published so far."""
        page = self.run_points(0)
        items = list(page["items"])
        while page["next"] < page["total"] and page["items"]:
            page = self.run_points(page["next"])
            items.extend(page["items"])
        return page["run"], items

    # events -----------------------------------------------------------------------------
    def open_events(self, *, open_timeout_s: float = 30.0) -> EventStream:
        """The event stream as an object: iterate it, or :meth:`EventStream.recv` with a
        timeout; :meth:`EventStream.close` (from any thread) ends it."""
        from websockets.exceptions import InvalidHandshake, InvalidStatus
        from websockets.sync.client import connect

        ws_url = "ws" + self.url[len("http"):] + API_PREFIX + "/events"
        headers = {"Authorization": f"Bearer {self.key}"} if self.key else None
        try:
            conn = connect(ws_url, additional_headers=headers, open_timeout=open_timeout_s,
                           ssl=self._ssl_context(), max_size=16 << 20)
        except InvalidStatus as err:
            raise ClientError(err.response.status_code,
                              "the server refused the event stream (check the key)") from err
        except (OSError, InvalidHandshake, TimeoutError) as err:
            raise ClientError(0, f"cannot reach the server at {self.url}: {err}") from err
        return EventStream(conn)

    def events(self, *, open_timeout_s: float = 30.0) -> Iterator[Message]:
        """The event stream, message by message, starting with ``hello``; ends when the
        server closes the connection. Close the generator (``break``) to disconnect."""
        with self.open_events(open_timeout_s=open_timeout_s) as stream:
            yield from stream


class EventStream:
    """An open event stream (:meth:`BenchClient.open_events`)."""

    def __init__(self, conn: Any) -> None:
        # entered as its context (the websockets library's way to own the connection);
        # :meth:`close` ends it
        self._conn = conn.__enter__()

    def recv(self, timeout_s: float | None = None) -> Message | None:
        """The next message; None when ``timeout_s`` passed without one.

        Raises
        ------
        EOFError
            The stream ended (the server closed it, or :meth:`close` was called).
        """
        from websockets.exceptions import ConnectionClosed

        try:
            return decode(self._conn.recv(timeout=timeout_s))
        except TimeoutError:
            return None
        except ConnectionClosed as err:
            raise EOFError("the event stream ended") from err

    def __iter__(self) -> Iterator[Message]:
        while True:
            try:
                yield cast(Message, self.recv())  # no timeout: it never returns None
            except EOFError:
                return

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> EventStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
