"""The bench server's wire protocol: message types shared by the server and its clients.

HTTP carries commands and queries (JSON bodies, ``/api/v1/...``; the server publishes the
OpenAPI schema at ``/openapi.json``). A WebSocket, ``/api/v1/events``, carries the event
stream: one JSON text frame per message::

    {"v": 1, "seq": 42, "type": "progress", "time": 1790000000.0, "data": {...}}

``v`` is :data:`PROTOCOL_VERSION` (a client refuses a major version it does not know);
``seq`` numbers every message the server publishes, in order, so a client sees a gap
(``hello`` and ``missed``, which concern one connection only, carry 0);
``type`` is one of :data:`MESSAGE_TYPES`, whose entry names the fields of ``data`` and
whether the message is *lifecycle* (never dropped for a slow client) or *display*
(superseded by the next one of its type, so a client that falls behind may lose it and is
then sent a ``missed`` message counting what it lost).

This module imports only the standard library: a notebook client needs nothing more.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

__all__ = [
    "API_PREFIX",
    "MESSAGE_TYPES",
    "PROTOCOL_VERSION",
    "ROLES",
    "Message",
    "MessageType",
    "decode",
    "encode",
    "role_allows",
]

#: Major version of the protocol; a change that breaks a client increments it.
PROTOCOL_VERSION = 1

#: Where every endpoint lives (the version is in the path, as in the messages).
API_PREFIX = "/api/v1"

#: Roles in increasing order of power; each may do what the ones before it may.
ROLES = ("observer", "operator", "admin")


def role_allows(role: str, needed: str) -> bool:
    """Whether ``role`` may do what ``needed`` may (unknown roles may do nothing)."""
    if role not in ROLES or needed not in ROLES:
        return False
    return ROLES.index(role) >= ROLES.index(needed)


@dataclass(frozen=True)
class MessageType:
    """One kind of event message: its ``type``, the fields of its ``data`` (name → JSON
    type, for the published schema) and whether it is lifecycle (never dropped)."""

    name: str
    lifecycle: bool
    fields: dict[str, str]
    doc: str


def _t(type_name: str, lifecycle: bool, doc: str, **fields: str) -> MessageType:
    return MessageType(type_name, lifecycle, fields, doc)


#: Every message type of the event stream, by name.
MESSAGE_TYPES: dict[str, MessageType] = {t.name: t for t in (
    _t("hello", True, "first message on a connection: who the server is and the state now",
       protocol="integer", bench="string", role="string", name="string", status="object"),
    _t("run_started", True, "a run (new or resumed) started",
       run_id="string", path="string", plan_kind="string", n_total="integer",
       n_done="integer", estimated_s="number", item_id="integer"),
    _t("points", False, "the points acquired since the last such message (at most 10 "
       "messages a second); each item: index, label, status, positions, angles, "
       "exposure_us, power_w, signal, retries. A client that missed some reads them from "
       "the run file", items="array"),
    _t("backfill", True, "a resumed run's points stored before it was resumed (after a "
       "restart of the server, a pause now or an abort), sent right after its run_started "
       "in parts of at most 5000 items (part of parts; n_points in all); items as in "
       "points. A client draws them as points: the run is then shown whole",
       run_id="string", path="string", n_points="integer", part="integer",
       parts="integer", items="array"),
    _t("progress", False, "points done, elapsed and estimated time left (the newest, at "
       "most 10 a second)",
       n_done="integer", n_total="integer", elapsed_s="number", eta_s="number"),
    _t("axis_homed", True, "the engine homed an axis the plan moves",
       device="string", position="number", elapsed_s="number"),
    _t("fault", True, "a device failed; action says what the engine does about it",
       device="string", cause="string", action="string", index="integer|null"),
    _t("paused", True, "the run is paused; answers lists what an operator may answer "
       "(after a device fault: retry, skip, abort)",
       reason="string", index="integer|null", answers="array"),
    _t("resumed", True, "the run goes on", index="integer|null"),
    _t("run_finished", True, "the run ended (status finished, aborted, paused or failed)",
       status="string", n_done="integer", n_total="integer", n_skipped="integer",
       path="string", elapsed_s="number", message="string"),
    _t("second_pass", True, "a queue item's two-pass lobe plan after its first pass: "
       "state planning (the first pass is being fitted), planned (n_points placed by "
       "Fisher information; its run starts next) or not run (it could not beat a single "
       "pass of equal time; message says why)", item_id="integer", first_pass="string",
       state="string", n_points="integer|null", message="string"),
    _t("queue", True, "the queue changed (items in order, whether it runs)",
       running="boolean", items="array"),
    _t("item_finished", True, "a queue item ended: its outcome and run file",
       item_id="integer", name="string", outcome="string", run_file="string|null"),
    _t("control", True, "who holds the operator's control lease, until when",
       holder="string|null", until="number|null"),
    _t("bench", True, "the bench was connected or disconnected", connected="boolean",
       bench="string", message="string"),
    _t("manual", True, "a manual command (home, jog, move, light, camera settings, stop "
       "all) was carried out", who="string", what="string", message="string"),
    _t("device_settings", True, "a device-settings request (POST /bench/devices/ROLE/"
       "settings) by request_id: state applying (accepted, waiting for or on the settings "
       "worker), done, failed (message and field say which and why; the fields before it "
       "were applied) or cancelled (Stop all, or the server closing, before it was "
       "applied); device_state: the device's state when it ended (as in devices' states)",
       request_id="integer", who="string", device="string", kind="string",
       changes="object", state="string", message="string", field="string|null",
       device_state="object|null"),
    _t("devices", False, "device states (at most 10 per second); camera: its exposure_us "
       "and gain between runs (null during a run, or without a camera); states: the "
       "lock-in's, filter wheel's and power meter's state by role (kind, connected, "
       "values, info: identity and settings' tables, error, read_at: unix s; during a run "
       "the state read before it)", axes="object",
       light="boolean|null", owner="string", camera="object|null", states="object"),
    _t("frame", False, "the latest camera frame, decimated for display (8-bit, base64)",
       index="integer", shape="array", scale="number", data="string",
       exposure_us="number|null", saturated="number|null"),
    _t("missed", True, "this client fell behind: display messages it did not receive",
       counts="object", first_seq="integer", last_seq="integer"),
)}


@dataclass(frozen=True)
class Message:
    """One event message (see the module's docstring)."""

    seq: int
    type: str
    time: float
    data: dict[str, Any]
    v: int = PROTOCOL_VERSION

    @property
    def lifecycle(self) -> bool:
        t = MESSAGE_TYPES.get(self.type)
        return t is None or t.lifecycle  # unknown types are kept, never dropped


def encode(message: Message) -> str:
    return json.dumps({"v": message.v, "seq": message.seq, "type": message.type,
                       "time": message.time, "data": message.data},
                      separators=(",", ":"), allow_nan=False, default=_jsonable)


def _jsonable(value: Any) -> Any:
    if isinstance(value, tuple | set | frozenset):
        return list(value)
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def decode(text: str | bytes) -> Message:
    """A message from its JSON text.

    Raises
    ------
    ValueError
        Not a message of this protocol, or of a newer major version.
    """
    try:
        raw = json.loads(text)
        v, seq, kind, t, data = raw["v"], raw["seq"], raw["type"], raw["time"], raw["data"]
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"not a scatterlab event message: {err}") from err
    if not isinstance(v, int) or v > PROTOCOL_VERSION:
        raise ValueError(f"the server speaks protocol version {v}; this client knows up "
                         f"to {PROTOCOL_VERSION}: update scatterlab")
    if not isinstance(data, dict):
        raise ValueError("not a scatterlab event message: data is not an object")
    return Message(int(seq), str(kind), float(t), data, v)


def schema() -> dict[str, Any]:
    """The event messages as a JSON document (served at ``/api/v1/events/schema``)."""
    return {"protocol": PROTOCOL_VERSION, "envelope": {
        "v": "integer", "seq": "integer", "type": "string", "time": "number (unix s)",
        "data": "object"},
        "types": {t.name: {"lifecycle": t.lifecycle, "doc": t.doc, "data": t.fields}
                  for t in MESSAGE_TYPES.values()}}
