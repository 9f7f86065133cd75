"""The bench service: the one owner of the bench, its engine and the plan queue.

Everything here is plain threads and is used by the HTTP layer (:mod:`instrument.server.app`)
through the methods below, each of which either does what it says or raises
:class:`ServiceError` with the HTTP status and a sentence — *before* anything changed.

Threads:

* the **runner** takes the head of the queue when the queue runs and the bench is idle,
  starts (or resumes, exactly as ``scatterlab resume`` does: :func:`resume_run`) its run,
  holds the run's writer lock (``RUN.h5.lock``, so a ``scatterlab resume`` elsewhere is
  told who continues it) and records the outcome in the history — before the run leaves
  the status and before ``run_finished`` goes out (the engine's ``run_finished`` is held
  back until then), so a client that lists the history when it sees ``run_finished``
  finds the row;
* the **sampler** publishes device states at most 10 times a second (read back by the
  engine during a run, polled otherwise) and the run's latest camera frame, decimated for
  display, at most twice a second;
* the engine's worker and writer threads (ADR 0011); the event hub's dispatcher.

Manual commands (home, jog, move, light, stop all) are judged by the same guard as the
GUI's (:mod:`instrument.bench.manual`); while a run owns the bench only Stop all is
accepted, and it aborts the run (the engine stops every axis and turns the light off).

Device settings (the lock-in's, filter wheel's and power meter's:
:mod:`instrument.server.device_settings`) are checked when asked, then applied by the
**settings worker**, one request at a time, in the order accepted: a wheel move or an
auto-range holds its device for seconds, never the HTTP loop, the event stream or the
bench's lock. The request is answered at once with its id; the ``device_settings`` event
says when it is applied or why it failed. While a request waits or is applied, the queue
runner starts no run; Stop all never waits for one (it stops the axes at once, the
device in progress finishes its command, the requests still waiting are cancelled).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import itertools
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from drivers.base import LightSource, MotionAxis
from drivers.errors import DeviceError
from instrument.bench.device_state import kind_of, read_state, state_message
from instrument.bench.devices import Bench, open_bench
from instrument.bench.guard import GuardError
from instrument.bench.manual import MoveRefused, check_light_on, plan_home, plan_manual_move
from instrument.bench.profile import BenchProfile, ProfileError
from instrument.plans import build_plan, parse_plan
from instrument.run import events as ev
from instrument.run.engine import EngineState, RunEngine
from instrument.run.locks import LockHeld, hold
from instrument.run.paths import writer_lock_path
from instrument.run.runner import recover_run, resume_run, start_run
from instrument.run.storage import FrameData, StorageError
from instrument.server.audit import AuditLog
from instrument.server.db import ServerDB
from instrument.server.device_settings import Change, SettingRefused, check_changes, describe
from instrument.server.hub import EventHub
from instrument.server.plans import PlanRefused, check_plan
from instrument.server.points import MAX_POINTS_PAGE, stored_points
from instrument.server.queue import RESUMABLE, PlanQueue, QueueError, QueueItem

__all__ = ["LEASE_S", "BenchService", "Caller", "ServiceError"]

_T = TypeVar("_T")

#: Seconds an operator's control lease lasts after its last command.
LEASE_S = 300.0
#: Device states are published at most this often (Hz), camera frames at most FRAME_HZ.
STATE_HZ = 10.0
#: Device kinds whose whole state (values and settings, ``instrument.bench.device_state``)
#: the ``devices`` message carries under ``states``, each read at its kind's poll interval
#: while no run owns the bench (the axes, the light and the camera have their own fields).
STATE_KINDS = ("lockin", "filter_wheel", "power_meter")
FRAME_HZ = 2.0
#: Device-settings requests that may wait for the settings worker at once.
MAX_SETTINGS_PENDING = 16
#: Display frames are decimated to at most this many pixels on their longer side.
FRAME_MAX_PX = 160


@dataclass(frozen=True)
class Caller:
    """Who makes a request: the key's holder and role."""

    name: str
    role: str


