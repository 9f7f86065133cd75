"""The run engine: one worker thread executes a plan's commands; one writer thread stores.

Per point (plan commands ``Move → Acquire → PointDone``):

1. **Move**: every axis of the step is started, then all are waited for together (the
   slowest sets the step time), polling their status so that an abort can stop them.
2. **Acquire**: first the previous point must be durable (the writer thread has committed
   it: see docs/decisions/0010), so at most one point's data is ever at risk; then frames
   (fixed or auto-exposure with HDR brackets, averaging, dark frames) and a power reading.
3. **PointDone**: the record goes to the writer thread, and the worker starts the next
   move while the writer writes.

Pause takes effect at the next point boundary; abort stops motion at once, turns the light
off and finalises the file. Failures are handled per device by the profile's
:class:`~instrument.bench.profile.RetryPolicy`: ``attempts`` tries of the (idempotent) operation
with doubling back-off, then ``on_failure``: ``rehome`` (home the axis and try once more),
``skip`` (mark the point skipped and go on), ``pause`` (make the bench safe, report, wait
for :meth:`RunEngine.resume`) or ``abort``. Every retry and action is an event and is
logged in the run file. A storage error (disk full) pauses the run; on resume the file is
recovered from its journal and the uncommitted point is taken again.

Events go to subscribers on the worker thread (:mod:`instrument.run.events`).
"""

from __future__ import annotations

import contextlib
import enum
import math
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from drivers.base import AxisStatus, Camera, Frame, LockIn, Modulator, MotionAxis, PowerMeter
from drivers.errors import ControllerError, DeviceError, LimitError, MotionError
from instrument.bench.arms import safe_route
from instrument.bench.devices import Bench
from instrument.bench.dynamics import move_time
from instrument.bench.kinematics import TYPE_I_AXES, kinematics_of
from instrument.bench.profile import SPIN_ROLE, RetryPolicy
from instrument.plans.adaptive import AdaptiveDriver
from instrument.plans.build import Plan, dynamics_of
from instrument.plans.commands import Acquire, AcquisitionPolicy, Move, PointDone, SetLight
from instrument.plans.polarimetry_pem import DEFAULT_READS, DEFAULT_TIME_CONSTANTS
from instrument.run.events import (
    AxisHomed,
    Event,
    Fault,
    Paused,
    PointCompleted,
    Progress,
    Resumed,
    RunFinished,
    RunStarted,
)
from instrument.run.pem_reading import HarmonicLockIn, read_pem
from instrument.run.spinner import start_spinner
from instrument.run.storage import (
    STATUS_OK,
    STATUS_SKIPPED,
    FrameData,
    PointRecord,
    RunStore,
    StorageError,
)

__all__ = ["EngineSnapshot", "EngineState", "RunEngine"]

#: Seconds a point's write may take before the engine turns the light off and reports a
#: storage fault while it goes on waiting (a stalled disk or network share: an HDF5 write
#: in flight cannot be abandoned safely, but the sample need not stay lit meanwhile).
STORAGE_STALL_S = 30.0


class EngineState(enum.Enum):
    IDLE = "idle"
    RUNNING = "running"
    PAUSED = "paused"
    FINISHED = "finished"
    ABORTED = "aborted"
    FAILED = "failed"


@dataclass(frozen=True)
class EngineSnapshot:
    """What a client polling the engine (a GUI timer) needs, read under the lock."""

    state: EngineState
    n_done: int
    n_total: int
    n_skipped: int
    elapsed_s: float
    path: str
    pause_reason: str | None


class _Abort(Exception):
    """Internal: leave the run now."""


class _PointFailed(Exception):
    def __init__(self, action: str, device: str, cause: str) -> None:
        super().__init__(cause)
        self.action = action
        self.device = device
        self.cause = cause


@dataclass
class _PointState:
    index: int
    label: str = "sample"
    t_start: float = 0.0
    positions: dict[str, float] = field(default_factory=dict)
    frames: list[FrameData] = field(default_factory=list)
    exposure_us: float = math.nan
    power_w: float = math.nan
    signal: float = math.nan
    retries: int = 0
    main: FrameData | None = None  # the longest unsaturated light bracket (live views)
    extra: dict[str, float] = field(default_factory=dict)  # lock-in and filter readings


