"""What the GUI knows of a bench server, without Qt: the state its event messages describe.

In client mode (docs/decisions/0084) the engine and the bench live in the server process;
the GUI holds :class:`RemoteState`, which :meth:`RemoteState.apply` updates from the event
stream's messages (:mod:`instrument.protocol`) and which the widgets read on a timer. It
keeps the queue, the current run and its live points (a :class:`gui.model.live.LiveData`,
so the plots are the same as for a run in this process), device states (the lock-in's,
filter wheel's and power meter's as the :class:`DeviceState` the device panels show),
the newest camera frame, the control lease and a log of lifecycle messages.

Who may do what is decided here too (:meth:`RemoteState.may_operate`), so that the window
greys exactly the controls the server would refuse and says why: an observer key may only
watch; an operator may act when nobody else holds the control lease; Stop all is always
allowed to an operator.
"""

from __future__ import annotations

import base64
import collections
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gui.model.live import LiveData
from instrument.bench.device_state import DeviceState, state_from_message
from instrument.protocol import Message, role_allows
from instrument.run.events import PointCompleted

__all__ = ["LOG_LINES", "RemoteRun", "RemoteState", "point_event"]

#: Lifecycle lines kept for the log view.
LOG_LINES = 500


def _num(value: Any) -> float:
    """A JSON number (``null`` where the server had NaN) as a float."""
    return math.nan if value is None else float(value)


def point_event(item: dict[str, Any]) -> PointCompleted:
    """A ``points`` item of the event stream as the engine's :class:`PointCompleted`."""
    angles = item.get("angles")
    return PointCompleted(
        index=int(item["index"]), label=str(item.get("label", "")),
        status=str(item.get("status", "ok")),
        positions={k: _num(v) for k, v in (item.get("positions") or {}).items()},
        angles=None if angles is None else tuple(_num(a) for a in angles),
        exposure_us=_num(item.get("exposure_us")), power_w=_num(item.get("power_w")),
        signal=_num(item.get("signal")), retries=int(item.get("retries") or 0),
        nd_slot=int(item.get("nd_slot", -1) if item.get("nd_slot") is not None else -1))


@dataclass
class RemoteRun:
    """The server's current (or last) run as the GUI shows it."""

    run_id: str = ""
    path: str = ""
    plan_kind: str = ""
    n_total: int = 0
    n_done: int = 0
    state: str = "running"    # running | paused | finished | aborted | failed
    item_id: int | None = None
    answers: list[str] = field(default_factory=list)
    pause_reason: str = ""
    elapsed_s: float = 0.0
    eta_s: float = math.nan
    live: LiveData | None = None
    seen: set[int] = field(default_factory=set)

    @property
    def alive(self) -> bool:
        return self.state in ("running", "paused")

    def add_points(self, points: list[tuple[int, PointCompleted]]) -> int:
        """Points (index, event: :func:`point_event`) into the live arrays, each index once
        (the points read at connection and the stream overlap by a batch); returns how
        many were new."""
        if self.live is None:
            return 0
        n = 0
        for index, event in points:
            if index in self.seen:
                continue
            self.seen.add(index)
            if event.angles is not None:
                self.live.plan_angles(index, event.angles)
            self.live.on_event(event)
            n += 1
        return n


