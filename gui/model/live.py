"""A run's live values for the plots, without Qt: filled as points arrive, read on a timer.

:class:`LiveData` subscribes to the engine on its worker thread and appends every
completed point into arrays allocated once for the plan's points, so no event is lost
when the GUI is busy and nothing grows beyond the plan. The GUI's redraw timer asks for a
:class:`LiveSnapshot` (copies of the filled part) 10–30 times a second; a plot draws what
the snapshot holds. Which picture suits a plan kind is :func:`plot_kind`.

A frame subscription keeps the newest frame (sphere captures: the latest image) and, for
light-field scans, each point's frame averaged over its sensor rows: one row
L(y = camera_z, θ) of the light field, so the L(y, θ) image grows row by row.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from typing import Any

import numpy as np

from instrument.run.events import Event, PointCompleted, Progress, RunFinished, RunStarted

__all__ = ["LiveData", "LiveSnapshot", "ProgressClock", "decade_label", "log_ticks",
           "plot_kind", "signed_theta_r"]

#: Plan kind → the live picture of it.
PLOTS = {
    "brdf_in_plane": "in_plane", "reference": "in_plane", "signature": "in_plane",
    "brdf_hemisphere": "hemisphere", "lightfield": "lightfield",
    "sphere_capture": "image",
}
#: Light-field rows kept at most (columns × rows floats; wider rows are binned).
MAX_FIELD_VALUES = 16_000_000


def plot_kind(plan_kind: str) -> str:
    """``in_plane`` (signal against θr per θi), ``hemisphere`` (polar map), ``lightfield``
    (L(y, θ) image), ``image`` (latest frame) or ``series`` (signal per point: the
    calibrations)."""
    return PLOTS.get(plan_kind, "series")


def signed_theta_r(theta_r: np.ndarray, phi_i: np.ndarray, phi_r: np.ndarray) -> np.ndarray:
    """θr signed as in plan files: > 0 on the specular side (φr = φi + 180°), < 0 on the
    source side (φr = φi)."""
    d = np.mod(phi_r - phi_i, 360.0)
    specular = np.abs(d - 180.0) < 90.0
    return np.where(specular, theta_r, -theta_r)


@dataclass(frozen=True)
class LiveSnapshot:
    """The filled part of the live arrays (copies; the GUI may keep them)."""

    plan_kind: str
    n_total: int
    n_done: int
    n_received: int
    index: np.ndarray
    ok: np.ndarray            # bool per point: stored with status ok
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_r: np.ndarray
    phi_r: np.ndarray
    signal: np.ndarray        # DN/µs
    planned_theta_i: np.ndarray  # the plan's signed θi of each point (φi = 180°: < 0)
    power_w: np.ndarray
    positions: dict[str, float]  # the last read-back positions
    field: np.ndarray | None  # light field rows (n_total, n_theta), NaN where not measured
    field_y: np.ndarray | None  # camera_z of each row (NaN where not measured)
    image: np.ndarray | None  # the newest frame
    elapsed_s: float
    eta_s: float
    version: int              # changes whenever anything new arrived
    #: The neutral-density filter's wheel slot each point was read through (−1: open beam)
    nd_slot: np.ndarray = dataclass_field(default_factory=lambda: np.zeros(0, np.int64))


class LiveData:
    """Live values of one run. ``on_event``/``on_frame`` run on the engine's worker thread;
    :meth:`snapshot` on any thread."""

    def __init__(self, plan_kind: str, n_total: int, *, n_done: int = 0,
                 planned_angles: np.ndarray | None = None) -> None:
        """``planned_angles``: (n_total, 4) θi, φi, θr, φr of the plan's points (NaN where
        a point has none); a curve per incidence angle uses the planned θi."""
        self.plan_kind = plan_kind
        self.n_total = int(n_total)
        n = max(self.n_total, 1)
        self._lock = threading.Lock()
        self._n = 0
        self._n_done = int(n_done)
        self._index = np.zeros(n, np.int64)
        self._ok = np.zeros(n, bool)
        self._angles = np.full((n, 4), np.nan, np.float32)
        self._signal = np.full(n, np.nan, np.float32)
        self._power = np.full(n, np.nan, np.float32)
        self._nd = np.full(n, -1, np.int64)
        self._positions: dict[str, float] = {}
        self._field: np.ndarray | None = None
        self._field_y: np.ndarray | None = None
        self._bin = 1
        self._image: np.ndarray | None = None
        self._elapsed = 0.0
        self._eta = math.nan
        self._version = 0
        signed = np.full(n, np.nan)
        if planned_angles is not None and len(planned_angles):
            pa = np.asarray(planned_angles, float).reshape(-1, 4)[:n]
            signed[:len(pa)] = np.where(np.abs(np.mod(pa[:, 1], 360) - 180) < 90,
                                        -pa[:, 0], pa[:, 0])
        self._planned_ti = signed

    def prefill(self, run: Any) -> int:
        """The points a resumed run already holds (``run``: the
        :class:`instrument.run.runfile.RunData` read from its file), so its plot starts
        with them instead of with the first new point. Returns the points added."""
        n = min(int(run.index.size), self._index.size)
        with self._lock:
            k = self._n
            m = min(n, self._index.size - k)
            if m <= 0:
                return 0
            self._index[k:k + m] = run.index[:m]
            self._ok[k:k + m] = run.point_status[:m] == 0
            self._angles[k:k + m] = np.stack([run.theta_i[:m], run.phi_i[:m],
                                              run.theta_r[:m], run.phi_r[:m]], axis=-1)
            self._signal[k:k + m] = run.signal[:m]
            self._power[k:k + m] = run.power_w[:m]
            nd = getattr(run, "nd_position", None)
            if nd is not None:
                self._nd[k:k + m] = np.asarray(nd)[:m]
            self._n = k + m
            self._version += 1
        return m

    def plan_angles(self, index: int, angles) -> None:
        """The planned θi of point ``index`` from its read-back angles (θi, φi, θr, φr),
        rounded to 0.1° (beyond any stage tolerance): for a client of the bench server,
        which receives the points but not the plan (docs/decisions/0084)."""
        if not 0 <= index < self._planned_ti.size:
            return
        ti, pi = float(angles[0]), float(angles[1])
        signed = -ti if abs(math.fmod(pi, 360.0) % 360.0 - 180.0) < 90.0 else ti
        with self._lock:
            self._planned_ti[index] = round(signed, 1)

    # worker thread -----------------------------------------------------------------
    def on_event(self, ev: Event) -> None:
        if isinstance(ev, PointCompleted):
            with self._lock:
                k = self._n
                if k >= self._index.size:  # never beyond the plan (a resumed point again)
                    return
                self._index[k] = ev.index
                self._ok[k] = ev.status == "ok"
                if ev.angles is not None:
                    self._angles[k] = ev.angles
                self._signal[k] = ev.signal
                self._power[k] = ev.power_w
                self._nd[k] = ev.nd_slot
                self._positions.update(ev.positions)
                if self._field_y is not None and "camera_z" in ev.positions \
                        and 0 <= ev.index < self._field_y.size:
                    self._field_y[ev.index] = ev.positions["camera_z"]
                self._n = k + 1
                self._version += 1
        elif isinstance(ev, Progress):
            with self._lock:
                self._n_done = ev.n_done
                self._elapsed, self._eta = ev.elapsed_s, ev.eta_s
                self._version += 1
        elif isinstance(ev, RunStarted | RunFinished):
            with self._lock:
                self._n_done = ev.n_done
                self._version += 1

    def on_frame(self, index: int, frame) -> None:
        """A point's main frame (:class:`instrument.run.storage.FrameData`)."""
        data = frame.data
        row = None
        if self.plan_kind == "lightfield" and data.ndim == 2 and getattr(frame, "light", True):
            row = data.mean(axis=0, dtype=np.float64)
        with self._lock:
            self._image = data
            if row is not None and 0 <= index < self.n_total:
                if self._field is None:
                    width = row.size
                    self._bin = max(1, math.ceil(width * self.n_total / MAX_FIELD_VALUES))
                    self._field = np.full((self.n_total, math.ceil(width / self._bin)),
                                          np.nan, np.float32)
                    self._field_y = np.full(self.n_total, np.nan, np.float32)
                binned = _bin(row, self._bin, self._field.shape[1])
                self._field[index] = binned / frame.exposure_us if frame.exposure_us \
                    else binned
            self._version += 1

    # any thread --------------------------------------------------------------------
    @property
    def version(self) -> int:
        with self._lock:
            return self._version

    @property
    def n_received(self) -> int:
        with self._lock:
            return self._n

    def snapshot(self) -> LiveSnapshot:
        with self._lock:
            n = self._n
            a = self._angles[:n].astype(np.float64)
            return LiveSnapshot(
                self.plan_kind, self.n_total, self._n_done, n, self._index[:n].copy(),
                self._ok[:n].copy(), a[:, 0], a[:, 1], a[:, 2], a[:, 3],
                self._signal[:n].astype(np.float64),
                self._planned_ti[np.clip(self._index[:n], 0, self._planned_ti.size - 1)],
                self._power[:n].astype(np.float64),
                dict(self._positions),
                None if self._field is None else self._field.copy(),
                None if self._field_y is None else self._field_y.copy(),
                self._image, self._elapsed, self._eta, self._version,
                self._nd[:n].copy())


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def decade_label(log10_value: float) -> str:
    """A log axis's tick label that always carries its decade: ``-3`` → ``10⁻³``,
    ``log10(2e-3)`` → ``2×10⁻³`` (a bare ``2`` on a log axis says nothing of the
    magnitude)."""
    d = math.floor(log10_value + 1e-9)
    m = round(10 ** (log10_value - d))
    if m >= 10:
        d, m = d + 1, 1
    power = f"10{str(d).translate(_SUPERSCRIPT)}"
    return power if m == 1 else f"{m}×{power}"