class RunEngine:
    """Run ``plan`` on ``bench`` into ``store``.

    Parameters
    ----------
    done
        Indices already in the run file (resume): they are not run again.
    move_timeout_factor, move_timeout_min_s
        A step may take ``factor × planned time + min`` seconds before it counts as a
        timeout (then the axes are stopped and the device's retry policy applies).
    poll_s
        Seconds between status polls of moving axes: the end of a step is noticed on
        average ``poll_s/2`` late, a cost paid at every point (scan efficiency).
    reopen_store
        Called to reopen the run file after a storage error (default:
        :meth:`RunStore.reopen` on the same path with the same settings).
    adaptive
        The driver of an adaptive plan (:mod:`instrument.plans.adaptive`): when every
        point of the plan is done it is asked for more, which are committed to the run
        file's planned table (:meth:`RunStore.extend_plan`) before they are run.
    wait
        Waits out a known, bounded time: the sample spinner's acceleration ramp, at the
        start and when it spins up again after a pause (tests pass an emulated clock's
        ``advance``).
    """

    def __init__(self, bench: Bench, plan: Plan, store: RunStore, *,
                 done: set[int] | frozenset[int] = frozenset(),
                 move_timeout_factor: float = 3.0, move_timeout_min_s: float = 10.0,
                 poll_s: float = 0.002,
                 reopen_store: Callable[[], tuple[RunStore, set[int]]] | None = None,
                 adaptive: AdaptiveDriver | None = None,
                 wait: Callable[[float], object] = time.sleep) -> None:
        self.bench = bench
        #: Waits out a bounded, known time (the spinner's ramp); an emulated clock's
        #: ``advance`` in tests.
        self._wait = wait
        #: An adaptive plan's driver: asked for more points when the plan's are done.
        self._adaptive = adaptive
        self.plan = plan
        self.store = store
        self._n_total = len(plan.points)
        self._done = _DoneSet(self._n_total, done)
        self._n_skipped = 0
        self._subscribers: list[Callable[[Event], None]] = []
        self._frame_subscribers: list[Callable[[int, FrameData], None]] = []
        self._skip_requested = False
        self._lock = threading.Condition()
        self._state = EngineState.IDLE
        self._pause_requested: str | None = None
        self._abort_requested = False
        self._resume_requested = False
        self._thread: threading.Thread | None = None
        self._writer: _Writer | None = None
        self._move_factor = move_timeout_factor
        self._move_min = move_timeout_min_s
        self._poll_s = poll_s
        self._reopen = reopen_store or (lambda: RunStore.reopen(
            store.path, fsync=store.fsync, sync_interval_s=store.sync_interval_s,
            min_free_bytes=store.min_free_bytes))
        self._dyn = dynamics_of(plan.profile, plan.axes)
        self._kin = kinematics_of(plan.profile.geometry)
        # The bench's devices do not change during a run: look them up once.
        self._camera = bench.camera
        self._pm = bench.power_meter
        self._lockin = getattr(bench, "lockin", None)
        # A PEM polarimeter's modulator (ADR 0106): set to each point's amplitude.
        self._modulator = next((d for d in bench.devices.values()
                                if isinstance(d, Modulator)), None)
        self._pem_state: dict[str, float] | None = None  # what the modulator was set to
        self._wheel = getattr(bench, "filter_wheel", None)
        self._wheel_slot: int | None = None  # the slot this engine last put in the beam
        # The attenuation ladder for a camera that saturates at its shortest exposure: the
        # open slot, then the wheel's neutral-density filters by optical density (a wheel
        # that carries a wavelength axis's band-pass filters is not used for this).
        self._nd_ladder: list[tuple[int, float]] | None = None
        self._nd_level = 0  # where the next point starts (predicted from the last one)
        # Light and dark frames switch the shutter when the bench has one, else the source;
        # with a shutter in front of a switchable source, the source is turned on with the
        # first light and left on (a laser is not cycled for every dark frame).
        self._source = getattr(bench, "light_switch", bench.source)
        lamp = bench.source
        self._lamp = lamp if lamp is not None and lamp is not self._source else None
        self._lamp_on = False
        self._roles = {id(d): r for r, d in bench.devices.items()}
        self._policies = {r: self._policy(r) for r in bench.devices}
        self._light: bool | None = None
        self._last_exposure: float | None = None
        # Exposures (µs) a dark frame of this run was taken at: with auto-exposure and
        # ``dark = "start"`` a lit exposure without one gets its dark frame when first used.
        self._dark_exposures: set[float] = set()
        self._t0 = 0.0
        self._point_dt: float | None = None
        self._message = ""
        self._position_cache: dict[str, float] = {}
        # The newest status read of each axis and when (monotonic s), for a client that
        # shows the bench during the run (the engine owns the drivers then).
        self._readbacks: dict[str, tuple[AxisStatus, float]] = {}
        self._readback_lock = threading.Lock()
        self._wheel_readback: tuple[str, int, float] | None = None

    # public API (any thread) ----------------------------------------------------
    def subscribe(self, callback: Callable[[Event], None]) -> None:
        """Call ``callback(event)`` on the worker thread for every event."""
        self._subscribers.append(callback)

    def unsubscribe(self, callback: Callable[..., None]) -> None:
        """Stop calling ``callback`` (a closing GUI window); unknown callbacks are ignored."""
        with contextlib.suppress(ValueError):
            self._subscribers.remove(callback)
        with contextlib.suppress(ValueError):
            self._frame_subscribers.remove(callback)

    def subscribe_frames(self, callback: Callable[[int, FrameData], None]) -> None:
        """Call ``callback(index, frame)`` on the worker thread with each stored point's main
        frame (the longest unsaturated bracket), just before its :class:`PointCompleted`.

        For live views (the latest image, a light field growing row by row): the callback
        must return quickly and keep no more of the frame than it needs. A callback that
        raises is dropped, as an event subscriber is.
        """
        self._frame_subscribers.append(callback)

    def axis_readbacks(self) -> dict[str, tuple[AxisStatus, float]]:
        """The newest status the engine read from each axis, with its ``time.monotonic()``
        stamp; safe from any thread. Axes the run has not read yet are absent."""
        with self._readback_lock:
            return dict(self._readbacks)

    def wheel_readback(self) -> tuple[str, int, float] | None:
        """(role, slot, ``time.monotonic()`` stamp) of the filter wheel's slot as the
        engine last read or set it; None before it touched the wheel. Safe from any
        thread, no device call (what the GUI shows during a run, ADR 0062)."""
        with self._readback_lock:
            return self._wheel_readback

    def _wheel_at(self, slot: int) -> None:
        role = self._roles[id(self._wheel)]
        with self._readback_lock:
            self._wheel_readback = (role, int(slot), time.monotonic())

    def _read_back(self, role: str, status: AxisStatus) -> AxisStatus:
        with self._readback_lock:
            self._readbacks[role] = (status, time.monotonic())
        return status

    @property
    def state(self) -> EngineState:
        with self._lock:
            return self._state

    @property
    def n_done(self) -> int:
        return len(self._done)

    def snapshot(self) -> EngineSnapshot:
        """State and counts now; safe from any thread."""
        with self._lock:
            elapsed = time.monotonic() - self._t0 if self._t0 else 0.0
            return EngineSnapshot(self._state, len(self._done), self._n_total,
                                  self._n_skipped, elapsed, str(self.store.path),
                                  self._pause_requested
                                  if self._state is EngineState.PAUSED else None)

    def start(self) -> None:
        """Start the worker thread; returns at once."""
        with self._lock:
            if self._thread is not None:
                raise RuntimeError("the engine runs a plan once; make a new engine")
            self._state = EngineState.RUNNING
        self._thread = threading.Thread(target=self._main, name="run-engine", daemon=True)
        self._thread.start()

    def run(self) -> EngineState:
        """Start and wait for the end (scripts, tests)."""
        self.start()
        return self.wait()

    def wait(self, timeout: float | None = None) -> EngineState:
        """Block until the worker ends (finished, aborted, failed, or paused and stopped)."""
        if self._thread is not None:
            self._thread.join(timeout)
        return self.state

    @property
    def alive(self) -> bool:
        """True from :meth:`start` until the worker thread has ended (paused counts)."""
        return self._thread is not None and self._thread.is_alive()

    def pause(self, reason: str = "paused by the operator") -> None:
        """Pause at the next point boundary."""
        with self._lock:
            self._pause_requested = reason
            self._lock.notify_all()

    def resume(self, *, skip_point: bool = False) -> None:
        """Continue a paused run.

        After a pause for a point's fault the point is tried again; with ``skip_point`` it
        is stored as skipped instead (status 1, its note naming the fault and the
        operator's choice) and the run goes on with the next one. ``skip_point`` means
        nothing after a pause between points (there is no failed point to skip).
        """
        with self._lock:
            self._pause_requested = None
            self._resume_requested = True
            self._skip_requested = bool(skip_point)
            self._lock.notify_all()

    def abort(self) -> None:
        """Stop motion now, turn the light off, finalise the file."""
        with self._lock:
            self._abort_requested = True
            self._lock.notify_all()

    def stop_when_paused(self) -> None:
        """Make a paused engine end its thread with status ``paused`` (resumable later)."""
        with self._lock:
            self._abort_requested = True
            self._stop_paused = True
            self._lock.notify_all()

    # worker ---------------------------------------------------------------------
    def _emit(self, event: Event) -> None:
        for cb in list(self._subscribers):
            try:
                cb(event)
            except Exception as err:  # a broken subscriber must not stop the hardware
                print(f"scatterlab: event subscriber {cb!r} failed: {err!r}", file=sys.stderr)
                self.unsubscribe(cb)

    def _emit_frame(self, index: int, frame: FrameData) -> None:
        for cb in list(self._frame_subscribers):
            try:
                cb(index, frame)
            except Exception as err:  # a broken live view must not stop the hardware
                print(f"scatterlab: frame subscriber {cb!r} failed: {err!r}", file=sys.stderr)
                self.unsubscribe(cb)

    def _main(self) -> None:
        status = "failed"
        self._t0 = time.monotonic()
        self._writer = _Writer(self.store)
        try:
            est = self.plan.estimate()
            self._emit(RunStarted(self.store.header.run_id, str(self.store.path),
                                  self.plan.kind, self._n_total, len(self._done),
                                  est.total_s * (1 - len(self._done) / max(1, self._n_total))
                                  + self._homing_s(est.homing_s)))
            self._prepare()
            status = self._loop()
        except _Abort:
            status = "paused" if getattr(self, "_stop_paused", False) else "aborted"
        except Exception as err:
            self._message = f"{type(err).__name__}: {err}"
            status = "failed"
            self._emit(Fault(getattr(err, "device", None) or "engine", str(err), "abort", None))
        finally:
            notes = [self._message] if self._message else []
            problems = self.bench.make_safe()
            if problems:
                notes.append("could not make safe: " + "; ".join(problems))
            try:
                self._writer.drain()
            except Exception as err:  # a storage error, or a bug: the run must still end
                self._store_broken = True
                notes.append(f"last point not stored: {err}")
            self._writer.stop()
            if self.store.closed:
                notes.append("the run file was closed at the storage error; "
                             "`scatterlab resume` continues it")
            else:
                try:
                    if self._store_broken:
                        raise StorageError(5, "the run file had a write error")
                    if status == "paused":
                        self.store.event({"kind": "paused",
                                          "reason": "run stopped while paused"})
                    self.store.close(status)
                except Exception as err:
                    self.store.abandon()
                    if status == "finished":
                        status = "paused"
                    notes.append(f"file not finalised ({err}); `scatterlab resume` "
                                 "repairs it")
            self._message = "; ".join(notes)
            with self._lock:
                self._state = {"finished": EngineState.FINISHED, "aborted": EngineState.ABORTED,
                               "paused": EngineState.PAUSED}.get(status, EngineState.FAILED)
            self._emit(RunFinished(status, len(self._done), self._n_total, self._n_skipped,
                                   str(self.store.path), time.monotonic() - self._t0,
                                   self._message))

    def _homing_s(self, homing_s: dict[str, float]) -> float:
        """Seconds :meth:`_prepare` will spend homing the plan's axes that are not homed."""
        total = 0.0
        for role in self.plan.axes:
            try:
                if not self._axis(role).status().is_homed:
                    total += homing_s.get(role, 0.0)
            except (DeviceError, _PointFailed):
                continue  # _prepare reports it
        return total

    def _prepare(self) -> None:
        """Enable and home every axis the plan moves (homing is skipped when homed); spin
        the sample when the plan asks (:mod:`instrument.run.spinner`)."""
        for role in self.plan.axes:
            axis = self._axis(role)
            policy = self._policy(role)
            status = self._read_back(role, self._retry(role, policy, "status", axis.status))
            if not status.is_enabled:
                self._retry(role, policy, "enable", axis.enable)
            if not status.is_homed:
                t0 = time.monotonic()
                # a default argument binds the loop's value; mypy cannot infer such a lambda
                self._retry(role, policy, "home",
                            lambda a=axis: a.home(timeout=300.0))  # type: ignore[misc]
                after = self._read_back(role, self._retry(role, policy, "status",
                                                          axis.status))
                self.store_event("homed", device=role, position=after.position)
                self._emit(AxisHomed(role, after.position, time.monotonic() - t0))
        spin = self.plan.spec.acquisition.spin_deg_s
        if spin > 0.0:
            # spun through the run; make_safe stops it with the other axes (ADR 0098)
            start_spinner(self.bench.devices, spin, sleep=self._wait)
            self._spin_stopped = False
            self.store_event("spinning", device=SPIN_ROLE, deg_per_s=spin)

    def _spin_up(self, st: _PointState) -> None:
        """Spin the sample again after a pause stopped it (``make_safe``), waiting for its
        speed before the next exposure (ADR 0098): a frame taken on a sample still
        ramping up, or standing, would average fewer speckle patterns than the
        reduction's σ assume. A failure is the spinner's fault, handled by its policy."""
        spin = self.plan.spec.acquisition.spin_deg_s
        if spin <= 0.0 or not self._spin_stopped:
            return
        self._retry(SPIN_ROLE, self._policy(SPIN_ROLE), "spin",
                    lambda: start_spinner(self.bench.devices, spin, sleep=self._wait), st)
        self._spin_stopped = False
        self.store_event("spinning", device=SPIN_ROLE, deg_per_s=spin, index=st.index)

    def _loop(self) -> str:
        while True:
            try:
                group: list[Any] = []
                for cmd in self.plan.commands(self._done.snapshot()):
                    match cmd:
                        case SetLight(on=on):
                            self._set_light(on)
                        case Move():
                            group = [cmd]
                        case Acquire():
                            group.append(cmd)
                        case PointDone():
                            group.append(cmd)
                            self._run_point(group)
                            group = []
                self._commit_wait_or_pause(None)
                if self._adaptive is not None and self._grow():
                    continue
                break
            except _Restart:
                # The run file was recovered from its journal after a storage error:
                # start the plan again from the first point it does not hold.
                continue
        with self._lock:
            n = len(self._done)
        return "finished" if n >= self._n_total else "paused"

    def _grow(self) -> bool:
        """Ask the adaptive plan for its next points; commit and add them (ADR 0091).
        Returns False when it is done. Refused points are logged in the run file."""
        with self._lock:
            if self._abort_requested:
                raise _Abort
        assert self._adaptive is not None  # only an adaptive plan grows
        assert self._writer is not None
        decision = self._adaptive.decide(self.plan)
        if decision is None:
            self.store_event("adaptive_done", rounds=self._adaptive.rounds)
            return False
        for ti, tr, reason in decision.record["refused"]:
            self.store_event("refused", theta_i=ti, theta_r=tr, reason=reason)
        self._writer.call(lambda: self.store.extend_plan(decision.rows, decision.record))
        self.plan = replace(self.plan, points=self.plan.points + tuple(decision.points))
        with self._lock:
            self._n_total = len(self.plan.points)
            self._done.grow(self._n_total)
        return True

    # points -----------------------------------------------------------------------
    def _run_point(self, group: list[Any]) -> None:
        move: Move = group[0]
        acq: Acquire = group[1]
        while True:
            self._boundary(move.index)
            try:
                st = self._execute(move, acq)
            except _PointFailed as fail:
                self._emit(Fault(fail.device, fail.cause, fail.action, move.index))
                self.store_event("fault", device=fail.device, cause=fail.cause,
                                 action=fail.action, index=move.index)
                if fail.action == "skip point":
                    self._submit(_PointState(move.index, acq.label, time.time()),
                                 skipped=fail.cause)
                    return
                if fail.action == "abort":
                    self._message = f"{fail.device}: {fail.cause}"
                    raise _Abort from fail
                if self._enter_pause(f"{fail.device}: {fail.cause}", move.index):
                    cause = f"skipped by the operator after {fail.device}: {fail.cause}"
                    self.store_event("skipped", index=move.index, reason=cause)
                    self._submit(_PointState(move.index, acq.label, time.time()),
                                 skipped=cause)
                    return
                continue
            self._submit(st)
            return

    def _execute(self, move: Move, acq: Acquire) -> _PointState:
        st = _PointState(move.index, acq.label, time.time())
        self._move(move, st)
        # Durability: the previous point is on disk before this one acquires anything.
        self._commit_wait_or_pause(move.index)
        self._spin_up(st)
        self._acquire(acq, st)
        return st

    def _boundary(self, index: int) -> None:
        with self._lock:
            if self._abort_requested:
                raise _Abort
            reason = self._pause_requested
        if reason is not None:
            self._enter_pause(reason, index)

    def _enter_pause(self, reason: str, index: int | None) -> bool:
        """Make safe, report, wait for resume or abort; return whether the operator asked
        to skip the point (:meth:`resume`)."""
        # A pause is for a person at the bench (a door opened, a sample touched): every
        # axis stands still, the spinner too; it spins up again before the next exposure.
        self.bench.make_safe()
        self._spin_stopped = True
        self._light = None  # re-applied on resume
        self._pem_state = None  # the modulator too: an operator may have set it meanwhile
        if not self._store_broken:
            assert self._writer is not None
            try:
                self._writer.call(self.store.sync)
            except StorageError:
                self._store_broken = True
        self.store_event("paused", reason=reason, index=index)
        with self._lock:
            self._state = EngineState.PAUSED
            self._pause_requested = reason
            self._resume_requested = False
        self._emit(Paused(reason, index))
        with self._lock:
            while not (self._resume_requested or self._abort_requested):
                self._lock.wait()
            if self._abort_requested:
                raise _Abort
            self._state = EngineState.RUNNING
            self._resume_requested = False
            skip, self._skip_requested = self._skip_requested, False
        if self._store_broken:
            self._reopen_store()
        self.store_event("resumed", index=index)
        self._emit(Resumed(index))
        want = self._light_wanted
        if want is not None:
            self._set_light(want)
        return skip

    _store_broken = False
    _light_wanted: bool | None = None
    _spin_stopped = True  # the spinner is not (known to be) at the plan's speed

    def _reopen_store(self) -> None:
        assert self._writer is not None
        self._writer.stop()
        self.store.abandon()
        self.store, done = self._reopen()
        with self._lock:
            self._done = _DoneSet(self._n_total, done)
        self._writer = _Writer(self.store)
        self._store_broken = False
        for line in self.store.repairs:  # what the recovery did, said where the run is shown
            self._emit(Fault("storage", f"repaired: {line}", "continue", None))

    def store_event(self, kind: str, **fields: Any) -> None:
        if self._store_broken:
            return
        assert self._writer is not None
        try:
            self._writer.call(lambda: self.store.event({"kind": kind, **fields}))
        except StorageError:
            self._store_broken = True

    def _commit_wait_or_pause(self, index: int | None) -> None:
        """Wait until the writer has committed the previous point; pause on a storage error.

        After a pause for a storage error the run file is recovered from its journal and
        the uncommitted point is run again, so nothing is missing or duplicated.
        """
        while True:
            assert self._writer is not None  # a new one after each storage recovery
            try:
                self._writer.drain(stall_s=STORAGE_STALL_S,
                                   on_stall=lambda: self._storage_stalled(index))
                return
            except StorageError as err:
                self._store_broken = True
                with self._lock:
                    self._done.discard_all(self._writer.failed)
                # Close the damaged handle now: while paused the file on disk is closed
                # and valid (recover() makes it agree with the journal).
                self._writer.stop()
                self._log_storage_pause(err, index)
                self._emit(Fault("storage", str(err), "pause", index))
                self._enter_pause(f"storage: {err}", index)
                # Recovered from the journal: the lost point is not in done any more.
                raise _Restart from err

    def _log_storage_pause(self, err: StorageError, index: int | None) -> None:
        """Close the store after a storage error, with the fault and the pause in the run
        file's event log like any other fault's (docs/guide/recovery.md).

        After a clean error (nothing written: the free-space check or the space
        reservation refused the point) the file is intact and the events go in as usual,
        into the free-space margin; after a failed write the store is abandoned and they
        go into the journal, from which the recovery before the run continues rewrites
        the log. Its resolution is the "resumed" event of the continued run."""
        todo = [{"kind": "fault", "device": "storage", "cause": str(err),
                 "action": "pause", "index": index},
                {"kind": "paused", "reason": f"storage: {err}", "index": index}]
        if getattr(err, "clean", False):
            try:
                while todo:
                    self.store.event(todo[0])
                    todo.pop(0)
                self.store.close("paused")
                return
            except Exception:
                self.store.abandon()
        else:
            self.store.abandon()
        with contextlib.suppress(StorageError):
            for record in todo:
                self.store.journal_event(record)

    def _storage_stalled(self, index: int | None) -> None:
        """The previous point's write is taking too long: make the bench safe (the axes
        are at rest here), say so, and let the next acquisition restore the light."""
        problems = self.bench.make_safe()
        self._light = None  # the next Acquire turns the light back to what it needs
        action = "light off, waiting for the write"
        if problems:
            action += "; could not make safe: " + "; ".join(problems)
        self._emit(Fault("storage", f"writing the previous point to {self.store.path} has "
                         f"taken over {STORAGE_STALL_S:g} s (disk or network share "
                         "stalled?)", action, index))

    def _submit(self, st: _PointState, skipped: str | None = None) -> None:
        axes = self.plan.axes
        positions = tuple(st.positions.get(r, math.nan) for r in axes)
        angles = (math.nan,) * 4
        point = self.plan.points[st.index]
        if point.angles is not None and all(r in st.positions for r in self._kin.axes):
            angles = self._kin.angles(st.positions).as_tuple()
        rec = PointRecord(st.index, st.label, st.t_start, time.time(), positions, angles,
                          st.exposure_us, st.power_w, st.signal,
                          STATUS_SKIPPED if skipped else STATUS_OK, st.retries,
                          skipped or "", st.frames, dict(st.extra))
        assert self._writer is not None
        if st.frames:
            self._writer.submit(rec)  # frames: written while the next move runs
        else:
            # Scalars only: a journal line costs less than a hand-over to the writer
            # thread; store it here (same durability, same order: the writer is idle).
            self._commit_wait_or_pause(st.index)
            try:
                self._writer.call(lambda: self.store.append(rec), inline=True)
            except StorageError:
                self._writer.failed.append(st.index)
                self._commit_wait_or_pause(st.index)  # pauses; raises _Restart on resume
        with self._lock:
            self._done.add(st.index)
            n = len(self._done)
        if self._adaptive is not None:
            self._adaptive.observe_point(st.index, None if math.isnan(angles[0]) else angles,
                                         st.signal, not skipped)
        if skipped:
            self._n_skipped += 1
        now = time.monotonic()
        dt = now - getattr(self, "_last_point_t", self._t0)
        self._last_point_t = now
        self._point_dt = dt if self._point_dt is None else 0.9 * self._point_dt + 0.1 * dt
        if st.main is not None and not skipped:
            self._emit_frame(st.index, st.main)
        nd = st.extra.get("nd_position", math.nan)
        self._emit(PointCompleted(st.index, st.label, "skipped" if skipped else "ok",
                                  dict(st.positions),
                                  None if math.isnan(angles[0]) else angles,
                                  st.exposure_us, st.power_w, st.signal, st.retries,
                                  nd_slot=-1 if math.isnan(nd) else int(nd)))
        self._emit(Progress(n, self._n_total, now - self._t0,
                            (self._n_total - n) * (self._point_dt or 0.0)))

    # devices ------------------------------------------------------------------------
    def _axis(self, role: str) -> MotionAxis:
        dev = self.bench.devices.get(role)
        if not isinstance(dev, MotionAxis):
            raise _PointFailed("abort", role, f"the bench has no axis {role!r}")
        return dev

    def _policy(self, role: str) -> RetryPolicy:
        spec = self.plan.profile.devices.get(role)
        return spec.retry if spec is not None else RetryPolicy()

    def _retry(self, role: str, policy: RetryPolicy, what: str, fn: Callable[[], Any],
               st: _PointState | None = None,
               *, on_exhausted: Callable[[], object] | None = None) -> Any:
        """Run ``fn`` up to ``policy.attempts`` times with doubling back-off."""
        delay = policy.backoff_s
        last: DeviceError | None = None
        for attempt in range(1, policy.attempts + 1):
            with self._lock:
                if self._abort_requested:
                    raise _Abort
            try:
                return fn()
            except DeviceError as err:
                last = err
                if st is not None:
                    st.retries += 1
                if attempt < policy.attempts:
                    action = f"retry {attempt}/{policy.attempts - 1}"
                    self._emit(Fault(role, f"{what}: {err}", action,
                                     None if st is None else st.index))
                    self.store_event("fault", device=role, cause=f"{what}: {err}",
                                     action=action, index=None if st is None else st.index)
                    time.sleep(delay)
                    delay *= 2
        assert last is not None
        cause = f"{what} failed {policy.attempts} time(s): {last}"
        if policy.on_failure == "rehome" and on_exhausted is not None:
            self._emit(Fault(role, cause, "rehome", None if st is None else st.index))
            self.store_event("fault", device=role, cause=cause, action="rehome",
                             index=None if st is None else st.index)
            try:
                on_exhausted()
                return fn()
            except DeviceError as err:
                raise _PointFailed("pause", role, f"{what} failed after re-homing: {err}"
                                   ) from err
        action = {"skip": "skip point", "abort": "abort", "pause": "pause",
                  "rehome": "pause"}[policy.on_failure]
        raise _PointFailed(action, role, cause) from last

    def _move(self, move: Move, st: _PointState) -> None:
        targets = dict(move.targets)
        for leg in self._route(targets):
            self._move_together(leg, st)
        self._move_together(targets, st)

    def _route(self, targets: dict[str, float]) -> list[dict[str, float]]:
        """The intermediate moves before ``targets`` on a type (i) bench (ADR 0099): none
        when the arms can move together from where they stand, else the legs of
        :func:`instrument.bench.arms.safe_route`. Decided before anything moves: a move
        with no collision-free route pauses the run instead."""
        profile = self.plan.profile
        if not (profile.geometry.is_type_i and all(r in targets for r in TYPE_I_AXES)):
            return []
        here = {}
        for role in TYPE_I_AXES:
            cached = self._position_cache.get(role)
            here[role] = (cached if cached is not None else
                          self._read_back(role, self._axis(role).status()).position)
        route = safe_route(profile.geometry, self._dyn, here, targets,
                           limits={r: d.limits for r, d in profile.axes.items()})
        if route is None:
            # no device failed: the fault names the two arms together
            raise _PointFailed("pause", "arms", "no collision-free route for the arms "
                               "from where they stand to this point; move them apart by "
                               "hand and resume")
        if route.split:
            self.store_event("route", how=route.how, legs=len(route.moves))
        return [dict(leg) for leg in route.moves[:-1]]

    def _move_together(self, targets: dict[str, float], st: _PointState) -> None:
        """Start every axis of ``targets``, then wait for them all."""
        moving: dict[str, MotionAxis] = {}
        plan_time = 0.0
        for role, target in targets.items():
            axis = self._axis(role)
            here = self._position_cache.get(role)
            if here is not None and abs(here - target) <= axis.position_tolerance / 2:
                st.positions[role] = here
                continue  # already there: no command, no wait
            plan_time = max(plan_time, move_time(target - (here or 0.0), self._dyn[role]))
            self._position_cache.pop(role, None)

            def start(a: MotionAxis = axis, t: float = target) -> None:
                a.move_to(t)

            # a default argument binds the loop's value; mypy cannot infer such a lambda
            self._retry(role, self._policy(role), f"move to {target:g}", start, st,
                        on_exhausted=lambda a=axis: self._rehome(a))  # type: ignore[misc]
            moving[role] = axis
        if not moving:
            return
        timeout = self._move_factor * plan_time + self._move_min
        self._wait_axes(moving, targets, timeout, st)
        if self._camera is not None:
            self._camera.invalidate()

    def _rehome(self, axis: MotionAxis) -> None:
        axis.stop()
        axis.home(timeout=300.0)

    def _wait_axes(self, moving: dict[str, MotionAxis], targets: dict[str, float],
                   timeout: float, st: _PointState) -> None:
        deadline = time.monotonic() + timeout
        pending = dict(moving)
        while pending:
            with self._lock:
                if self._abort_requested:
                    for a in moving.values():
                        a.stop()
                    raise _Abort
            for role, axis in list(pending.items()):
                try:
                    s = self._read_back(role, axis.status())
                except DeviceError as err:
                    s = None
                    fail = err
                if s is not None and not s.is_moving and not s.is_homing:
                    del pending[role]
                    self._finish_axis(role, axis, targets[role], st, s)
                elif s is None:
                    del pending[role]
                    self._recover_axis(role, axis, targets[role], st, fail)
            if pending:
                if time.monotonic() > deadline:
                    for role, axis in pending.items():
                        axis.stop()
                        err = DeviceError(f"move to {targets[role]:g} not done after "
                                          f"{timeout:.3g} s; stopped", device=role)
                        self._recover_axis(role, axis, targets[role], st, err)
                    return
                time.sleep(self._poll_s)

    def _finish_axis(self, role: str, axis: MotionAxis, target: float,
                     st: _PointState, status: AxisStatus) -> None:
        """Motion has ended: check limits and arrival from the status just read (the
        checks of :meth:`MotionAxis.wait`, without another round trip to the device)."""
        err: DeviceError | None = None
        if status.error:
            err = DeviceError(f"controller error: {status.error}", device=role)
        elif status.at_forward_limit or status.at_reverse_limit:
            err = LimitError(f"a limit switch stopped the axis at {status.position:.6g}",
                             device=role, command="move")
        elif abs(status.position - target) > axis.position_tolerance:
            err = MotionError(f"stopped at {status.position:.6g}, "
                              f"{status.position - target:+.3g} from the target {target:.6g}",
                              device=role, command="move")
        if err is not None:
            self._recover_axis(role, axis, target, st, err)
            return
        st.positions[role] = status.position
        self._position_cache[role] = status.position

    def _recover_axis(self, role: str, axis: MotionAxis, target: float, st: _PointState,
                      err: DeviceError) -> None:
        """A move failed: report, then retry the (absolute, idempotent) move per policy."""
        policy = self._policy(role)
        st.retries += 1
        self._position_cache.pop(role, None)
        self._emit(Fault(role, f"move to {target:g}: {err}", "retry", st.index))
        self.store_event("fault", device=role, cause=f"move to {target:g}: {err}",
                         action="retry", index=st.index)

        def again() -> float:
            axis.stop()
            axis.move_to(target, wait=True, timeout=self._move_min + 60.0)
            return axis.position

        retry_policy = RetryPolicy(max(1, policy.attempts - 1), policy.backoff_s,
                                   policy.on_failure)
        pos = self._retry(role, retry_policy, f"move to {target:g}", again, st,
                          on_exhausted=lambda: self._rehome(axis))
        st.positions[role] = float(pos)
        self._position_cache[role] = float(pos)

    def _set_light(self, on: bool) -> None:
        self._light_wanted = on
        if self._light is on:
            return
        src = self._source
        if src is None:
            self._light = on
            return
        if on and self._lamp is not None and not self._lamp_on:
            lamp_role = self._roles[id(self._lamp)]
            self._retry(lamp_role, self._policies[lamp_role], "turn on", self._lamp.turn_on)
            self._lamp_on = True
        role = self._roles[id(src)]
        self._retry(role, self._policies[role], "turn on" if on else "turn off",
                    src.turn_on if on else src.turn_off)
        self._light = on
        # The scene changed: frames a camera buffered before the switch are of the other
        # lighting (a dark frame would be lit, or the reverse).
        if self._camera is not None:
            self._camera.invalidate()

    def _acquire(self, acq: Acquire, st: _PointState) -> None:
        policy = acq.policy
        slot = dict(self.plan.points[acq.index].meta).get("filter")
        if slot is not None and self._wheel is not None:
            self._select_filter(int(slot), st)
        cam = self._camera if policy.uses_camera else None
        pm = self._pm if policy.uses_power_meter else None
        lockin = self._lockin if policy.uses_lockin else None
        if acq.light != self._light and self._source is not None:
            self._set_light(acq.light)
        ladder = self._attenuation_ladder(st) if (cam is not None and acq.light
                                                   and slot is None) else []
        level = min(self._nd_level, len(ladder) - 1) if ladder else 0
        while True:
            if ladder:
                assert cam is not None  # a ladder only for the camera
                self._select_filter(ladder[level][0], st)
            if pm is not None:
                st.power_w = self._read_power(pm, st)
            pem = dict(self.plan.points[acq.index].meta).get("pem_waves")
            if lockin is not None and pem is not None and acq.light:
                st.extra.update(self._read_pem(lockin, float(pem), st))
            elif lockin is not None:
                role = self._roles[id(lockin)]
                st.extra.update(self._retry(role, self._policies[role], "read lock-in",
                                            lambda: self._read_lockin(policy.frames), st))
            brackets: list[FrameData] = []
            if cam is None:
                break
            role = self._roles[id(cam)]
            brackets = self._retry(role, self._policy(role), "acquire",
                                   lambda: self._brackets(cam, policy, acq), st)
            main = _best_bracket(brackets)
            if (main.saturated > 0 and level + 1 < len(ladder)
                    and main.exposure_us <= self._shortest_exposure(cam, policy)):
                # Clipped at the shortest exposure: the next denser filter, and the point
                # is read again (every detector, so that all see the same light).
                level += 1
                continue
            st.frames.extend(brackets)
            st.main = main
            st.exposure_us = main.exposure_us
            break
        if ladder:
            assert cam is not None
            self._nd_level = self._next_level(ladder, level, st.main, cam, policy)
            st.extra["nd_position"] = float(ladder[level][0]) if level else math.nan
        if self._wheel is not None:
            st.extra.update(self._filter_in_beam())
        dark_level = 0.0
        if policy.dark == "per_point" and acq.light and self._source is not None:
            # One dark phase for every detector of the point (light off: the shutter
            # closed or the source off), read as the light was: the power meter's and the
            # lock-in's offsets are subtracted by the reduction like the camera's frames.
            self._set_light(False)
            if pm is not None and policy.reads_dark("power_meter"):
                st.extra["power_dark_w"] = self._read_power(pm, st)
            if lockin is not None and policy.reads_dark("lockin"):
                role = self._roles[id(lockin)]
                st.extra.update(self._retry(role, self._policies[role], "read lock-in dark",
                                            lambda: self._read_lockin_dark(policy.frames),
                                            st))
            for b in brackets:
                assert cam is not None  # brackets come from the camera
                role = self._roles[id(cam)]
                dark = self._retry(role, self._policy(role), "dark",
                                   # the default binds the loop's value; mypy cannot infer it
                                   lambda e=b.exposure_us: self._frame(  # type: ignore[misc]
                                       cam, e, policy.frames, False), st)
                st.frames.append(dark)
                if b is st.main:
                    dark_level = float(dark.data.mean())
            self._set_light(True)
        elif cam is not None and not acq.light:
            self._dark_exposures.update(f.exposure_us for f in st.frames)
        elif (cam is not None and policy.dark == "start" and policy.mode == "auto"
              and self._source is not None):
            dark_level = self._dark_for_new_exposure(cam, policy, st)
        if st.main is not None:
            st.signal = (float(st.main.data.mean()) - dark_level) / st.main.exposure_us

    def _dark_for_new_exposure(self, cam: Camera, policy: AcquisitionPolicy,
                               st: _PointState) -> float:
        """Auto-exposure with one dark frame at the start: a lit exposure the run has no dark
        frame at gets one now (light off, the frame, light on), stored with this point, so
        that every lit frame's dark is at its own exposure (the reduction subtracts it).
        Returns the mean of the dark taken at the main exposure (0 when none was needed)."""
        level = 0.0
        for b in [f for f in st.frames if f.light]:
            if b.exposure_us in self._dark_exposures:
                continue
            self._set_light(False)
            role = self._roles[id(cam)]
            dark = self._retry(role, self._policy(role), "dark",
                               # the default binds the loop's value; mypy cannot infer it
                               lambda e=b.exposure_us: self._frame(  # type: ignore[misc]
                                   cam, e, policy.frames, False), st)
            self._set_light(True)
            st.frames.append(dark)
            self._dark_exposures.add(b.exposure_us)
            if b is st.main:
                level = float(dark.data.mean())
        return level

    def _read_power(self, pm: PowerMeter, st: _PointState) -> float:
        role = self._roles[id(pm)]
        return float(self._retry(role, self._policies[role], "read power", pm.read_power_w,
                                 st))

    #: Overloads tolerated while reading one point before the point fails (each one makes
    #: the lock-in choose its range again and settle).
    LOCKIN_OVERLOAD_RETRIES = 3

    def _read_lockin(self, n: int) -> dict[str, float]:
        """The lock-in at this point: settle the output filter (the 99 % wait of its slope),
        choose the range, then ``n`` (at least 4) snapshots one settle time apart; their
        mean R and its standard error, with the range and time constant they were read
        at. An overload during the readings re-ranges and starts again; one that persists
        raises :class:`~drivers.errors.ControllerError`, which the device's retry policy
        handles like any failed reading (retry, then pause, skip or abort)."""
        li = self._lockin
        assert li is not None
        readings = self._lockin_snapshots(n)
        r = np.array([x.r_v for x in readings])
        return {"lockin_r_v": float(r.mean()),
                "lockin_u_r_v": float(r.std(ddof=1) / math.sqrt(r.size)),
                "lockin_x_v": float(np.mean([x.x_v for x in readings])),
                "lockin_y_v": float(np.mean([x.y_v for x in readings])),
                "lockin_theta_deg": float(np.mean([x.theta_deg for x in readings])),
                "lockin_sensitivity_v": float(li.sensitivity_v),
                "lockin_time_constant_s": float(li.time_constant_s),
                "lockin_overload": 0.0}

    def _read_pem(self, lockin: LockIn, waves: float, st: _PointState) -> dict[str, float]:
        """A PEM setting (:mod:`instrument.run.pem_reading`): the modulator set to ``waves``
        (when it is not already), then the lock-in's DC, 1f and 2f, each through its
        device's retry policy; the modulator's amplitude (rad at its wavelength setting),
        wavelength setting and frequency as read back with them."""
        pol = self.plan.spec.polarimetry or {}
        mod = self._modulator
        if mod is not None and (self._pem_state is None
                                or self._pem_state["waves"] != waves):
            role = self._roles[id(mod)]

            def set_pem() -> dict[str, float]:
                mod.retardation_waves = waves
                return {"waves": waves, "pem_amplitude_rad": float(mod.retardation_rad),
                        "pem_wavelength_nm": float(mod.wavelength_nm),
                        "pem_frequency_hz": float(mod.frequency_hz)}

            self._pem_state = self._retry(role, self._policies[role], "set modulator",
                                          set_pem, st)
        role = self._roles[id(lockin)]
        out = self._retry(role, self._policies[role], "read PEM", lambda: read_pem(
            cast(HarmonicLockIn, lockin),
            time_constants=float(pol.get("time_constants", DEFAULT_TIME_CONSTANTS)),
            reads=int(pol.get("reads", DEFAULT_READS)),
            snapshots=lambda: self._lockin_snapshots(int(pol.get("reads", DEFAULT_READS)))),
            st)
        out["lockin_time_constant_s"] = float(lockin.time_constant_s)
        if self._pem_state is not None:
            out.update({k: v for k, v in self._pem_state.items() if k != "waves"})
        return dict(out)

    def _lockin_snapshots(self, n: int) -> list[Any]:
        """``max(n, 4)`` settled snapshots of the lock-in on a range that does not overload
        (:meth:`_read_lockin`)."""
        li = self._lockin
        assert li is not None
        n = max(int(n), 4)
        for _ in range(self.LOCKIN_OVERLOAD_RETRIES + 1):
            li.settle()
            li.auto_range()
            li.overload_status()  # clear the latched flags of the ranging
            readings = []
            for k in range(n):
                if k:
                    li.settle()
                readings.append(li.snapshot())
            if not li.overload_status().overloaded:
                return readings
        raise ControllerError("the input stays overloaded at every range (too much "
                              "light, or the dynamic reserve is too low)",
                              device=self._roles[id(li)], command="read lock-in")

    def _read_lockin_dark(self, n: int) -> dict[str, float]:
        """The lock-in with the light off, read as :meth:`_read_lockin` reads the light:
        the mean X and Y (a coherent offset, e.g. pickup at the chopper frequency, is a
        vector; the reduction subtracts it from the light's X, Y) and the standard error
        of one component from the spread of the snapshots."""
        readings = self._lockin_snapshots(n)
        xy = np.array([[x.x_v for x in readings], [x.y_v for x in readings]])
        return {"lockin_dark_x_v": float(xy[0].mean()), "lockin_dark_y_v": float(xy[1].mean()),
                "lockin_dark_u_v": float(np.sqrt(np.mean(xy.var(axis=1, ddof=1))
                                                 / xy.shape[1]))}

    def _attenuation_ladder(self, st: _PointState) -> list[tuple[int, float]]:
        """(slot, nominal transmission) of the open slot, then of the wheel's
        neutral-density filters from the lightest to the densest; empty without any."""
        if self._nd_ladder is None:
            wheel = self._wheel
            nd = sorted((f.od, s) for s, f in (wheel.filters.items() if wheel else ())
                        if f.is_neutral_density)
            if not nd:
                self._nd_ladder = []
                return []
            assert wheel is not None  # it has the filters
            role = self._roles[id(wheel)]
            count = int(self._retry(role, self._policies[role], "read slot count",
                                    lambda: wheel.position_count, st))
            open_slot = next((k for k in range(1, count + 1) if wheel.filter_at(k).is_empty),
                             None)
            if open_slot is None:
                raise _PointFailed("abort", role, "the filter wheel has neutral-density "
                                   "filters but no open slot: leave one slot empty in the "
                                   "profile's options.filters")
            self._nd_ladder = [(open_slot, 1.0)] + [(s, 10.0 ** -od) for od, s in nd]
        return self._nd_ladder

    @staticmethod
    def _shortest_exposure(cam: Camera, policy: AcquisitionPolicy) -> float:
        return max(cam.exposure_range_us[0], policy.min_exposure_us)

    def _next_level(self, ladder: list[tuple[int, float]], level: int,
                    main: FrameData | None, cam: Camera, policy: AcquisitionPolicy) -> int:
        """The filter the next point starts with: the lightest one through which this
        point's brightest pixel would not have clipped at the shortest exposure (nominal
        transmissions, 20 % margin). Neighbouring points of a scan see similar light, so
        the wheel turns back only when the peak has been left behind."""
        if main is None or not level:
            return 0
        emin = self._shortest_exposure(cam, policy)
        full = float(2 ** _bit_depth(cam) - 1)
        # DN per µs of the open beam (the dark level is small beside a clipping peak)
        rate_open = float(np.max(main.data)) / main.exposure_us / ladder[level][1]
        for k in range(level + 1):
            if rate_open * ladder[k][1] * emin < 0.8 * full:
                return k
        return level

    def _select_filter(self, slot: int, st: _PointState) -> None:
        """Put ``slot`` in the beam (a wavelength axis): the wheel moves only when the slot
        changes; then the camera's buffered frames are of the other band (dropped) and the
        power meter's responsivity correction follows the filter's centre wavelength."""
        if slot == self._wheel_slot:
            return
        wheel = self._wheel
        assert wheel is not None  # a plan with filters needs the wheel
        role = self._roles[id(wheel)]
        if self._wheel_slot is None:  # first filter of the run: the wheel may be there
            self._wheel_slot = int(self._retry(role, self._policies[role], "read position",
                                               lambda: wheel.position, st))
        if slot != self._wheel_slot:
            self._retry(role, self._policies[role], f"move to filter {slot}",
                        lambda: wheel.move_to(slot), st)
        self._wheel_slot = slot
        self._wheel_at(slot)
        if self._camera is not None:
            self._camera.invalidate()
        centre = getattr(wheel.filter_at(slot), "center_nm", None)
        if self._pm is not None and centre is not None:
            pm = self._pm
            pm_role = self._roles[id(pm)]
            self._retry(pm_role, self._policies[pm_role], "set wavelength",
                        lambda: setattr(pm, "wavelength_nm", float(centre)), st)

    def _filter_in_beam(self) -> dict[str, float]:
        """The filter-wheel slot in the beam and its band (NaN for an empty slot)."""
        wheel = self._wheel
        assert wheel is not None
        role = self._roles[id(wheel)]
        slot = int(self._retry(role, self._policies[role], "read position",
                               lambda: wheel.position))
        self._wheel_at(slot)
        spec = wheel.filter_at(slot) if hasattr(wheel, "filter_at") else None
        centre = getattr(spec, "center_nm", None)
        width = getattr(spec, "bandwidth_nm", None)
        return {"filter_position": float(slot),
                "wavelength_nm": math.nan if centre is None else float(centre),
                "bandwidth_nm": math.nan if width is None else float(width)}

    def _frame(self, cam: Camera, exposure_us: float, n: int, light: bool) -> FrameData:
        if cam.exposure_us != exposure_us:
            cam.exposure_us = exposure_us
        frames: list[Frame] = cam.acquire(n)
        if n == 1:
            data = frames[0].data
        else:
            data = np.mean([f.data for f in frames], axis=0, dtype=np.float64).astype(np.float32)
        sat = frames[0].saturation_dn
        saturated = float(np.mean(np.max([f.data for f in frames], axis=0) >= sat))
        # The exposure the camera took, where it reports one: a GenICam camera rounds a
        # request to its own step (1 µs, a line time), and the signal is divided by it.
        taken = frames[0].exposure_us
        exposure = float(taken) if math.isfinite(taken) else float(exposure_us)
        return FrameData(cast("NDArray[Any]", data), exposure, light, frames[-1].timestamp,
                         saturated)

    def _brackets(self, cam: Camera, policy: AcquisitionPolicy, acq: Acquire
                  ) -> list[FrameData]:
        """Fixed exposure, or auto-exposure with HDR bracketing (see AcquisitionPolicy)."""
        lo, hi = cam.exposure_range_us
        emin, emax = max(lo, policy.min_exposure_us), min(hi, policy.max_exposure_us)
        if acq.exposure_us is not None or policy.mode == "fixed" or not acq.light:
            # A dark frame (light off) is not auto-exposed: its peak is the black level,
            # which would lengthen it to the longest exposure; it takes the plan's.
            e = acq.exposure_us if acq.exposure_us is not None else policy.exposure_us
            return [self._frame(cam, min(max(e, lo), hi), policy.frames, acq.light)]
        e = self._last_exposure or policy.exposure_us
        e = min(max(e, emin), emax)
        kept: list[FrameData] = []
        for _ in range(max(policy.max_brackets, 1) + 4):
            fr = self._frame(cam, e, policy.frames, acq.light)
            peak = float(np.max(fr.data))
            sat_level = float(2 ** _bit_depth(cam) - 1)
            if fr.saturated > 0 and e > emin:
                if policy.hdr and len(kept) < policy.max_brackets - 1:
                    kept.append(fr)
                e = max(emin, e / policy.hdr_factor)
                continue
            if (not kept and peak < policy.target_fraction * sat_level / policy.hdr_factor
                    and e < emax):
                e = min(emax, e * policy.hdr_factor)
                continue
            kept.append(fr)
            break
        else:
            kept.append(fr)
        self._last_exposure = kept[-1].exposure_us if not policy.hdr else kept[0].exposure_us
        return kept


