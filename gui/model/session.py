"""The bench session: one device worker owns the bench, and hands it to the engine for runs.

No driver is ever called on the GUI thread. Outside a run, the session's **device worker**
thread owns every driver: it executes the operator's commands in order (a priority queue
lets *stop* overtake anything waiting), polls each device at its kind's interval (axes at
10 Hz, the slower kinds less often) and reports states and command results to a
:class:`SessionListener` (the Qt bridge turns them into signals). Moves and homes are
started and left running — the worker never waits for motion — so a stop is carried out
within one poll period.

For a run, the worker creates the engine (:func:`instrument.run.runner.start_run` or
``resume_run``: they read identities and positions, driver calls) and stops touching the
drivers: from then until the engine's thread has ended, the **engine's worker** owns them,
manual commands are refused with the reason, and *Stop all* aborts the run (the engine
stops the axes and turns the light off). When the run ends, the device worker takes the
bench back and polls again.

Every manual move goes through :mod:`instrument.bench.manual`, the plan's guard: the
positions are read on the worker at the moment of the command, the pose after the move is
judged, and a refused move is reported with the guard's reasons and moves nothing.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from drivers.base import Camera, Device, LightSource, MotionAxis
from drivers.errors import DeviceError
from gui.model.camera import FramePump, FrameSlot
from gui.model.live import LiveData
from instrument.bench.device_state import DeviceState, axis_status_values, kind_of, read_state
from instrument.bench.devices import Bench, open_bench, open_device
from instrument.bench.manual import MoveRefused, check_light_on, plan_home, plan_manual_move
from instrument.bench.profile import BenchProfile, ProfileError, same_bench
from instrument.plans.build import Plan
from instrument.run.engine import EngineState, RunEngine
from instrument.run.events import Event, EventQueue, RunFinished
from instrument.run.runner import resume_run, start_run
from instrument.run.storage import StorageError

__all__ = [
    "Action",
    "BenchSession",
    "CommandResult",
    "Connect",
    "ConnectionStatus",
    "Disconnect",
    "Home",
    "Jog",
    "MoveTo",
    "Reconnect",
    "ResumeRun",
    "RunHandle",
    "SessionListener",
    "SetLight",
    "SetSetting",
    "StartRun",
    "StartStream",
    "Stop",
    "StopAll",
    "StopStream",
]


# --------------------------------------------------------------------------- commands
@dataclass(frozen=True)
class Connect:
    profile: BenchProfile


@dataclass(frozen=True)
class Disconnect:
    """Close every device (the bench made safe first)."""


@dataclass(frozen=True)
class Reconnect:
    """Close and open one device again (a cable plugged back in)."""

    role: str


@dataclass(frozen=True)
class Home:
    role: str


@dataclass(frozen=True)
class MoveTo:
    role: str
    target: float


@dataclass(frozen=True)
class Jog:
    role: str
    delta: float


@dataclass(frozen=True)
class Stop:
    role: str


@dataclass(frozen=True)
class StopAll:
    """Stop every axis now (Esc, the Stop all button)."""


@dataclass(frozen=True)
class SetLight:
    """Turn a light source on or off; ``role`` names one (a shutter is one), else the
    bench's first. On is refused while the detector stands in the beam."""

    on: bool
    role: str | None = None


@dataclass(frozen=True)
class SetSetting:
    """Set a public property the device's kind allows (validated by the driver)."""

    role: str
    name: str
    value: Any


@dataclass(frozen=True)
class Action:
    """Call one of the kind's named actions (a power meter's dark zero; a filter wheel's
    ``move_to`` with the slot in ``args``)."""

    role: str
    name: str
    args: tuple[Any, ...] = ()


@dataclass(frozen=True)
class StartStream:
    """Start the camera's live stream (frames to the camera view)."""


@dataclass(frozen=True)
class StopStream:
    """Stop the camera's live stream."""


@dataclass(frozen=True)
class StartRun:
    plan: Plan
    runs_dir: Path


@dataclass(frozen=True)
class ResumeRun:
    path: Path


@dataclass(frozen=True)
class _RunEnded:
    handle: RunHandle