class RemoteState:
    """The server's state as told by its messages. Not thread-safe: one thread (the GUI's)
    applies messages and reads it."""

    def __init__(self, url: str = "") -> None:
        self.url = url
        self.stream_up = False
        self.you = {"name": "", "role": ""}
        self.bench = ""
        self.bench_connected = False
        self.runs_dir = ""
        self.queue_items: list[dict[str, Any]] = []
        self.queue_running = False
        self.run: RemoteRun | None = None
        self.control: dict[str, Any] = {"holder": None, "until": None}
        self.axes: dict[str, dict[str, Any]] = {}
        self.light: bool | None = None
        #: The camera's exposure_us and gain between runs (None: during a run, no camera)
        self.camera: dict[str, float | None] | None = None
        self.owner = ""
        #: The lock-in's, filter wheel's and power meter's states by role; an entry is
        #: replaced only when the server's message for it changed (the panels redraw then)
        self.device_states: dict[str, DeviceState] = {}
        self._device_raw: dict[str, Any] = {}
        #: Device-settings requests not yet ended, by role: the newest ``device_settings``
        #: message of each (state applying); an ended one moves to :attr:`settings_ended`
        self.settings_pending: dict[str, dict[str, Any]] = {}
        #: Ended requests whose end the window has not shown yet (it empties the list)
        self.settings_ended: list[dict[str, Any]] = []
        self.frame: tuple[int, np.ndarray, float] | None = None
        self.missed: collections.Counter[str] = collections.Counter()
        self.log: collections.deque[str] = collections.deque(maxlen=LOG_LINES)
        self.version = 0

    def homed_positions(self) -> dict[str, float]:
        """Read-back positions of the homed axes (an unhomed axis's counter is not a
        position), for the goniometer drawing."""
        return {role: float(ax["position"]) for role, ax in self.axes.items()
                if ax.get("homed") and ax.get("position") is not None}

    # who may do what --------------------------------------------------------------------
    def may_operate(self, now: float | None = None) -> tuple[bool, str]:
        """Whether queue edits, run control and manual moves are allowed, and why not."""
        if not self.stream_up:
            return False, f"not connected to the server at {self.url}"
        role = self.you.get("role", "")
        if not role_allows(role, "operator"):
            return False, (f"your key is an {role or 'unknown'} key: you may watch; an "
                           "operator key is needed to act")
        holder = self.lease_holder(now)
        if holder is not None and holder != self.you.get("name"):
            return False, f"control is held by {holder}: ask them to release it, or wait"
        return True, ""

    def may_stop_all(self) -> tuple[bool, str]:
        """Stop all is allowed to any operator, whoever holds control."""
        if not self.stream_up:
            return False, f"not connected to the server at {self.url}"
        if not role_allows(self.you.get("role", ""), "operator"):
            return False, "Stop all needs an operator key"
        return True, ""

    def lease_holder(self, now: float | None = None) -> str | None:
        until = self.control.get("until")
        if self.control.get("holder") is None or until is None:
            return None
        return self.control["holder"] if until > (now or time.time()) else None

    def holds_control(self) -> bool:
        return self.lease_holder() == self.you.get("name")

    # messages ---------------------------------------------------------------------------
    def apply(self, msg: Message) -> str:
        """Take one message into the state; returns the part it changed (``queue``,
        ``run``, ``points``, ``devices``, ``frame``, ``control``, ``bench``, ``log``)."""
        self.version += 1
        handler = getattr(self, f"_on_{msg.type}", None)
        if handler is None:
            self._say(msg, f"{msg.type}: {msg.data}")
            return "log"
        return handler(msg, msg.data)

    def _say(self, msg: Message, text: str) -> None:
        self.log.append(f"{time.strftime('%H:%M:%S', time.localtime(msg.time))}  {text}")

    def _on_hello(self, msg: Message, d: dict[str, Any]) -> str:
        self.stream_up = True
        self.you = {"name": d.get("name", ""), "role": d.get("role", "")}
        self.bench = d.get("bench", "")
        self.apply_status(d.get("status") or {})
        self._say(msg, f"connected to {self.url} (bench {self.bench!r}) as "
                  f"{self.you['name']} ({self.you['role']})")
        return "bench"

    def apply_status(self, st: dict[str, Any]) -> None:
        """A ``GET /status`` answer (also inside ``hello``)."""
        self.bench_connected = bool(st.get("connected"))
        self.runs_dir = str(st.get("runs_dir") or "")
        self.queue_running = bool(st.get("queue_running"))
        self.queue_items = list(st.get("queue") or [])
        self.control = dict(st.get("control") or {"holder": None, "until": None})
        r = st.get("run")
        if r is None:
            if self.run is not None and self.run.alive:
                self.run.state = "finished"
            return
        if self.run is None or self.run.path != r.get("path"):
            self.run = RemoteRun(path=r.get("path") or "")
        run = self.run
        run.n_total = int(r.get("n_total") or 0)
        run.n_done = int(r.get("n_done") or 0)
        run.state = str(r.get("state") or "running")
        run.item_id = r.get("item_id")
        run.answers = list(r.get("answers") or [])
        run.pause_reason = r.get("pause_reason") or ""
        run.elapsed_s = _num(r.get("elapsed_s"))

    def prefill(self, run: dict[str, Any] | None,
                points: list[tuple[int, PointCompleted]]) -> int:
        """The current run's points published before this client connected (``GET
        /runs/current/points``); returns how many were added."""
        if run is None or self.run is None or not self.run.alive:
            return 0
        if self.run.live is None or self.run.run_id != run.get("run_id"):
            self._start_live(self.run, run)
        return self.run.add_points(points)

    def _start_live(self, target: RemoteRun, d: dict[str, Any]) -> None:
        target.run_id = str(d.get("run_id") or "")
        target.path = str(d.get("path") or target.path)
        target.plan_kind = str(d.get("plan_kind") or "")
        target.n_total = int(d.get("n_total") or target.n_total)
        target.item_id = d.get("item_id", target.item_id)
        target.live = LiveData(target.plan_kind, target.n_total, n_done=target.n_done)
        target.seen = set()

    def _on_run_started(self, msg: Message, d: dict[str, Any]) -> str:
        self.run = RemoteRun(n_done=int(d.get("n_done") or 0))
        self._start_live(self.run, d)
        self._say(msg, f"run {self.run.run_id} started ({self.run.plan_kind}, "
                  f"{self.run.n_total} points, {self.run.n_done} done)")
        return "run"

    def _on_points(self, msg: Message, d: dict[str, Any]) -> str:
        self.add_points([(int(i["index"]), point_event(i)) for i in d.get("items") or []])
        return "points"

    def _on_backfill(self, msg: Message, d: dict[str, Any]) -> str:
        """A resumed run's points from before its resumption: drawn as points are."""
        self._say(msg, f"run {d.get('run_id')}: {d.get('n_points')} points stored before "
                  f"it was resumed (part {d.get('part')} of {d.get('parts')})")
        return self._on_points(msg, d)

    def add_points(self, points: list[tuple[int, PointCompleted]]) -> int:
        """Points of the current run (parsed by :func:`point_event`, on any thread)."""
        return 0 if self.run is None else self.run.add_points(points)

    def _on_progress(self, msg: Message, d: dict[str, Any]) -> str:
        if self.run is not None:
            self.run.n_done = int(d.get("n_done") or 0)
            self.run.elapsed_s = _num(d.get("elapsed_s"))
            self.run.eta_s = _num(d.get("eta_s"))
        return "run"

    def _on_axis_homed(self, msg: Message, d: dict[str, Any]) -> str:
        self._say(msg, f"{d.get('device')} homed at {_num(d.get('position')):.3f}")
        return "log"

    def _on_fault(self, msg: Message, d: dict[str, Any]) -> str:
        self._say(msg, f"FAULT {d.get('device')}: {d.get('cause')} → {d.get('action')}")
        return "run"

    def _on_paused(self, msg: Message, d: dict[str, Any]) -> str:
        if self.run is not None:
            self.run.state = "paused"
            self.run.answers = list(d.get("answers") or [])
            self.run.pause_reason = d.get("reason") or ""
        self._say(msg, f"paused: {d.get('reason')} (answers: "
                  f"{', '.join(d.get('answers') or [])})")
        return "run"

    def _on_resumed(self, msg: Message, d: dict[str, Any]) -> str:
        if self.run is not None:
            self.run.state = "running"
            self.run.answers = []
            self.run.pause_reason = ""
        self._say(msg, "resumed")
        return "run"

    def _on_run_finished(self, msg: Message, d: dict[str, Any]) -> str:
        if self.run is not None:
            self.run.state = str(d.get("status") or "finished")
            self.run.n_done = int(d.get("n_done") or self.run.n_done)
            self.run.answers = []
        self._say(msg, f"run {d.get('status')}: {d.get('n_done')} of {d.get('n_total')} "
                  f"points; {d.get('message') or ''}".rstrip("; "))
        return "run"

    def _on_queue(self, msg: Message, d: dict[str, Any]) -> str:
        self.queue_items = list(d.get("items") or [])
        self.queue_running = bool(d.get("running"))
        return "queue"

    def _on_item_finished(self, msg: Message, d: dict[str, Any]) -> str:
        self._say(msg, f"item {d.get('item_id')} ({d.get('name')}): {d.get('outcome')}")
        return "log"

    def _on_control(self, msg: Message, d: dict[str, Any]) -> str:
        self.control = {"holder": d.get("holder"), "until": d.get("until")}
        self._say(msg, f"control: {d.get('holder') or 'free'}")
        return "control"

    def _on_bench(self, msg: Message, d: dict[str, Any]) -> str:
        self.bench_connected = bool(d.get("connected"))
        self._say(msg, str(d.get("message") or ""))
        return "bench"

    def _on_manual(self, msg: Message, d: dict[str, Any]) -> str:
        self._say(msg, f"{d.get('who')}: {d.get('message')}")
        return "log"

    def _on_devices(self, msg: Message, d: dict[str, Any]) -> str:
        self.axes = dict(d.get("axes") or {})
        if d.get("light") is not None or d.get("owner") != "run":
            self.light = d.get("light")
        self.owner = str(d.get("owner") or "")
        cam = d.get("camera")
        self.camera = None if not isinstance(cam, dict) else {
            k: (None if cam.get(k) is None else _num(cam.get(k)))
            for k in ("exposure_us", "gain")}
        states = d.get("states") or {}
        for role, raw in states.items():
            if isinstance(raw, dict) and raw != self._device_raw.get(role):
                self._device_raw[role] = raw
                self.device_states[role] = state_from_message(role, raw)
        for role in set(self.device_states) - set(states):
            del self.device_states[role], self._device_raw[role]
        return "devices"

    def _on_device_settings(self, msg: Message, d: dict[str, Any]) -> str:
        """A device-settings request was accepted or ended (by any client): a pending one
        by role; an ended one with the device's state as it is now (shown at once, not
        at the next poll)."""
        role = str(d.get("device") or "")
        if d.get("state") == "applying":
            self.settings_pending[role] = dict(d)
            return "device_settings"
        pending = self.settings_pending.get(role)
        if pending is not None and pending.get("request_id") == d.get("request_id"):
            del self.settings_pending[role]
        self.settings_ended.append(dict(d))
        raw = d.get("device_state")
        if isinstance(raw, dict):
            self._device_raw[role] = raw
            self.device_states[role] = state_from_message(role, raw)
        self._say(msg, f"{d.get('who')}: {d.get('message')}")
        return "device_settings"

    def _on_frame(self, msg: Message, d: dict[str, Any]) -> str:
        shape = tuple(int(s) for s in d.get("shape") or ())
        raw = base64.b64decode(d.get("data") or "")
        if len(shape) == 2 and len(raw) == shape[0] * shape[1]:
            img = np.frombuffer(raw, np.uint8).reshape(shape)
            self.frame = (int(d.get("index") or 0), img, _num(d.get("scale")))
        return "frame"

    def _on_missed(self, msg: Message, d: dict[str, Any]) -> str:
        self.missed.update({k: int(v) for k, v in (d.get("counts") or {}).items()})
        return "log"