class _DoneSet:
    """Which points are done: a fixed bitmap, so memory stays flat on long runs."""

    def __init__(self, n: int, initial: Iterable[int] = ()) -> None:
        self._bits = np.zeros(max(n, 1), dtype=bool)
        self._count = 0
        for i in initial:
            self.add(i)

    def add(self, i: int) -> None:
        if not self._bits[i]:
            self._bits[i] = True
            self._count += 1

    def grow(self, n: int) -> None:
        """Make room for points up to ``n`` (an adaptive plan's new points, not done)."""
        if n > self._bits.size:
            self._bits = np.concatenate([self._bits, np.zeros(n - self._bits.size, bool)])

    def discard_all(self, indices: Iterable[int]) -> None:
        for i in indices:
            if self._bits[i]:
                self._bits[i] = False
                self._count -= 1

    def __contains__(self, i: object) -> bool:  # Container's signature; i is an index
        return bool(self._bits[cast(int, i)])

    def __len__(self) -> int:
        return self._count

    def snapshot(self) -> _DoneSet:
        copy = _DoneSet(0)
        copy._bits = self._bits.copy()
        copy._count = self._count
        return copy


class _Restart(Exception):
    """Internal: the done set changed (storage recovery); iterate the plan again."""


def _bit_depth(cam: Camera) -> int:
    try:
        return cam.bit_depth
    except DeviceError:
        return 16