@dataclass(frozen=True)
class _Shutdown:
    """Ends the device worker's loop (the session closing)."""


Command = (Connect | Disconnect | Reconnect | Home | MoveTo | Jog | Stop | StopAll | SetLight
           | SetSetting | Action | StartStream | StopStream | StartRun | ResumeRun)


@dataclass(frozen=True)
class CommandResult:
    """How a command ended. ``refused``: the guard or the session's state said no and
    nothing was done; ``message`` says why (or what was done)."""

    command: Any
    ok: bool
    message: str = ""
    refused: bool = False
    violations: tuple = ()


@dataclass(frozen=True)
class ConnectionStatus:
    state: str  # "disconnected" | "connecting" | "connected" | "failed"
    profile: BenchProfile | None = None
    message: str = ""
    roles: tuple[str, ...] = ()


@dataclass
class RunHandle:
    """A run in progress: its engine, live values and the GUI's event queue."""

    engine: RunEngine
    live: LiveData
    events: EventQueue
    plan: Plan
    path: Path
    resumed: bool = False
    finished: RunFinished | None = None


class SessionListener(Protocol):
    """Receives the session's reports, on the device worker's (or the engine's) thread."""

    def states(self, states: dict[str, DeviceState]) -> None: ...

    def result(self, result: CommandResult) -> None: ...

    def connection(self, status: ConnectionStatus) -> None: ...

    def run_changed(self, run: RunHandle | None) -> None: ...


class NullListener:
    """A listener that ignores every report (a session driven without a GUI, in tests and
    scripts); the Qt bridge is the listener that forwards them as signals."""

    def states(self, states: dict[str, DeviceState]) -> None:
        """Ignored."""

    def result(self, result: CommandResult) -> None:
        """Ignored."""

    def connection(self, status: ConnectionStatus) -> None:
        """Ignored."""

    def run_changed(self, run: RunHandle | None) -> None:
        """Ignored."""


#: Bound on the GUI's engine-event queue: live values beyond it are dropped (the live
#: plots read :class:`LiveData`, which misses nothing), lifecycle events never.
EVENT_QUEUE_MAX = 2000


@dataclass
class _Move:
    target: float
    started: float = field(default_factory=time.monotonic)