class ServiceError(Exception):
    """A request refused or failed; nothing changed. ``status`` is its HTTP status;
    ``reasons`` lists details (a guard's violations, a plan's field errors)."""

    def __init__(self, status: int, message: str, reasons: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.reasons = list(reasons)


@dataclass(frozen=True)
class _SettingsRequest:
    """A checked device-settings request waiting for (or on) the settings worker."""

    id: int
    caller: Caller
    role: str
    kind: str
    changes: tuple[Change, ...]

    def event(self, state: str, message: str, field: str | None = None,
              device_state: dict[str, Any] | None = None) -> dict[str, Any]:
        """The ``device_settings`` message's data."""
        return {"request_id": self.id, "who": self.caller.name, "device": self.role,
                "kind": self.kind,
                "changes": {c.field.name: c.value for c in self.changes},
                "state": state, "message": message, "field": field,
                "device_state": device_state}


#: The audit log's status for how a device-settings request ended (as the manual commands':
#: 502 a device's error, 409 cancelled by the bench's state).
_ENDED_STATUS = {"done": 200, "failed": 502, "cancelled": 409}


class _StoppedBetweenPasses(Exception):
    """The queue was stopped while a two-pass lobe plan's second pass was being planned:
    the item stays at the head, and starting the queue plans it again."""


def event_message(event: ev.Event) -> tuple[str, dict[str, Any]]:
    """An engine event as an event-stream message (type, data)."""
    name = {ev.RunStarted: "run_started", ev.PointCompleted: "point",
            ev.Progress: "progress", ev.Fault: "fault", ev.Paused: "paused",
            ev.Resumed: "resumed", ev.RunFinished: "run_finished",
            ev.AxisHomed: "axis_homed"}[type(event)]
    return name, _finite(dataclasses.asdict(event))


def _finite(value: Any) -> Any:
    """JSON has no NaN: a value not measured is ``null``."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def decimate(frame: np.ndarray, max_px: int = FRAME_MAX_PX) -> tuple[np.ndarray, float]:
    """A frame for display: block-averaged to at most ``max_px`` on its longer side, scaled
    to 8 bits by its own maximum; returns the image and the scale (DN per 8-bit step)."""
    img = np.asarray(frame, dtype=np.float32)
    k = max(1, int(np.ceil(max(img.shape) / max_px)))
    h, w = (img.shape[0] // k) * k, (img.shape[1] // k) * k
    small = img[:h, :w].reshape(h // k, k, w // k, k).mean(axis=(1, 3))
    top = float(small.max()) if small.size else 0.0
    scale = top / 255.0 if top > 0 else 1.0
    return np.clip(np.rint(small / scale), 0, 255).astype(np.uint8), scale


class BenchService:
    """Own ``profile``'s bench, the queue in ``runs_dir`` and the runs it makes.

    Parameters
    ----------
    opener
        Opens the bench (tests pass one that also reaches the emulators).
    allowed
        Folders besides ``runs_dir`` whose files a plan may name.
    connect
        Open the bench now (else an admin connects it).
    """

    def __init__(self, profile: BenchProfile, runs_dir: str | Path, *, fsync: bool = True,
                 allowed: Sequence[str | Path] = (), lease_s: float = LEASE_S,
                 opener: Callable[[BenchProfile], Bench] = open_bench,
                 connect: bool = True) -> None:
        self.profile = profile
        self.runs_dir = Path(runs_dir).resolve()
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        self.allowed = [self.runs_dir, *(Path(a).resolve() for a in allowed)]
        self.fsync = fsync
        self.lease_s = float(lease_s)
        self._opener = opener
        self.db = ServerDB(self.runs_dir)
        self.queue = PlanQueue(self.db)
        self.hub = EventHub()
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._bench_lock = threading.Lock()  # one manual command or poll at a time
        self.bench: Bench | None = None
        self.engine: RunEngine | None = None
        self.current: QueueItem | None = None
        self.queue_running = False
        self._closed = False
        self._pause_now = False
        self._last_fault: ev.Fault | None = None
        self._lease: tuple[str, float] | None = None
        self._frame: tuple[int, FrameData] | None = None
        self._display_lock = threading.Lock()
        self._points: list[dict[str, Any]] = []
        self._progress: dict[str, Any] | None = None
        # STATE_KINDS devices (sampler thread only): role -> (monotonic time read,
        # message), their static information, and the bench they were read from
        self._states: dict[str, tuple[float, dict[str, Any]]] = {}
        self._state_info: dict[str, Mapping[str, Any]] = {}
        self._states_of: Bench | None = None
        # a run file about to be resumed and its stored points (runner thread; published
        # after the resumed run's run_started by _publish_backfill)
        self._backfill: tuple[str, list[dict[str, Any]]] | None = None
        # the engine's run_finished message, held back by the worker thread until the
        # runner has recorded the outcome and cleared the status (_end_run)
        self._finished_msg: dict[str, Any] | None = None
        # device settings: requests waiting for the settings worker, the one it applies,
        # roles whose state the sampler reads afresh (info included) after a change
        self._settings: collections.deque[_SettingsRequest] = collections.deque()
        self._applying: _SettingsRequest | None = None
        self._settings_ids = itertools.count(1)
        self._stale: set[str] = set()
        self._audit = AuditLog(self.db)
        self.interrupted = self.queue.after_restart()
        if connect:
            self.connect(Caller("server", "admin"))
        self._runner = threading.Thread(target=self._run_queue, name="queue-runner",
                                        daemon=True)
        self._runner.start()
        self._sampler = threading.Thread(target=self._sample, name="state-sampler",
                                         daemon=True)
        self._sampler.start()
        self._settings_worker = threading.Thread(target=self._apply_settings,
                                                 name="device-settings", daemon=True)
        self._settings_worker.start()

    # lifecycle --------------------------------------------------------------------------
    def close(self) -> None:
        """Abort a run in progress (resumable), make the bench safe, close everything."""
        with self._cond:
            self._closed = True
            self.queue_running = False
            engine = self.engine
            self._cond.notify_all()
        if engine is not None:
            engine.abort()
            engine.wait(60.0)
        self._runner.join(60.0)
        self._sampler.join(5.0)
        self._settings_worker.join(60.0)  # a wheel move or an auto-range ends first
        with self._bench_lock:
            if self.bench is not None:
                self.bench.close()
                self.bench = None
        self.hub.close()
        self.db.close()

    # state ------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        with self._lock:
            engine, item = self.engine, self.current
            lease = self._lease_now()
            run = None
            if engine is not None:
                s = engine.snapshot()
                run = {"state": s.state.value, "n_done": s.n_done, "n_total": s.n_total,
                       "n_skipped": s.n_skipped, "elapsed_s": s.elapsed_s, "path": s.path,
                       "pause_reason": s.pause_reason, "item_id": item.id if item else None,
                       "answers": self._answers() if s.state is EngineState.PAUSED else []}
            return {"bench": self.profile.name, "connected": self.bench is not None,
                    "queue_running": self.queue_running, "run": run,
                    "control": {"holder": lease[0] if lease else None,
                                "until": lease[1] if lease else None},
                    "queue": [i.summary() for i in self.queue.items()],
                    "runs_dir": str(self.runs_dir)}

    def _answers(self) -> list[str]:
        f = self._last_fault
        return ["retry", "skip", "abort"] if f is not None and f.action == "pause" \
            else ["resume", "abort"]

    def _publish_queue(self) -> None:
        self.hub.publish("queue", {"running": self.queue_running,
                                   "items": [i.summary() for i in self.queue.items()]})

    # control lease ----------------------------------------------------------------------
    def _lease_now(self) -> tuple[str, float] | None:
        if self._lease is not None and self._lease[1] <= time.time():
            self._lease = None
        return self._lease

    def take_control(self, caller: Caller, *, force: bool = False,
                     timeout_s: float | None = None) -> dict[str, Any]:
        """Take (or renew) the control lease. Another holder's live lease refuses it
        (409) unless an admin forces it."""
        with self._lock:
            lease = self._lease_now()
            if not (force and caller.role == "admin"):
                self.check_control(caller)
            s = self.lease_s if timeout_s is None else max(1.0, min(float(timeout_s), 86400))
            self._lease = (caller.name, time.time() + s)
            changed = lease is None or lease[0] != caller.name
        if changed:
            self._publish_control()
        return {"holder": self._lease[0], "until": self._lease[1]}

    def release_control(self, caller: Caller) -> None:
        with self._lock:
            lease = self._lease_now()
            if lease is None:
                return
            if lease[0] != caller.name and caller.role != "admin":
                raise ServiceError(409, f"control is held by {lease[0]}, not by you")
            self._lease = None
        self._publish_control()

    def _publish_control(self) -> None:
        lease = self._lease_now()
        self.hub.publish("control", {"holder": lease[0] if lease else None,
                                     "until": lease[1] if lease else None})

    def check_control(self, caller: Caller) -> None:
        """Refuse (409) when another operator holds control. The caller's command, once
        carried out, takes or renews the lease (:meth:`take_control`): the first command
        of an operator when nobody holds control takes it, and that is announced."""
        with self._lock:
            lease = self._lease_now()
            if lease and lease[0] != caller.name:
                raise ServiceError(409, f"control is held by {lease[0]} until "
                                   f"{time.strftime('%H:%M:%S', time.localtime(lease[1]))}; "
                                   "ask them to release it, or wait")

    # queue ------------------------------------------------------------------------------
    def add_plan(self, caller: Caller, text: str, name: str | None = None, *,
                 propose: bool = False) -> QueueItem:
        try:
            spec = check_plan(text, self.profile, self.allowed)
        except PlanRefused as err:
            raise ServiceError(422, err.message, err.errors) from err
        item = self.queue.add("plan", name or spec.name, text, caller.name, proposed=propose)
        self._queue_changed()
        return item

    def add_stop(self, caller: Caller) -> QueueItem:
        item = self.queue.add("stop", "stop marker", None, caller.name)
        self._queue_changed()
        return item

    def _queue_call(self, fn: Callable[..., _T], *args: Any) -> _T:
        try:
            return fn(*args)
        except QueueError as err:
            raise ServiceError(err.status, str(err)) from err

    def remove(self, caller: Caller, item_id: int) -> QueueItem:
        with self._lock:
            if self.current is not None and self.current.id == item_id:
                raise ServiceError(409, f"item {item_id} is running: abort its run first")
            item = self._queue_call(self.queue.remove, item_id, caller.name)
        self._queue_changed()
        return item

    def move_item(self, caller: Caller, item_id: int, index: int) -> QueueItem:
        item = self._queue_call(self.queue.move, item_id, index)
        self._queue_changed()
        return item

    def approve(self, caller: Caller, item_id: int) -> QueueItem:
        item = self._queue_call(self.queue.approve, item_id)
        self._queue_changed()
        return item

    def deny(self, caller: Caller, item_id: int) -> QueueItem:
        item = self._queue_call(self.queue.deny, item_id, caller.name)
        self._queue_changed()
        return item

    def start_queue(self, caller: Caller) -> None:
        with self._cond:
            if self.bench is None:
                raise ServiceError(409, "no bench is connected: an admin connects it first")
            self.queue_running = True
            self._cond.notify_all()
        self._publish_queue()

    def stop_queue(self, caller: Caller) -> None:
        """The queue stops after the run in progress (which goes on)."""
        with self._cond:
            self.queue_running = False
        self._publish_queue()

    def _queue_changed(self) -> None:
        with self._cond:
            self._cond.notify_all()
        self._publish_queue()

    # run control ------------------------------------------------------------------------
    def _live_engine(self) -> RunEngine:
        engine = self.engine
        if engine is None or not engine.alive:
            raise ServiceError(409, "no run is in progress")
        return engine

    def pause(self, caller: Caller, *, now: bool = False) -> str:
        """Pause at the end of the point in progress, or ``now``: stop at once (motion
        stopped, light off, the file closed), leaving the item at the head, resumable."""
        with self._lock:
            engine = self._live_engine()
            if now:
                self._pause_now = True
                self.queue_running = False
                engine.abort()
                return "stopping now: the run is resumable from its file (resume)"
            if engine.state is EngineState.PAUSED:
                return "the run is already paused"
            engine.pause(f"paused by {caller.name}")
            return "pausing at the end of the point in progress"

    def resume(self, caller: Caller, answer: str = "resume") -> str:
        """Continue: a paused engine (``retry`` or ``skip`` the failed point after a device
        fault), or the head item's interrupted, aborted or paused-now run (the queue is
        started and resumes its file)."""
        if answer not in ("resume", "retry", "skip"):
            raise ServiceError(422, f"answer must be resume, retry or skip, got {answer!r}")
        with self._cond:
            engine = self.engine
            if engine is not None and engine.alive:
                if engine.state is not EngineState.PAUSED:
                    raise ServiceError(409, "the run is not paused")
                engine.resume(skip_point=answer == "skip")
                return "resuming" + (" (the failed point is skipped)" if answer == "skip"
                                     else "")
            head = self.queue.head()
            if head is None or not head.summary()["resumable"]:
                raise ServiceError(409, "nothing to resume: no paused run and no "
                                   "resumable item at the head of the queue")
        self.start_queue(caller)
        return f"resuming item {head.id} ({head.name}) from {head.run_file}"

    def abort(self, caller: Caller) -> str:
        with self._lock:
            engine = self._live_engine()
            self.queue_running = False
            engine.abort()
        self._publish_queue()
        return "aborting: the item stays at the head of the queue, resumable"

    # manual commands --------------------------------------------------------------------
    def _idle_bench(self) -> Bench:
        if self.bench is None:
            raise ServiceError(409, "no bench is connected")
        if self.engine is not None and self.engine.alive:
            raise ServiceError(409, "a run owns the bench: pause does not hand it back; "
                               "abort the run or let it finish")
        return self.bench

    def _axis(self, bench: Bench, role: str) -> MotionAxis:
        axis = bench.axes.get(role)
        if axis is None:
            raise ServiceError(422, f"bench {self.profile.name!r} has no axis {role!r} "
                               f"(axes: {', '.join(bench.axes)})")
        return axis

    @staticmethod
    def _light_on(bench: Bench) -> bool:
        return bool(bench.source is not None and bench.source.is_on)

    def _manual(self, caller: Caller, what: str, fn: Callable[[Bench], str]) -> str:
        with self._lock, self._bench_lock:
            bench = self._idle_bench()
            try:
                message = fn(bench)
            except MoveRefused as err:
                raise ServiceError(422, str(err), [v.detail for v in err.violations]) from err
            except DeviceError as err:
                raise ServiceError(502, f"{what}: device error: {err}") from err
        self.hub.publish("manual", {"who": caller.name, "what": what, "message": message})
        return message

    def home(self, caller: Caller, role: str) -> str:
        def do(bench: Bench) -> str:
            axis = self._axis(bench, role)
            plan_home(bench.profile, bench.homed_pose(), role, light=self._light_on(bench))
            if not axis.is_enabled:
                axis.enable()
            axis.home(wait=False)
            return f"{role}: homing"
        return self._manual(caller, f"home {role}", do)

    def move_axes(self, caller: Caller, targets: dict[str, float]) -> str:
        def do(bench: Bench) -> str:
            axes = {r: self._axis(bench, r) for r in targets}
            move = plan_manual_move(bench.profile, bench.homed_pose(), targets,
                                    light=self._light_on(bench))
            for role, target in targets.items():
                axes[role].move_to(float(target))
            return f"{move.describe()}: moving"
        return self._manual(caller, "move " + " ".join(f"{r}={v:g}" for r, v in targets.items()),
                            do)

    def jog(self, caller: Caller, role: str, step: float) -> str:
        with self._bench_lock:
            bench = self._idle_bench()
            s = self._axis(bench, role).status()
        if not s.is_homed:
            raise ServiceError(409, f"{role} is not homed: home it first")
        return self.move_axes(caller, {role: s.position + float(step)})

    def light(self, caller: Caller, on: bool) -> str:
        def do(bench: Bench) -> str:
            src = bench.source
            if not isinstance(src, LightSource):
                raise ServiceError(422, f"bench {self.profile.name!r} has no light source")
            if on:
                bad = check_light_on(bench.profile, bench.homed_pose())
                if bad:
                    raise ServiceError(422, "light on refused: " + "; ".join(
                        v.detail for v in bad) + "; move the detector out of the beam first",
                        [v.detail for v in bad])
                src.turn_on()
            else:
                src.turn_off()
            return f"light {'on' if on else 'off'}"
        return self._manual(caller, f"light {'on' if on else 'off'}", do)

    def camera_settings(self, caller: Caller, *, exposure_us: float | None = None,
                        gain: float | None = None) -> str:
        """Set the camera's exposure and/or gain between runs (a run sets its own from
        its plan); a value outside the camera's range is refused with the range."""
        if exposure_us is None and gain is None:
            raise ServiceError(422, "give exposure_us, gain or both")

        def do(bench: Bench) -> str:
            cam = bench.camera
            if cam is None:
                raise ServiceError(422, f"bench {self.profile.name!r} has no camera")
            try:
                if exposure_us is not None:
                    cam.exposure_us = exposure_us
                if gain is not None:
                    cam.gain = gain
            except ValueError as err:
                raise ServiceError(422, f"camera settings refused: {err}") from err
            return f"camera: exposure {cam.exposure_us:g} µs, gain {cam.gain:g}"
        what = ", ".join(f"{k} {v:g}" for k, v in (("exposure_us", exposure_us),
                                                    ("gain", gain)) if v is not None)
        return self._manual(caller, f"camera {what}", do)

    def stop_all(self, caller: Caller) -> str:
        """Stop every axis now; during a run, abort it (the engine stops every axis and
        turns the light off). The queue stops too, so that nothing starts moving again by
        itself (the next item, a lobe plan's second pass). Never refused for want of
        control."""
        was_running = self.queue_running
        with self._lock:
            cancelled, applying = list(self._settings), self._applying
            self._settings.clear()
            engine = self.engine
            if engine is not None and engine.alive:
                self.queue_running = False
                engine.abort()
                message = "run aborted: the engine stops every axis and turns the light off"
            elif self.bench is None:
                raise ServiceError(409, "no bench is connected")
            else:
                self.queue_running = False  # nothing starts moving again by itself
                with self._bench_lock:
                    problems = []
                    for role, axis in self.bench.axes.items():
                        try:
                            axis.stop()
                        except DeviceError as err:
                            problems.append(f"{role}: {err}")
                message = "all axes stopped" + (
                    f" (could not stop: {'; '.join(problems)})" if problems else "")
        if applying is not None:
            message += (f"; {applying.role} finishes its setting in progress (request "
                        f"{applying.id})")
        self.hub.publish("manual", {"who": caller.name, "what": "stop all",
                                    "message": message})
        for req in cancelled:
            self._settings_ended(req, "cancelled", f"{req.role}: cancelled by Stop all "
                                 f"({caller.name}) before it was applied")
        if was_running:
            self._publish_queue()
        return message

    # device settings --------------------------------------------------------------------
    def _settings_busy(self) -> bool:
        """A device-settings request waits or is being applied (under ``_lock``)."""
        return self._applying is not None or bool(self._settings)

    def device_settings(self, caller: Caller, role: str, changes: Mapping[str, Any]
                        ) -> dict[str, Any]:
        """Accept a settings change for the device ``role`` (checked now, applied by the
        settings worker); returns ``request_id`` and a message at once. Refused (nothing
        sent) when no bench is connected, a run owns the bench or the queue runs (409), or
        a field is unknown or its value refused (422, naming ``role.field``)."""
        with self._cond:
            bench = self._idle_bench()
            if self.queue_running:
                raise ServiceError(409, "the queue is running: its next run takes the bench "
                                   "at any moment; stop the queue to change device settings")
            device = bench.devices.get(role)
            settable = [r for r, d in bench.devices.items()
                        if (k := kind_of(d)) is not None and k.name in STATE_KINDS]
            if device is None:
                raise ServiceError(422, f"{role}: bench {self.profile.name!r} has no device "
                                   f"{role!r} (devices with settings: "
                                   f"{', '.join(settable) or 'none'})", [role])
            kind = kind_of(device)
            try:
                checked = check_changes(role, kind.name if kind else "unknown", changes,
                                        self._state_info.get(role) or {})
            except SettingRefused as err:
                raise ServiceError(422, err.message, [err.field]) from err
            if len(self._settings) >= MAX_SETTINGS_PENDING:
                raise ServiceError(409, f"{len(self._settings)} device-settings requests "
                                   "wait already: wait for their events")
            req = _SettingsRequest(next(self._settings_ids), caller, role,
                                   kind.name if kind else "unknown", tuple(checked))
            self._settings.append(req)
            message = f"{role}: applying {describe(checked)} (request {req.id})"
            # published before the worker can end it: a client sees applying, then the end
            self.hub.publish("device_settings", req.event("applying", message))
            self._cond.notify_all()
        return {"request_id": req.id, "message": message}

    def _apply_settings(self) -> None:
        """The settings worker: each request in turn, its fields in order, off the bench's
        lock (the sampler leaves the device alone meanwhile); then the device's state as
        it is now goes with the event, and the sampler reads it afresh."""
        while True:
            with self._cond:
                while not self._settings and not self._closed:
                    self._cond.wait(0.5)
                if self._closed:
                    left, self._settings = list(self._settings), collections.deque()
                    break
                req = self._settings.popleft()
                bench, why = self.bench, ""
                device = bench.devices.get(req.role) if bench is not None else None
                if self.engine is not None and self.engine.alive:
                    why = "a run took the bench before it was applied"
                elif device is None:
                    why = "the bench was disconnected before it was applied"
                else:
                    with self._bench_lock:  # a poll of this device in progress ends first
                        self._applying = req
            if device is None or why:
                self._settings_ended(req, "failed", f"{req.role}: {why}")
                continue
            self._apply_one(req, device)
        for req in left:
            self._settings_ended(req, "cancelled", f"{req.role}: the server is closing")

    def _apply_one(self, req: _SettingsRequest, device: Any) -> None:
        field: str | None = None
        try:
            for change in req.changes:
                field = change.field.name
                change.field.apply(device, change.value)
        except (DeviceError, ValueError, TypeError) as err:
            state, message = "failed", f"{req.role}.{field}: {err}"
        else:
            state, message, field = "done", f"{req.role}: {describe(req.changes)} done", None
        now = read_state(req.role, device, with_info=True)
        with self._cond:
            self._applying = None
            self._stale.add(req.role)
            self._cond.notify_all()
        self._settings_ended(req, state, message, field, state_message(now, time.time()))

    def _settings_ended(self, req: _SettingsRequest, state: str, message: str,
                        field: str | None = None,
                        device_state: dict[str, Any] | None = None) -> None:
        """Publish the end of a request and write it to the audit log (the request itself
        is there already, as accepted or refused)."""
        self.hub.publish("device_settings", req.event(state, message, field, device_state))
        with contextlib.suppress(Exception):  # the database closing with the server
            self._audit.write(req.caller.name, req.caller.role, f"device settings request "
                              f"{req.id} ({req.role}): {state}", _ENDED_STATUS[state], message)

    # bench ------------------------------------------------------------------------------
    def connect(self, caller: Caller) -> str:
        with self._cond, self._bench_lock:
            if self.bench is not None:
                return f"bench {self.profile.name!r} is connected"
            try:
                self.bench = self._opener(self.profile)
            except (DeviceError, ProfileError, OSError, ValueError) as err:
                raise ServiceError(502, f"bench {self.profile.name!r}: {err}") from err
            self._cond.notify_all()
        message = f"bench {self.profile.name!r} connected: {len(self.bench.devices)} devices"
        self.hub.publish("bench", {"connected": True, "bench": self.profile.name,
                                   "message": message})
        return message

    def disconnect(self, caller: Caller) -> str:
        with self._cond, self._bench_lock:
            if self.engine is not None and self.engine.alive:
                raise ServiceError(409, "a run owns the bench: abort it first")
            if self._settings_busy():
                raise ServiceError(409, "a device setting is being applied: wait for its "
                                   "device_settings event (or Stop all cancels the waiting "
                                   "ones)")
            bench, self.bench = self.bench, None
            self.queue_running = False
        if bench is not None:
            bench.close()  # stops every axis and turns the light off first
        message = "bench disconnected: axes stopped, light off"
        self.hub.publish("bench", {"connected": False, "bench": self.profile.name,
                                   "message": message})
        return message

    # runner -----------------------------------------------------------------------------
    def _next_item(self) -> QueueItem | None:
        """The item to run next; waits while the queue is stopped. A running queue that
        has run out stops (as a stop marker would), and says so."""
        with self._cond:
            while not self._closed:
                if self.queue_running and self.bench is not None and \
                        not self._settings_busy():  # a setting first, then the run
                    head = self.queue.head()
                    if head is not None:
                        return head
                    self.queue_running = False
                    self.hub.publish("queue", {"running": False, "items": [
                        i.summary() for i in self.queue.items()]})
                self._cond.wait(0.5)
            return None

    def _run_queue(self) -> None:
        while (item := self._next_item()) is not None:
            if item.kind == "stop":
                self.queue.finish(item, "stop marker", "server",
                                  note="the queue stopped at a stop marker")
                with self._cond:
                    self.queue_running = False
                self.hub.publish("item_finished", {"item_id": item.id, "name": item.name,
                                                   "outcome": "stop marker", "run_file": None})
                self._publish_queue()
                continue
            try:
                self._run_item(item)
            except Exception as err:
                self._item_failed(item, f"{type(err).__name__}: {err}")

    def _item_failed(self, item: QueueItem, why: str) -> None:
        self.queue.record(item, "failed", "server", note=why, state="failed")
        self._end_run(stop_queue=True)
        self.hub.publish("item_finished", {"item_id": item.id, "name": item.name,
                                           "outcome": "failed", "run_file": item.run_file})
        self._publish_queue()

    def _engine_for(self, item: QueueItem, bench: Bench) -> tuple[RunEngine | None, str]:
        """A new run for a queued item, or its run file continued; when that file had
        finished, what follows it (:meth:`_after`)."""
        if item.run_file and item.state in RESUMABLE:
            report = recover_run(item.run_file)
            if report.status == "finished":
                return self._after(item, bench, item.run_file)
            # the points already in the file go out after run_started (_on_engine_event)
            self._backfill = (item.run_file, stored_points(item.run_file))
            with self._bench_lock:
                return resume_run(item.run_file, bench, fsync=self.fsync), ""
        plan = build_plan(parse_plan(item.plan_text or "", source=f"queue item {item.id}"),
                          bench.profile)
        with self._bench_lock:  # not while planning: a manual Stop all must not wait
            return start_run(plan, bench, runs_dir=self.runs_dir, fsync=self.fsync), ""

    def _after(self, item: QueueItem, bench: Bench, finished: str
               ) -> tuple[RunEngine | None, str]:
        """The run that follows the item's finished run ``finished``, or None and a note
        when the item is done. Only the first pass of a two-pass lobe plan has a
        follower: its second pass, planned from the first pass's fit exactly as
        ``scatterlab run`` plans it (:mod:`instrument.pipelines.brdf.second_pass`), unless
        it could not beat a single pass of equal time (the note says so, as ``run``
        does). Each step is announced on the event stream (``second_pass``)."""
        # Imported here, not at the top: the lobe planner and the second pass fit BRDF
        # models (SciPy, the BRDF pipeline), which every server start would otherwise
        # import (about 1 s of CPU) though only a finished lobe plan's run needs them.
        from instrument.pipelines.brdf.second_pass import second_pass_plan

        if not self._continues(item, finished):
            return None, ""
        spec = parse_plan(item.plan_text or "", source=f"queue item {item.id}")

        def say(state: str, n_points: int | None, message: str) -> None:
            self.hub.publish("second_pass", {"item_id": item.id, "first_pass": finished,
                                             "state": state, "n_points": n_points,
                                             "message": message})

        say("planning", None, "fitting the first pass and placing the second pass's points")
        try:
            second = second_pass_plan(finished, spec, bench.profile)
        except (ValueError, GuardError) as err:
            raise ValueError(f"the second pass of {Path(finished).name} could not be "
                             f"planned: {err}") from err
        if not second.worthwhile:
            say("not run", 0, second.refusal())
            return None, second.refusal()
        pl, t = second.placement, second.target
        say("planned", len(second.plan.points),
            f"{len(second.plan.points)} points placed by Fisher information on "
            f"{second.model} fitted to the first pass ({second.verdict}); predicted σ({t}) "
            f"{pl.sigma_first[t]:.3g} after the first pass, {pl.sigma_both[t]:.3g} with "
            "the second")
        with self._cond, self._bench_lock:
            if not self.queue_running:  # stopped (or Stop all) while the fit ran
                raise _StoppedBetweenPasses
            return start_run(second.plan, bench, runs_dir=self.runs_dir,
                             fsync=self.fsync), ""

    @staticmethod
    def _continues(item: QueueItem, finished: str) -> bool:
        """Whether the item's run ``finished`` is followed by another (a two-pass lobe
        plan's first pass): then the item is not over when that run is."""
        from instrument.pipelines.brdf.second_pass import is_second_pass
        from instrument.plans.lobe import lobe_of

        spec = parse_plan(item.plan_text or "", source=f"queue item {item.id}")
        return lobe_of(spec) is not None and not is_second_pass(finished)

    def _run_item(self, item: QueueItem) -> None:
        """Run the item: one run, or a two-pass lobe plan's two runs one after the other.
        The item's ``run_file`` names the run in progress, so that after a restart the
        right one is resumed, or the second pass planned after a finished first."""
        bench = self.bench
        assert bench is not None
        finished: str | None = None  # this item's run that has just finished
        while True:
            try:
                engine, note = (self._engine_for(item, bench) if finished is None
                                else self._after(item, bench, finished))
            except _StoppedBetweenPasses:
                self.queue.record(item, "stopped", "server", run_file=finished,
                                  state="aborted", note="the queue was stopped after the "
                                  "first pass; starting it plans and runs the second pass")
                self.hub.publish("item_finished", {"item_id": item.id, "name": item.name,
                                                   "outcome": "stopped",
                                                   "run_file": finished})
                self._publish_queue()
                return
            except (ProfileError, StorageError, DeviceError, ValueError) as err:
                self._item_failed(item, str(err))
                return
            if engine is None:
                run_file = finished or item.run_file
                self.queue.finish(item, "finished", "server", run_file=run_file,
                                  note=note or ("" if finished else
                                                "its run file was complete"))
                self.hub.publish("item_finished", {"item_id": item.id, "name": item.name,
                                                   "outcome": "finished",
                                                   "run_file": run_file})
                self._publish_queue()
                return
            path = str(engine.store.path)
            try:
                with hold(writer_lock_path(path), f"scatterlab serve (queue item {item.id})"):
                    if not self._drive(item, engine, path):
                        return
            except LockHeld as err:
                # The other holder is writing this file: close our handles without
                # writing a status or a journal line into its run.
                engine.store.abandon()
                self._item_failed(item, f"run {Path(path).name} is being continued by "
                                  f"{err.holder}")
                return
            item, finished = self.queue.get(item.id), path

    def _drive(self, item: QueueItem, engine: RunEngine, path: str) -> bool:
        """Run ``engine`` to its end; True when it finished and the item goes on (a
        lobe plan's first pass: the caller plans the second), else the item's outcome is
        recorded (and, unless it finished, the queue stops). The history row is written
        before the run leaves the status and before ``run_finished`` is published."""
        self.queue.set_state(item.id, "running", path)
        with self._cond:
            self.current = self.queue.get(item.id)
            self._pause_now = False
            self._last_fault = None
            self._finished_msg = None
            self.engine = engine
        engine.subscribe(self._on_engine_event)
        engine.subscribe_frames(self._on_frame)
        self._publish_queue()
        engine.start()
        engine.wait()
        state = engine.state
        with self._cond:
            pause_now, self._pause_now = self._pause_now, False
        if state is EngineState.FINISHED:
            if self._continues(item, path):
                self._end_run(stop_queue=False)
                return True
            self.queue.finish(item, "finished", "server", run_file=path)
            self._end_run(stop_queue=False)
            self.hub.publish("item_finished", {"item_id": item.id, "name": item.name,
                                               "outcome": "finished", "run_file": path})
            self._publish_queue()
            return False
        if pause_now:
            self.queue.record(item, "paused", "server", run_file=path, state="paused",
                              note="stopped at once (pause now); resume continues the file")
            outcome = "paused"
        elif state is EngineState.ABORTED:
            self.queue.record(item, "aborted", "server", run_file=path, state="aborted",
                              note="the item stays at the head; starting the queue resumes it")
            outcome = "aborted"
        else:  # failed, or paused and stopped: keep it for a look, stop the queue
            self.queue.record(item, state.value, "server", run_file=path, state="failed",
                              note=engine.snapshot().pause_reason or "")
            outcome = state.value
        self._end_run(stop_queue=True)
        self.hub.publish("item_finished", {"item_id": item.id, "name": item.name,
                                           "outcome": outcome, "run_file": path})
        self._publish_queue()
        return False

    def _end_run(self, *, stop_queue: bool) -> None:
        """After the run's outcome is in the history: the run leaves the status (and the
        queue stops, when asked), then the held-back ``run_finished`` goes out."""
        with self._cond:
            self.engine = None
            self.current = None
            if stop_queue:
                self.queue_running = False
            finished, self._finished_msg = self._finished_msg, None
        if finished is not None:
            self.hub.publish("run_finished", finished)

    def _on_engine_event(self, event: ev.Event) -> None:
        """On the engine's worker thread: one queue put per lifecycle event (the hub does
        the rest). Points and progress are display messages: they are gathered here and
        published by the sampler at most :data:`STATE_HZ` times a second (every point, in
        batches; the newest progress), so the fan-out per second does not grow with the
        engine's rate; a lifecycle event first flushes what was gathered, so that a client
        never sees a run end before its last points."""
        kind, data = event_message(event)
        if kind in ("point", "progress"):
            with self._display_lock:
                if kind == "point":
                    self._points.append(data)
                else:
                    self._progress = data
            return
        self._flush_display()
        if isinstance(event, ev.RunFinished):
            # published by the runner once the history has the outcome (_end_run; it
            # reads this after joining this thread, so no lock is needed — and none is
            # taken while the engine calls its subscribers)
            self._finished_msg = data
            return
        if isinstance(event, ev.Fault):
            self._last_fault = event
        elif isinstance(event, ev.Paused):
            data["answers"] = self._answers()
        elif isinstance(event, ev.Resumed):
            self._last_fault = None
        elif isinstance(event, ev.RunStarted):
            item = self.current
            data["item_id"] = item.id if item is not None else None
        self.hub.publish(kind, data)
        if isinstance(event, ev.RunStarted):
            self._publish_backfill(event)

    def _publish_backfill(self, started: ev.RunStarted) -> None:
        """A resumed run's points stored before it was resumed (after a restart, a pause
        now or an abort), read from its file before the engine reopened it: sent right
        after ``run_started`` as ``backfill`` messages (lifecycle: never dropped; pages of
        at most :data:`~instrument.server.points.MAX_POINTS_PAGE`), so that every client
        draws the run whole; the current-points query has them too."""
        backfill, self._backfill = self._backfill, None
        if backfill is None or started.n_done == 0 or \
                Path(backfill[0]).resolve() != Path(started.path).resolve():
            return
        items = backfill[1]
        parts = max(1, math.ceil(len(items) / MAX_POINTS_PAGE))
        for k in range(parts):
            self.hub.publish("backfill", {
                "run_id": started.run_id, "path": started.path, "n_points": len(items),
                "part": k + 1, "parts": parts,
                "items": items[k * MAX_POINTS_PAGE:(k + 1) * MAX_POINTS_PAGE]})

    def _flush_display(self) -> None:
        with self._display_lock:
            points, self._points = self._points, []
            progress, self._progress = self._progress, None
        if points:
            self.hub.publish("points", {"items": points})
        if progress is not None:
            self.hub.publish("progress", progress)

    def _on_frame(self, index: int, frame: FrameData) -> None:
        self._frame = (index, frame)  # the sampler decimates it (off the worker thread)

    # sampler ----------------------------------------------------------------------------
    def _sample(self) -> None:
        last_state: dict[str, Any] | None = None
        last_sent = 0.0
        last_frame_t = 0.0
        while not self._closed:
            time.sleep(1.0 / STATE_HZ)
            self._flush_display()
            state = self._device_states()
            now = time.monotonic()
            if state is not None and (state != last_state or now - last_sent > 2.0):
                self.hub.publish("devices", state)
                last_state, last_sent = state, now
            frame, self._frame = self._frame, None
            if frame is not None and now - last_frame_t >= 1.0 / FRAME_HZ:
                last_frame_t = now
                self.hub.publish("frame", _frame_message(*frame))

    def _device_states(self) -> dict[str, Any] | None:
        engine = self.engine
        if engine is not None and engine.alive:
            axes = {r: {"position": s.position, "moving": s.is_moving, "homed": s.is_homed}
                    for r, (s, _) in engine.axis_readbacks().items()}
            # the engine owns the devices: the states read before the run, with their age
            return {"axes": axes, "light": None, "owner": "run",
                    "states": {r: m for r, (_, m) in self._states.items()}}
        if not self._bench_lock.acquire(timeout=0.05):
            return None  # a manual command is talking to the bench: next time
        try:
            bench = self.bench
            if bench is None:
                return None
            axes = {}
            for role, axis in bench.axes.items():
                with contextlib.suppress(DeviceError):
                    s = axis.status()
                    axes[role] = {"position": s.position, "moving": s.is_moving,
                                  "homed": s.is_homed}
            light = None
            with contextlib.suppress(DeviceError):
                light = self._light_on(bench)
            camera = None
            if bench.camera is not None:
                with contextlib.suppress(DeviceError):
                    # NaN where a backend cannot report it: null in the message
                    camera = {k: (v if math.isfinite(v) else None) for k, v in (
                        ("exposure_us", float(bench.camera.exposure_us)),
                        ("gain", float(bench.camera.gain)))}
            state = {"axes": axes, "light": light, "owner": "idle", "camera": camera}
        finally:
            self._bench_lock.release()
        state["states"] = self._poll_states(bench)
        return state

    def _poll_states(self, bench: Bench) -> dict[str, dict[str, Any]]:
        """The :data:`STATE_KINDS` devices' states, each read again once its kind's poll
        interval has passed (a lock-in's flags latch between reads; its settings are among
        the values, so a change made at the instrument's front panel shows); the static
        information (identity, tables) once per connection. The bench's lock is taken for
        one device at a time, so that a manual command or Stop all waits for at most one
        device's read (a lock-in's: a few ms, up to ~0.1 s on a loaded machine)."""
        if self._states_of is not bench:  # (re)connected: read everything afresh
            self._states_of = bench
            self._states.clear()
            self._state_info.clear()
        with self._lock:
            stale, self._stale = self._stale, set()
        for role in stale:  # a setting changed: its tables and values are read again now
            self._states.pop(role, None)
            self._state_info.pop(role, None)
        for role, device in bench.devices.items():
            kind = kind_of(device)
            if kind is None or kind.name not in STATE_KINDS:
                continue
            last = self._states.get(role)
            if last is not None and time.monotonic() - last[0] < kind.poll_s:
                continue
            if not self._bench_lock.acquire(timeout=0.05):
                continue  # a manual command is talking to the bench: next time
            try:
                if self.bench is not bench or (self.engine is not None and
                                               self.engine.alive):
                    break  # disconnected, or a run took the bench meanwhile
                if self._applying is not None and self._applying.role == role:
                    continue  # the settings worker talks to it: read it when it is done
                info = self._state_info.get(role)
                state = read_state(role, device, with_info=info is None, info=info)
            finally:
                self._bench_lock.release()
            if info is None and state.error is None:
                self._state_info[role] = state.info
            self._states[role] = (time.monotonic(), state_message(state, time.time()))
        return {r: m for r, (_, m) in self._states.items()}


def _frame_message(index: int, frame: FrameData) -> dict[str, Any]:
    import base64

    img, scale = decimate(frame.data)
    return {"index": index, "shape": list(img.shape), "scale": scale,
            "data": base64.b64encode(img.tobytes()).decode("ascii"),
            # what the display cannot show: the exposure, and the saturated fraction of
            # the full-resolution frame (the decimated one averages saturation away)
            "exposure_us": _finite(float(frame.exposure_us)),
            "saturated": _finite(float(frame.saturated))}