def _best_bracket(brackets: list[FrameData]) -> FrameData:
    """The longest unsaturated exposure (the last bracket taken)."""
    unsat = [b for b in brackets if b.saturated == 0]
    return max(unsat, key=lambda b: b.exposure_us) if unsat else brackets[-1]


class _Writer:
    """The writer thread: stores one point while the worker moves to the next."""

    def __init__(self, store: RunStore) -> None:
        self._store = store
        self._q: queue.Queue[Any] = queue.Queue(maxsize=1)
        self._cond = threading.Condition()
        self._busy = 0
        self._error: BaseException | None = None
        self.failed: list[int] = []  # indices of points whose storing failed
        self._thread = threading.Thread(target=self._loop, name="run-writer", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while True:
            job = self._q.get()
            if job is None:
                return
            try:
                if self._error is None:
                    job()
            except BaseException as err:
                with self._cond:
                    self._error = err
            finally:
                with self._cond:
                    self._busy -= 1
                    self._cond.notify_all()

    def submit(self, rec: PointRecord) -> None:
        def job() -> None:
            try:
                self._store.append(rec)
            except BaseException:
                self.failed.append(rec.index)
                raise

        self._put(job)

    def _put(self, job: Callable[[], object]) -> None:
        with self._cond:
            self._busy += 1
        self._q.put(job)

    def call(self, fn: Callable[[], object], *, inline: bool = False) -> None:
        """Run ``fn`` on the writer thread (it owns the store) and wait for it; with
        ``inline``, on the calling thread, which is safe only while the writer is idle."""
        if not inline:
            self._put(fn)
            self.drain()
            return
        with self._cond:
            assert self._busy == 0, "inline store call while the writer is busy"
        if self._error is not None:
            self.drain()
        try:
            fn()
        except BaseException as err:
            with self._cond:
                self._error = err
            raise

    def drain(self, *, stall_s: float = math.inf,
              on_stall: Callable[[], object] | None = None) -> None:
        """Wait until every submitted job is done; re-raise a storage error once.

        An HDF5 write in flight cannot be abandoned, so this waits for it however long it
        takes; ``on_stall()`` is called once (outside the lock) if it takes longer than
        ``stall_s`` seconds.
        """
        deadline = time.monotonic() + stall_s if on_stall is not None else math.inf
        while True:
            with self._cond:
                while self._busy and time.monotonic() < deadline:
                    self._cond.wait(min(deadline - time.monotonic(), 3600.0))
                if not self._busy:
                    err = self._error  # sticky: this store is broken until replaced
                    break
            assert on_stall is not None  # the deadline is finite only with on_stall
            on_stall()
            deadline = math.inf
        if err is not None:
            if isinstance(err, StorageError):
                raise err
            if isinstance(err, OSError):
                raise StorageError(err.errno or 5, str(err)) from err
            raise err

    def stop(self) -> None:
        if self._thread.is_alive():
            self._q.put(None)
            self._thread.join(10.0)