class BenchSession:
    """Owns the bench for the GUI (see the module docstring).

    Parameters
    ----------
    listener
        Gets states, results, connection changes and runs (on worker threads).
    opener
        Opens a profile's devices (default :func:`instrument.bench.devices.open_bench`;
        tests pass an in-process bench).
    poll_s
        Fastest poll period, seconds (the axes'); ≥ 0.1 keeps polling at ≤ 10 Hz.
    fsync
        Passed to the run storage (see ``scatterlab run --no-fsync``).
    """

    def __init__(self, listener: SessionListener | None = None, *,
                 opener: Callable[[BenchProfile], Bench] = open_bench,
                 poll_s: float = 0.1, fsync: bool = True) -> None:
        if poll_s < 0.1:
            raise ValueError("poll_s must be >= 0.1 s (position polling at most 10 Hz)")
        self.listener: SessionListener = listener or NullListener()
        self._opener = opener
        self.poll_s = float(poll_s)
        self.fsync = fsync
        self.frame_slot = FrameSlot()
        self._q: queue.PriorityQueue = queue.PriorityQueue()
        self._seq = itertools.count()
        self._bench: Bench | None = None
        self._profile: BenchProfile | None = None
        self._states: dict[str, DeviceState] = {}
        self._last_poll: dict[str, float] = {}
        self._info_dirty: set[str] = set()
        self._moves: dict[str, _Move] = {}
        self._pump: FramePump | None = None
        self._run: RunHandle | None = None
        self._lock = threading.Lock()
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="device-worker", daemon=True)
        self._thread.start()

    # any thread ---------------------------------------------------------------------
    def submit(self, command: Command) -> None:
        """Queue ``command`` for the device worker (stops overtake everything waiting)."""
        if self._stopped.is_set():
            self.listener.result(CommandResult(command, False, "the session is closed",
                                               refused=True))
            return
        prio = 0 if isinstance(command, StopAll | Stop) else 1
        self._q.put((prio, next(self._seq), command))

    def stop_all(self) -> None:
        """Stop every axis now (during a run: abort it; the engine makes the bench safe)."""
        run = self.run
        if run is not None:
            run.engine.abort()
        self.submit(StopAll())

    @property
    def run(self) -> RunHandle | None:
        with self._lock:
            return self._run

    @property
    def profile(self) -> BenchProfile | None:
        with self._lock:
            return self._profile

    @property
    def connected(self) -> bool:
        with self._lock:
            return self._bench is not None

    def states(self) -> dict[str, DeviceState]:
        with self._lock:
            return dict(self._states)

    # run control from the GUI: the engine's own thread-safe requests, never a driver call
    def pause_run(self) -> bool:
        run = self.run
        if run is None or run.engine.state is not EngineState.RUNNING:
            return False
        run.engine.pause()
        return True

    def resume_run(self, *, skip_point: bool = False) -> bool:
        run = self.run
        if run is None or run.engine.state is not EngineState.PAUSED:
            return False
        run.engine.resume(skip_point=skip_point)
        return True

    def abort_run(self) -> bool:
        run = self.run
        if run is None:
            return False
        run.engine.abort()
        return True

    def close(self, timeout: float = 30.0) -> bool:
        """Abort a run (the engine makes the bench safe and finalises the file), close the
        bench and end the worker. Returns whether everything ended within ``timeout``."""
        deadline = time.monotonic() + timeout
        run = self.run
        if run is not None:
            run.engine.abort()
            run.engine.wait(max(0.1, deadline - time.monotonic()))
        if not self._stopped.is_set():
            self._q.put((2, next(self._seq), _Shutdown()))
        self._thread.join(max(0.1, deadline - time.monotonic()))
        return not self._thread.is_alive()

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Block until every command queued so far has been executed (tests, scripts)."""
        done = threading.Event()
        self._q.put((1, next(self._seq), _Marker(done)))
        return done.wait(timeout)

    # worker thread ------------------------------------------------------------------
    def _loop(self) -> None:
        try:
            while True:
                try:
                    _, _, cmd = self._q.get(timeout=self._poll_wait())
                except queue.Empty:
                    self._poll()
                    continue
                if isinstance(cmd, _Shutdown):
                    return
                if isinstance(cmd, _Marker):
                    cmd.event.set()
                    continue
                self._execute(cmd)
                if self._due():
                    self._poll()
        finally:
            self._stopped.set()
            self._teardown()

    def _poll_wait(self) -> float:
        if self._bench is None:
            return 0.5
        if self._run is not None:
            return self.poll_s  # the engine's read-backs, no driver call
        return max(0.0, min(self._next_poll_times(), default=0.5))

    def _next_poll_times(self) -> list[float]:
        now = time.monotonic()
        out = []
        for role, device in self._bench.devices.items():
            kind = kind_of(device)
            period = max(self.poll_s, kind.poll_s if kind else 1.0)
            out.append(self._last_poll.get(role, -math.inf) + period - now)
        return out

    def _due(self) -> bool:
        return (self._bench is not None and self._run is None
                and min(self._next_poll_times(), default=1.0) <= 0)

    def _poll(self, *, force: bool = False) -> None:
        bench = self._bench
        if bench is None:
            return
        if self._run is not None:
            self._poll_run(self._run)
            return
        now = time.monotonic()
        changed = False
        for role, device in bench.devices.items():
            kind = kind_of(device)
            period = max(self.poll_s, kind.poll_s if kind else 1.0)
            if not force and now - self._last_poll.get(role, -math.inf) < period:
                continue
            self._last_poll[role] = now
            self._read(role, device)
            changed = True
        if changed:
            self._check_arrivals()
            self.listener.states(self.states())

    def _poll_run(self, run: RunHandle) -> None:
        """While the engine owns the bench: the axes' states from the engine's own status
        reads and the filter wheel's slot as the engine read or set it (the drivers are not
        touched), stamped with the time of each read; the other devices keep their last
        state, whose stamp tells its age."""
        changed = False
        for role, (status, t) in run.engine.axis_readbacks().items():
            old = self._states.get(role)
            if old is None or old.t >= t:
                continue
            values = {**old.values, **axis_status_values(status)}
            state = DeviceState(role, old.kind, True, values, old.info, status.error or None,
                                t=t)
            with self._lock:
                self._states[role] = state
            changed = True
        # the filter wheel as the engine last read or set it (an ND filter in the beam)
        wheel = getattr(run.engine, "wheel_readback", lambda: None)()
        if wheel is not None:
            role, slot, t = wheel
            old = self._states.get(role)
            if old is not None and old.t < t:
                state = DeviceState(role, old.kind, True, {**old.values, "position": slot},
                                    old.info, None, t=t)
                with self._lock:
                    self._states[role] = state
                changed = True
        if changed:
            self.listener.states(self.states())

    def _read(self, role: str, device: Device) -> DeviceState:
        old = self._states.get(role)
        with_info = old is None or role in self._info_dirty or not old.info
        state = read_state(role, device, with_info=with_info,
                           info=None if old is None else old.info)
        if with_info and state.error is None:
            self._info_dirty.discard(role)
        with self._lock:
            self._states[role] = state
        return state

    def _check_arrivals(self) -> None:
        """A move that ended outside the axis's tolerance is reported (the driver's
        ``wait`` would have raised MotionError; the worker does not wait)."""
        for role, move in list(self._moves.items()):
            state = self._states.get(role)
            if state is None or state.value("moving", True) or state.error:
                continue
            del self._moves[role]
            pos = state.value("position")
            tol = state.info.get("tolerance", 0.01)
            if pos is not None and abs(pos - move.target) > tol:
                self.listener.result(CommandResult(
                    MoveTo(role, move.target), False,
                    f"{role}: stopped at {pos:.6g}, {pos - move.target:+.3g} from the "
                    f"target {move.target:.6g}"))

    def _execute(self, cmd: Any) -> None:
        try:
            result = self._dispatch(cmd)
        except MoveRefused as err:
            result = CommandResult(cmd, False, str(err), refused=True,
                                   violations=tuple(err.violations))
        except (DeviceError, ValueError, TypeError, OSError) as err:
            result = CommandResult(cmd, False, str(err))
        if result is not None:
            self.listener.result(result)

    def _dispatch(self, cmd: Any) -> CommandResult | None:
        match cmd:
            case Connect():
                return self._connect(cmd)
            case Disconnect():
                return self._disconnect(cmd)
            case _RunEnded():
                self._hand_back(cmd.handle)
                return None
        if self._bench is None:
            return CommandResult(cmd, False, "no bench is connected: connect one first",
                                 refused=True)
        if self._run is not None:
            if isinstance(cmd, StopAll):
                self._run.engine.abort()
                return CommandResult(cmd, True, "run aborted: the engine stops every axis "
                                     "and turns the light off")
            return CommandResult(cmd, False, "a run owns the bench: pause does not hand it "
                                 "back; abort the run or let it finish", refused=True)
        match cmd:
            case StopAll():
                return self._stop_all(cmd)
            case Stop(role=role):
                self._axis(role).stop()
                self._moves.pop(role, None)
                return CommandResult(cmd, True, f"{role} stopped")
            case Home(role=role):
                return self._home(cmd, role)
            case MoveTo(role=role, target=target):
                return self._move(cmd, role, float(target))
            case Jog(role=role, delta=delta):
                return self._move(cmd, role, self._jog_base(self._axis(role)) + float(delta))
            case SetLight(on=on, role=role):
                return self._set_light(cmd, bool(on), role)
            case SetSetting(role=role, name=name, value=value):
                return self._set_setting(cmd, role, name, value)
            case Action(role=role, name=name, args=args):
                device = self._device(role)
                kind = kind_of(device)
                if kind is None or name not in kind.actions:
                    raise ValueError(f"{role}: no action {name!r}")
                if name in kind.slow_actions and self._axes_moving():
                    return CommandResult(cmd, False, f"{role}: {name} waits until every "
                                         "axis is at rest (it holds the bench for seconds)",
                                         refused=True)
                kind.actions[name](device, *args)
                self._info_dirty.add(role)
                self._report_state_now(role, device)
                return CommandResult(cmd, True, f"{role}: {name} done")
            case StartStream():
                return self._start_stream(cmd)
            case StopStream():
                self._stop_stream()
                return CommandResult(cmd, True, "camera stream stopped")
            case Reconnect(role=role):
                return self._reconnect(cmd, role)
            case StartRun():
                return self._start_run(cmd, resume=None)
            case ResumeRun(path=path):
                return self._start_run(cmd, resume=Path(path))
        raise TypeError(f"unknown command {cmd!r}")

    # device helpers -----------------------------------------------------------------
    def _device(self, role: str) -> Device:
        assert self._bench is not None
        try:
            return self._bench.devices[role]
        except KeyError:
            raise ValueError(f"bench {self._bench.profile.name!r} has no device "
                             f"{role!r}") from None

    def _axis(self, role: str) -> MotionAxis:
        dev = self._device(role)
        if not isinstance(dev, MotionAxis):
            raise ValueError(f"{role} is not a motion axis")
        return dev

    def _pose(self) -> dict[str, float]:
        """Positions of the homed axes now (read on this thread, for the guard)."""
        assert self._bench is not None
        return self._bench.homed_pose()

    @staticmethod
    def _jog_base(axis: MotionAxis) -> float:
        """Where a jog starts: the last target while the axis moves to it or has arrived
        within its tolerance, so that steps add exactly (1 + 3 × 1° is 4.000, not the
        read-back's 3.998); the read-back after a stop short of it, or before any move."""
        s = axis.status()
        target = axis.target
        if target is not None and s.is_homed and (
                s.is_moving or abs(s.position - target) <= axis.position_tolerance):
            return float(target)
        return s.position

    def _axes_moving(self) -> list[str]:
        assert self._bench is not None
        return [role for role, axis in self._bench.axes.items() if axis.is_moving]

    def _light_on(self) -> bool:
        src = self._bench.source if self._bench is not None else None
        return bool(src is not None and src.is_on)

    # commands -----------------------------------------------------------------------
    def _connect(self, cmd: Connect) -> CommandResult:
        if self._run is not None:
            return CommandResult(cmd, False, "a run is in progress", refused=True)
        if self._bench is not None:
            self._disconnect(Disconnect())
        self.listener.connection(ConnectionStatus("connecting", cmd.profile,
                                                  f"opening bench {cmd.profile.name!r}"))
        try:
            bench = self._opener(cmd.profile)
        except (DeviceError, ProfileError, OSError, ValueError) as err:
            self.listener.connection(ConnectionStatus("failed", cmd.profile, str(err)))
            return CommandResult(cmd, False, f"bench {cmd.profile.name!r}: {err}")
        with self._lock:
            self._bench = bench
            self._profile = cmd.profile
            self._states = {}
        self._last_poll.clear()
        self._info_dirty = set(bench.devices)
        # connected first, then the first states: a listener builds its panels for the
        # bench's roles before their states arrive
        self.listener.connection(ConnectionStatus(
            "connected", cmd.profile, f"bench {cmd.profile.name!r} connected",
            tuple(bench.devices)))
        self._poll(force=True)
        return CommandResult(cmd, True, f"bench {cmd.profile.name!r} connected: "
                             f"{len(bench.devices)} devices")

    def _disconnect(self, cmd: Disconnect) -> CommandResult:
        if self._run is not None:
            return CommandResult(cmd, False, "a run owns the bench: abort it first",
                                 refused=True)
        self._stop_stream()
        bench = self._bench
        with self._lock:
            self._bench = None
            self._states = {}
        self._moves.clear()
        if bench is not None:
            bench.close()  # stops every axis and turns the light off first
        self.listener.connection(ConnectionStatus(
            "disconnected", self._profile, "bench disconnected: axes stopped, light off"))
        return CommandResult(cmd, True, "bench disconnected")

    def _stop_all(self, cmd: StopAll) -> CommandResult:
        assert self._bench is not None
        problems = []
        for role, axis in self._bench.axes.items():
            try:
                axis.stop()
            except DeviceError as err:
                problems.append(f"{role}: {err}")
        self._moves.clear()
        self._poll(force=True)
        if problems:
            return CommandResult(cmd, False, "stop all: " + "; ".join(problems))
        return CommandResult(cmd, True, "all axes stopped")

    def _home(self, cmd: Home, role: str) -> CommandResult:
        axis = self._axis(role)
        assert self._bench is not None
        plan_home(self._bench.profile, self._pose(), role, light=self._light_on())
        if not axis.is_enabled:
            axis.enable()
        axis.home(wait=False)
        self._moves.pop(role, None)
        self._info_dirty.add(role)
        self._last_poll.pop(role, None)
        return CommandResult(cmd, True, f"{role}: homing")

    def _move(self, cmd: Any, role: str, target: float) -> CommandResult:
        axis = self._axis(role)
        assert self._bench is not None
        move = plan_manual_move(self._bench.profile, self._pose(), {role: target},
                                light=self._light_on())
        axis.move_to(target)  # the driver checks its soft limits and the homed state too
        self._moves[role] = _Move(target)
        self._last_poll.pop(role, None)
        return CommandResult(cmd, True, f"{move.describe()}: moving")

    def _set_light(self, cmd: SetLight, on: bool, role: str | None) -> CommandResult:
        assert self._bench is not None
        src = self._bench.source if role is None else self._device(role)
        if src is None:
            raise ValueError(f"bench {self._bench.profile.name!r} has no light source")
        if not isinstance(src, LightSource):
            raise ValueError(f"{role} is not a light source or shutter")
        name = self._role_of(src)
        if on:
            bad = check_light_on(self._bench.profile, self._pose())
            if bad:
                reasons = "; ".join(v.detail for v in bad)
                return CommandResult(cmd, False, f"{name}: light on refused: {reasons}; "
                                     "move the detector out of the beam first", refused=True,
                                     violations=tuple(bad))
            src.turn_on()
        else:
            src.turn_off()
        self._last_poll.pop(name, None)
        self._poll(force=False)
        return CommandResult(cmd, True, f"{name}: light {'on' if on else 'off'}")

    def _role_of(self, device: Device) -> str:
        assert self._bench is not None
        return next(r for r, d in self._bench.devices.items() if d is device)

    def _set_setting(self, cmd: SetSetting, role: str, name: str, value: Any
                     ) -> CommandResult:
        device = self._device(role)
        kind = kind_of(device)
        if kind is None or name not in kind.settings:
            allowed = ", ".join(kind.settings) if kind else "none"
            raise ValueError(f"{role}: {name!r} is not a setting of this device "
                             f"(settings: {allowed})")
        setattr(device, name, value)  # the driver validates and raises a clear error
        self._info_dirty.add(role)
        self._report_state_now(role, device)
        return CommandResult(cmd, True, f"{role}: {name} = {getattr(device, name)!r}")

    def _report_state_now(self, role: str, device: Device) -> None:
        """Read ``role``'s state (with its settings) and report it before the command's
        result: states and results reach the GUI in the order they are reported, so a
        field that shows the device's setting again when the result arrives already has
        the new value, never the one polled before the command."""
        self._last_poll[role] = time.monotonic()
        self._read(role, device)
        self.listener.states(self.states())

    def _camera(self) -> Camera:
        assert self._bench is not None
        cam = self._bench.camera
        if cam is None:
            raise ValueError(f"bench {self._bench.profile.name!r} has no camera")
        return cam

    def _start_stream(self, cmd: StartStream) -> CommandResult:
        cam = self._camera()
        if self._pump is not None and self._pump.alive:
            return CommandResult(cmd, True, "the camera is streaming")
        cam.start_streaming()
        self.frame_slot.reset_counts()
        self._pump = FramePump(cam, self.frame_slot, on_error=self._stream_failed)
        self._pump.start()
        self._last_poll.pop(self._role_of(cam), None)
        return CommandResult(cmd, True, "camera streaming")

    def _stream_failed(self, err: BaseException) -> None:
        self.listener.result(CommandResult(StartStream(), False, f"camera stream: {err}"))

    def _stop_stream(self) -> None:
        pump, self._pump = self._pump, None
        if pump is not None:
            pump.stop()
        cam = self._bench.camera if self._bench is not None else None
        if cam is not None and cam.is_streaming:
            cam.stop_streaming()

    def _reconnect(self, cmd: Reconnect, role: str) -> CommandResult:
        assert self._bench is not None
        old = self._device(role)
        if isinstance(old, Camera):
            self._stop_stream()
        with contextlib.suppress(Exception):
            old.close()
        spec = self._bench.profile.device(role)
        self._bench.devices[role] = open_device(spec)
        self._info_dirty.add(role)
        self._last_poll.pop(role, None)
        return CommandResult(cmd, True, f"{role} reconnected")

    # runs ---------------------------------------------------------------------------
    def _start_run(self, cmd: Any, *, resume: Path | None) -> CommandResult:
        assert self._bench is not None
        bench = self._bench
        if resume is not None:
            from instrument.run.runfile import read_run

            stored = read_run(resume)
            if stored.status == "finished":
                return CommandResult(cmd, False, f"run {stored.run_id} is finished: every "
                                     "point is measured, nothing to resume", refused=True)
            stored_bench = stored.profile().get("bench", {}).get("name")
            if stored_bench and not same_bench(stored_bench, bench.profile.name):
                return CommandResult(cmd, False, f"run {stored.run_id} was recorded on "
                                     f"bench {stored_bench!r}, the connected bench is "
                                     f"{bench.profile.name!r}: connect that bench first",
                                     refused=True)
        self._stop_stream()
        self._moves.clear()
        try:
            if resume is None:
                engine = start_run(cmd.plan, bench, runs_dir=cmd.runs_dir, fsync=self.fsync)
                plan, path = cmd.plan, engine.store.path
            else:
                engine = resume_run(resume, bench, fsync=self.fsync)
                plan, path = engine.plan, Path(engine.store.path)
        except (StorageError, FileExistsError) as err:
            return CommandResult(cmd, False, f"the run file could not be made: {err}")
        live = LiveData(plan.kind, len(plan.points), n_done=engine.n_done,
                        planned_angles=np.array([p.angles.as_tuple() if p.angles else
                                                 (np.nan,) * 4 for p in plan.points]))
        if resume is not None:
            live.prefill(stored)  # the points measured before: the plot starts with them
        events = EventQueue(maxsize=EVENT_QUEUE_MAX)
        handle = RunHandle(engine, live, events, plan, Path(path), resumed=resume is not None)
        cam = bench.camera
        bits = 16
        if cam is not None:
            with contextlib.suppress(DeviceError):
                bits = cam.bit_depth
        saturation = float(2 ** bits - 1)

        def on_frame(index: int, frame) -> None:
            live.on_frame(index, frame)
            self.frame_slot.put_array(frame.data, exposure_us=frame.exposure_us,
                                      saturation_dn=saturation, index=index,
                                      timestamp=frame.timestamp, compute=False)

        def on_event(ev: Event) -> None:
            live.on_event(ev)
            if isinstance(ev, RunFinished):
                handle.finished = ev
                self._q.put((1, next(self._seq), _RunEnded(handle)))

        engine.subscribe(on_event)
        engine.subscribe(events)
        engine.subscribe_frames(on_frame)
        with self._lock:
            self._run = handle
        self.listener.run_changed(handle)
        engine.start()
        what = "resumed" if resume is not None else "started"
        return CommandResult(cmd, True, f"run {engine.store.header.run_id} {what}: "
                             f"{len(plan.points) - engine.n_done} points to go, file {path}")

    def _hand_back(self, handle: RunHandle) -> None:
        """The engine has ended (RunFinished): wait for its thread, take the bench back."""
        handle.engine.wait(30.0)
        with self._lock:
            if self._run is handle:
                self._run = None
        self._last_poll.clear()
        self._info_dirty = set(self._bench.devices) if self._bench is not None else set()
        self.listener.run_changed(None)
        self._poll(force=True)

    def _teardown(self) -> None:
        with contextlib.suppress(Exception):
            self._stop_stream()
        bench, self._bench = self._bench, None
        if bench is not None:
            bench.close()


@dataclass(frozen=True)
class _Marker:
    event: threading.Event