def log_ticks(lo: float, hi: float) -> list[tuple[float, list[float]]]:
    """Ticks of a log axis showing log10 values ``lo``..``hi``: the decades as major
    ticks, 2…9 × each decade as minor ones (pyqtgraph's ``tickValues`` form)."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [(1.0, []), (None, [])]
    first, last = math.floor(lo), math.ceil(hi)
    if last - first > 60:  # a degenerate range: no minor ticks, every few decades
        step = math.ceil((last - first) / 12)
        return [(float(step), [float(d) for d in range(first, last + 1, step)
                               if lo <= d <= hi]), (None, [])]
    major = [float(d) for d in range(first, last + 1) if lo <= d <= hi]
    minor = [d + math.log10(k) for d in range(first, last + 1) for k in range(2, 10)
             if lo <= d + math.log10(k) <= hi]
    return [(1.0, major), (None, minor)]


class ProgressClock:
    """Elapsed time and time left of a run, without its pauses.

    The engine's :class:`~instrument.run.events.Progress` counts wall time since it
    started, pauses included, so after a ten-minute pause the elapsed time says ten
    minutes more and the time left jumps. This clock measures the pauses between
    ``Paused`` and ``Resumed`` (``now``: a monotonic clock, injectable for tests) and
    subtracts them; the time left is the points still to do times the mean active time
    per point measured in this session (a resumed run's earlier points are not in it).
    """

    def __init__(self, now: Callable[[], float] = time.monotonic) -> None:
        self._now = now
        self.start(0)

    def start(self, n_done: int) -> None:
        self._n0 = int(n_done)
        self._paused_s = 0.0
        self._pause_t: float | None = None

    def paused(self) -> None:
        if self._pause_t is None:
            self._pause_t = self._now()

    def resumed(self) -> None:
        if self._pause_t is not None:
            self._paused_s += self._now() - self._pause_t
            self._pause_t = None

    def paused_s(self) -> float:
        """Time paused so far (a pause in progress included)."""
        now = 0.0 if self._pause_t is None else self._now() - self._pause_t
        return self._paused_s + now

    def times(self, ev: Progress) -> tuple[float, float]:
        """(elapsed, time left) in seconds for a Progress event; NaN time left before
        the first point of this session."""
        elapsed = max(0.0, ev.elapsed_s - self.paused_s())
        done_here = ev.n_done - self._n0
        if done_here <= 0:
            return elapsed, math.nan
        return elapsed, (ev.n_total - ev.n_done) * elapsed / done_here


def _bin(row: np.ndarray, factor: int, width: int) -> np.ndarray:
    if factor == 1:
        return row.astype(np.float32)
    pad = width * factor - row.size
    padded = np.concatenate([row, np.full(pad, np.nan)]) if pad else row
    return np.nanmean(padded.reshape(width, factor), axis=1).astype(np.float32)
