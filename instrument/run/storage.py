"""Run files: one HDF5 file per run (NeXus-style, plain h5py) plus its commit journal.

Layout (``/entry`` is an NXentry; every group carries an ``NX_class`` attribute)::

    /entry                      attrs: run_id, plan_kind, plan_name, status, start_time,
                                end_time, software_version, schema_version, durability
      sample/      NXsample     name, description
      instrument/  NXinstrument bench_profile (TOML text), geometry attrs,
                                <role>/ (NXpositioner | NXdetector | NXsource | NXmonitor)
                                with the device identity and retry policy as attributes
      plan/        NXcollection plan_text, acquisition_policy, retry_policies (JSON),
                                axes, planned_targets (N, A), planned_angles (N, 4),
                                planned_label, planned_light, planned_exposure_us
      calibration/ NXcollection one attribute per calibration reference (run id or path)
      points/      NXcollection per completed point (row = point index order of
                                completion): index, label, status (0 ok, 1 skipped, 2 frames
                                lost to a damaged file), note,
                                t_start, t_end (Unix s), positions (N, A) read back,
                                theta_i, phi_i, theta_r, phi_r (deg, from the read-back
                                positions), exposure_us, power_w, signal, n_frames,
                                frame_start, retries
      data/        NXdata       frames (F, H, W) chunked per frame, compressed when it
                                pays; frame_point, frame_exposure_us, frame_light,
                                frame_timestamp, frame_saturated; signal/axes linked from
                                points/
      events/      NXcollection log: one JSON string per event (faults, pauses, resumes)

Durability (docs/decisions/0010): the journal ``<file>.journal`` is the commit log. A
point is complete when its record is in the journal; its frames are written and flushed
to the HDF5 file *before* that record is appended. Scalar rows are written to the HDF5
file in batches (every ``sync_interval_s`` and whenever frames are flushed), so a kill -9
can leave the HDF5 tables behind the journal, never ahead of it in a way that counts.
:func:`recover` makes the HDF5 file agree with the journal: it truncates anything
uncommitted, rewrites the scalar tables from the journal, and rebuilds the file from the
journal's header if the HDF5 file no longer opens.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import shutil
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from instrument.run.journal import Journal, read_journal

__all__ = ["FrameData", "PointRecord", "RunHeader", "RunStore", "StorageError", "recover"]

SCHEMA_VERSION = 1
FLOAT_FIELDS = ("t_start", "t_end", "theta_i", "phi_i", "theta_r", "phi_r", "exposure_us",
                "power_w", "signal")
INT_FIELDS = ("index", "status", "n_frames", "frame_start", "retries")
STR_FIELDS = ("label", "note")
FRAME_FIELDS = ("frame_point", "frame_exposure_us", "frame_light", "frame_timestamp",
                "frame_saturated")
STATUS_OK, STATUS_SKIPPED = 0, 1
#: A committed point whose frames a damaged file no longer holds (stored as zeros):
#: its scalar values (from the journal) stand, its frames must not be analysed.
FRAMES_LOST = 2
FRAMES_LOST_NOTE = "frames lost: the run file was damaged; scalars recovered from the journal"
#: Disk space reserved per point besides its frames: new chunks of the scalar tables
#: (1024 rows × 8 B × ~20 datasets) and metadata.
RESERVE_BYTES = 512 * 1024
_STR = h5py.string_dtype()


class StorageError(OSError):
    """A run file could not be written (disk full, I/O error) or is not a run file.

    ``clean`` is true when the error was detected before anything was written (free-space
    check, space reservation): the file is then intact and can be closed normally.
    """

    clean = False


def _clean_error(code: int, message: str) -> StorageError:
    err = StorageError(code, message)
    err.clean = True
    return err


@dataclass(frozen=True)
class FrameData:
    data: np.ndarray          # (H, W) DN
    exposure_us: float
    light: bool
    timestamp: float
    saturated: float          # fraction of pixels at or above saturation


@dataclass
class PointRecord:
    index: int
    label: str
    t_start: float
    t_end: float
    positions: tuple[float, ...]
    angles: tuple[float, float, float, float] = (math.nan,) * 4
    exposure_us: float = math.nan
    power_w: float = math.nan
    signal: float = math.nan
    status: int = STATUS_OK
    retries: int = 0
    note: str = ""
    frames: list[FrameData] = field(default_factory=list)


@dataclass(frozen=True)
class RunHeader:
    """Everything written once, at creation; also the journal's first record."""

    run_id: str
    plan_kind: str
    plan_name: str
    plan_text: str
    profile_text: str
    bench_name: str
    sample_name: str
    sample_description: str
    axes: tuple[str, ...]
    planned_targets: list[list[float]]
    planned_angles: list[list[float]]
    planned_label: list[str]
    planned_light: list[bool]
    planned_exposure_us: list[float]
    acquisition_policy: str
    retry_policies: str
    identities: dict[str, dict[str, str]]
    device_kinds: dict[str, str]
    geometry: dict[str, Any]
    calibration: dict[str, str]
    software_version: str
    created: float

    def as_dict(self) -> dict[str, Any]:
        d = dict(vars(self))
        d["axes"] = list(self.axes)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunHeader:
        d = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        d["axes"] = tuple(d["axes"])
        return cls(**d)


def journal_path(path: str | Path) -> Path:
    return Path(str(path) + ".journal")


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(t)) + f"{t % 1:.3f}"[1:]


# --------------------------------------------------------------------------- writer


class RunStore:
    """Writes one run. Not thread-safe: the engine's writer thread owns it."""

    def __init__(self, path: Path, h5: h5py.File, journal: Journal, header: RunHeader, *,
                 n_points: int, n_frames: int, fsync: bool, sync_interval_s: float,
                 min_free_bytes: int) -> None:
        self.path = path
        self.header = header
        self._h5 = h5
        self._journal = journal
        self.n_points = n_points
        self.n_frames = n_frames
        self.fsync = fsync
        self.sync_interval_s = sync_interval_s
        self.min_free_bytes = min_free_bytes
        self._pending: list[tuple[PointRecord, int, int]] = []
        self._pending_events: list[str] = []
        self._last_sync = time.monotonic()
        self._last_free_check = -math.inf
        self._compress: bool | None = None
        self._closed = False

    # creation -----------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, header: RunHeader, *, fsync: bool = True,
               sync_interval_s: float = 0.25, min_free_bytes: int = 64 << 20) -> RunStore:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists() or journal_path(path).exists():
            raise FileExistsError(f"run file {path} already exists")
        _check_free(path.parent, min_free_bytes, 0)
        h5 = _new_file(path, header)
        h5.attrs["durability"] = "fsync" if fsync else "process"
        h5.flush()
        journal = Journal(journal_path(path), fsync=fsync)
        try:
            journal.append({"t": "header", **header.as_dict()})
        except BaseException:
            journal.close()
            h5.close()
            raise
        return cls(path, h5, journal, header, n_points=0, n_frames=0, fsync=fsync,
                   sync_interval_s=sync_interval_s, min_free_bytes=min_free_bytes)

    @classmethod
    def reopen(cls, path: str | Path, *, fsync: bool = True, sync_interval_s: float = 0.25,
               min_free_bytes: int = 64 << 20) -> tuple[RunStore, set[int]]:
        """Recover ``path`` and open it to append; returns the store and the done indices."""
        path = Path(path)
        report = recover(path)
        h5 = h5py.File(path, "r+")
        journal = Journal(journal_path(path), fsync=fsync)
        store = cls(path, h5, journal, report.header, n_points=report.n_points,
                    n_frames=report.n_frames, fsync=fsync, sync_interval_s=sync_interval_s,
                    min_free_bytes=min_free_bytes)
        return store, report.done

    # writing ------------------------------------------------------------------
    def append(self, rec: PointRecord) -> None:
        """Make ``rec`` durable: when this returns, the point survives a kill -9.

        Raises
        ------
        StorageError
            Not enough free space (checked first: nothing is written) or a write failed;
            the point is not committed and :func:`recover` restores a consistent file.
        """
        nbytes = sum(f.data.nbytes for f in rec.frames)
        now = time.monotonic()
        writes_hdf5 = bool(nbytes) or now - self._last_sync >= self.sync_interval_s
        if writes_hdf5 or now - self._last_free_check >= 1.0:
            # Checked before every HDF5 write, and at least once a second otherwise
            # (a journal line is ~300 bytes: a statvfs per line would cost more).
            _check_free(self.path.parent, self.min_free_bytes, 2 * nbytes + 65536)
            self._last_free_check = now
        if writes_hdf5:
            self._reserve(2 * nbytes + RESERVE_BYTES)
        try:
            frame_start = self.n_frames
            if rec.frames:
                self._write_frames(rec.index, rec.frames)
            entry = _point_json(rec, frame_start)
            self._pending.append((rec, frame_start, len(rec.frames)))
            if writes_hdf5:
                self._sync_tables(extra=1)
            self._journal.append(entry)
        except (OSError, RuntimeError) as err:
            # h5py reports failed writes/flushes as OSError or RuntimeError (H5Fflush).
            self._pending.clear()
            if isinstance(err, StorageError):
                raise
            raise StorageError(_errno_of(err),
                               f"writing point {rec.index} to {self.path} failed: "
                               f"{_first_line(err)}") from err
        self.n_points += 1
        self.n_frames = frame_start + len(entry["frames"])

    def event(self, record: dict[str, Any]) -> None:
        """Log an event (fault, pause, resume): journal now, HDF5 at the next sync."""
        rec = {"t": "event", "time": time.time(), **record}
        try:
            self._journal.append(rec)
            self._pending_events.append(json.dumps(rec))
            if rec.get("kind") in ("fault", "paused", "aborted"):
                self._sync_tables()
        except (OSError, RuntimeError) as err:
            if isinstance(err, StorageError):
                raise
            raise StorageError(_errno_of(err), f"logging an event in {self.path} failed: "
                               f"{_first_line(err)}") from err

    def sync(self) -> None:
        """Write buffered rows to the HDF5 file and flush it (pause, finish)."""
        try:
            self._sync_tables()
        except (OSError, RuntimeError) as err:
            if isinstance(err, StorageError):
                raise
            raise StorageError(_errno_of(err), f"syncing {self.path} failed: "
                               f"{_first_line(err)}") from err

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self, status: str) -> None:
        """Finalise: rows written, status and end time set, files closed. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self._sync_tables()
            entry = self._h5["entry"]
            entry.attrs["status"] = status
            entry.attrs["end_time"] = _iso(time.time())
            entry.attrs["n_points"] = self.n_points
            self._h5.flush()
            self._journal.append({"t": "status", "status": status, "time": time.time(),
                                  "n_points": self.n_points})
        finally:
            self._h5.close()
            self._journal.close()

    def abandon(self) -> None:
        """Close the files without touching them further (after a storage error)."""
        if self._closed:
            return
        self._closed = True
        for closer in (self._h5.close, self._journal.close):
            with contextlib.suppress(Exception):
                closer()

    # internals ----------------------------------------------------------------
    def _reserve(self, nbytes: int) -> None:
        """Allocate disk blocks for the next write *before* HDF5 makes it.

        A full disk (or a file-size limit) then fails here, with nothing written, instead
        of in the middle of an HDF5 metadata flush, which would leave a file that HDF5
        refuses to open ("truncated file"). HDF5 trims the file back to its own end of
        allocation when it flushes, so the reservation is renewed per point.
        """
        try:
            size = int(self._h5.id.get_filesize())
            fd = os.open(self.path, os.O_RDWR)
            try:
                os.posix_fallocate(fd, 0, size + nbytes)
            finally:
                os.close(fd)
        except OSError as err:
            raise _clean_error(err.errno or errno.ENOSPC,
                               f"no room for the next point in {self.path}: "
                               f"{err.strerror or err}; free space, then `scatterlab resume`"
                               ) from err

    def _write_frames(self, index: int, frames: list[FrameData]) -> None:
        data = self._h5["entry/data"]
        if "frames" not in data:
            first = frames[0].data
            self._compress = _compression_pays(first)
            kw: dict[str, Any] = {}
            if self._compress:
                kw = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
            data.create_dataset("frames", shape=(0, *first.shape),
                                maxshape=(None, *first.shape), chunks=(1, *first.shape),
                                dtype=first.dtype, **kw)
            data["frames"].attrs["units"] = "DN"
        ds = data["frames"]
        n0 = self.n_frames
        n1 = n0 + len(frames)
        ds.resize(n1, axis=0)
        for k, f in enumerate(frames):
            ds[n0 + k] = f.data
        cols = {
            "frame_point": [index] * len(frames),
            "frame_exposure_us": [f.exposure_us for f in frames],
            "frame_light": [f.light for f in frames],
            "frame_timestamp": [f.timestamp for f in frames],
            "frame_saturated": [f.saturated for f in frames],
        }
        for name, vals in cols.items():
            d = data[name]
            d.resize(n1, axis=0)
            d[n0:n1] = vals
        self._h5.flush()
        if self.fsync:
            _fsync_path(self.path)

    def _sync_tables(self, extra: int = 0) -> None:
        """Write the buffered rows; ``extra`` of them are not yet counted in n_points."""
        if self._pending:
            first = self.n_points + extra - len(self._pending)
            _write_rows(self._h5["entry/points"], first, self._pending,
                        len(self.header.axes))
            self._pending.clear()
        if self._pending_events:
            log = self._h5["entry/events/log"]
            n = log.shape[0]
            log.resize(n + len(self._pending_events), axis=0)
            log[n:] = self._pending_events
            self._pending_events.clear()
        self._h5["entry"].attrs["n_points"] = self.n_points + extra
        self._h5.flush()
        self._last_sync = time.monotonic()


def _errno_of(err: BaseException) -> int:
    """The errno of an OSError, or the one HDF5 quotes in its message ("errno = 28")."""
    if isinstance(err, OSError) and err.errno:
        return err.errno
    m = re.search(r"errno = (\d+)", str(err))
    return int(m.group(1)) if m else errno.EIO


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    m = re.search(r"error message = '([^']*)'", text)
    head = text.splitlines()[0] if text else type(err).__name__
    return f"{head.rstrip(' (')}: {m.group(1)}" if m else head


def _compression_pays(frame: np.ndarray) -> bool:
    """Compress frames when gzip-1 with byte shuffle saves at least 20 % on the first one."""
    raw = np.ascontiguousarray(frame)
    shuffled = raw.view(np.uint8).reshape(-1, raw.itemsize).T.tobytes()
    return len(zlib.compress(shuffled, 1)) < 0.8 * raw.nbytes


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _check_free(folder: Path, min_free: int, needed: int) -> None:
    free = shutil.disk_usage(folder).free
    if free < min_free + needed:
        raise _clean_error(
            errno.ENOSPC,
            f"disk nearly full: {free / 2**20:.1f} MiB free in {folder}, the run keeps "
            f"at least {min_free / 2**20:.1f} MiB free (point needs {needed / 2**20:.2f} MiB)"
            "; free space, then `scatterlab resume`",
        )


def _point_json(rec: PointRecord, frame_start: int) -> dict[str, Any]:
    return {
        "t": "point", "index": rec.index, "label": rec.label, "status": rec.status,
        "note": rec.note, "t_start": rec.t_start, "t_end": rec.t_end,
        "positions": list(rec.positions), "angles": list(rec.angles),
        "exposure_us": rec.exposure_us, "power_w": rec.power_w, "signal": rec.signal,
        "retries": rec.retries, "frame_start": frame_start,
        "frames": [[f.exposure_us, bool(f.light), f.timestamp, f.saturated,
                    zlib.crc32(np.ascontiguousarray(f.data).tobytes())] for f in rec.frames],
    }


def _write_rows(grp: h5py.Group, n0: int, recs: list[tuple[PointRecord, int, int]],
                n_axes: int) -> None:
    n1 = n0 + len(recs)
    cols: dict[str, list[Any]] = {k: [] for k in (*FLOAT_FIELDS, *INT_FIELDS, *STR_FIELDS)}
    # a plan that moves no axis (dark frames) still has a one-column table (see _ext)
    pos = np.full((len(recs), max(n_axes, 1)), np.nan)
    for k, (r, frame_start, n_frames) in enumerate(recs):
        cols["t_start"].append(r.t_start)
        cols["t_end"].append(r.t_end)
        for j, name in enumerate(("theta_i", "phi_i", "theta_r", "phi_r")):
            cols[name].append(r.angles[j])
        cols["exposure_us"].append(r.exposure_us)
        cols["power_w"].append(r.power_w)
        cols["signal"].append(r.signal)
        cols["index"].append(r.index)
        cols["status"].append(r.status)
        cols["n_frames"].append(n_frames)
        cols["frame_start"].append(frame_start)
        cols["retries"].append(r.retries)
        cols["label"].append(r.label)
        cols["note"].append(r.note)
        pos[k, :len(r.positions)] = r.positions
    _put_rows(grp, n0, n1, cols, pos)


def _put_rows(grp: h5py.Group, n0: int, n1: int, cols: dict[str, list[Any]],
              pos: np.ndarray) -> None:
    for name, vals in cols.items():
        d = grp[name]
        if d.shape[0] != n1:
            d.resize(n1, axis=0)
        if n1 > n0:
            d[n0:n1] = vals
    d = grp["positions"]
    if d.shape[0] != n1:
        d.resize(n1, axis=0)
    if n1 > n0:
        d[n0:n1] = pos


# --------------------------------------------------------------------------- layout


def _group(parent: h5py.Group, name: str, nx_class: str) -> h5py.Group:
    g = parent.create_group(name)
    g.attrs["NX_class"] = nx_class
    return g


def _ext(grp: h5py.Group, name: str, dtype: Any, *, width: int | None = None,
         units: str | None = None, chunk: int = 1024) -> h5py.Dataset:
    shape, maxshape, chunks = (0,), (None,), (chunk,)
    if width is not None:
        shape, maxshape, chunks = (0, max(width, 1)), (None, max(width, 1)), (chunk, max(width, 1))
    d = grp.create_dataset(name, shape=shape, maxshape=maxshape, chunks=chunks, dtype=dtype)
    if units:
        d.attrs["units"] = units
    return d


_UNITS = {"t_start": "s", "t_end": "s", "theta_i": "deg", "phi_i": "deg", "theta_r": "deg",
          "phi_r": "deg", "exposure_us": "us", "power_w": "W", "signal": "DN/us"}


def _new_file(path: Path, h: RunHeader) -> h5py.File:
    f = h5py.File(path, "w")
    try:
        f.attrs["default"] = "entry"
        f.attrs["creator"] = "scatterlab"
        entry = _group(f, "entry", "NXentry")
        entry.attrs["default"] = "data"
        for key in ("run_id", "plan_kind", "plan_name", "software_version"):
            entry.attrs[key] = getattr(h, key)
        entry.attrs["schema_version"] = SCHEMA_VERSION
        entry.attrs["status"] = "running"
        entry.attrs["start_time"] = _iso(h.created)
        entry.attrs["n_planned"] = len(h.planned_label)
        entry.attrs["n_points"] = 0
        entry.create_dataset("title", data=h.plan_name)
        sample = _group(entry, "sample", "NXsample")
        sample.create_dataset("name", data=h.sample_name)
        sample.create_dataset("description", data=h.sample_description)
        inst = _group(entry, "instrument", "NXinstrument")
        inst.create_dataset("name", data=h.bench_name)
        inst.create_dataset("bench_profile", data=h.profile_text)
        for k, v in h.geometry.items():
            if isinstance(v, str | int | float | bool):
                inst.attrs[f"geometry.{k}"] = v
        retry = json.loads(h.retry_policies)
        for role, kind in h.device_kinds.items():
            g = _group(inst, role, kind)
            for k, v in h.identities.get(role, {}).items():
                g.attrs[k] = str(v)
            if role in retry:
                g.attrs["retry_policy"] = json.dumps(retry[role])
        plan = _group(entry, "plan", "NXcollection")
        plan.create_dataset("plan_text", data=h.plan_text)
        plan.create_dataset("acquisition_policy", data=h.acquisition_policy)
        plan.create_dataset("retry_policies", data=h.retry_policies)
        plan.create_dataset("axes", data=np.array(list(h.axes), dtype=object), dtype=_STR)
        n = len(h.planned_label)
        targets = np.array(h.planned_targets, dtype=float).reshape(n, len(h.axes))
        plan.create_dataset("planned_targets", data=targets)
        plan.create_dataset("planned_angles",
                            data=np.array(h.planned_angles, dtype=float).reshape(n, 4))
        plan.create_dataset("planned_label", data=np.array(h.planned_label, dtype=object),
                            dtype=_STR)
        plan.create_dataset("planned_light", data=np.array(h.planned_light, dtype=bool))
        plan.create_dataset("planned_exposure_us",
                            data=np.array(h.planned_exposure_us, dtype=float))
        cal = _group(entry, "calibration", "NXcollection")
        for k, v in h.calibration.items():
            cal.attrs[k] = v
        pts = _group(entry, "points", "NXcollection")
        for name in FLOAT_FIELDS:
            _ext(pts, name, "f8", units=_UNITS.get(name))
        for name in INT_FIELDS:
            _ext(pts, name, "i8")
        for name in STR_FIELDS:
            _ext(pts, name, _STR)
        _ext(pts, "positions", "f8", width=len(h.axes))
        pts["positions"].attrs["axes"] = ",".join(h.axes)
        data = _group(entry, "data", "NXdata")
        for name, dt in zip(FRAME_FIELDS, ("i8", "f8", "bool", "f8", "f8"), strict=True):
            _ext(data, name, dt)
        data["signal"] = pts["signal"]
        for name in ("theta_i", "theta_r", "phi_r"):
            data[name] = pts[name]
        data.attrs["signal"] = "signal"
        data.attrs["axes"] = ["theta_r"]
        ev = _group(entry, "events", "NXcollection")
        _ext(ev, "log", _STR, chunk=64)
    except BaseException:
        f.close()
        raise
    return f


# --------------------------------------------------------------------------- recovery


@dataclass(frozen=True)
class RecoveryReport:
    header: RunHeader
    n_points: int
    n_frames: int
    done: set[int]
    status: str
    rebuilt: bool
    dropped_rows: int
    frames_lost: int
    #: Points whose frames this recovery found damaged (now marked FRAMES_LOST).
    points_lost: tuple[int, ...] = ()


def _not_a_run(path: Path) -> StorageError:
    """Why ``path`` (whose journal has no header) cannot be resumed, in words."""
    jp = journal_path(path)
    if not path.exists() and not jp.exists():
        return StorageError(errno.ENOENT, f"{path}: no such run file")
    if path.is_dir():
        return StorageError(errno.EISDIR, f"{path} is a folder; give a run file (.h5)")
    if not jp.exists():
        try:
            with h5py.File(path, "r") as f:
                is_run = "run_id" in f["entry"].attrs
        except (OSError, KeyError):
            is_run = False
        if is_run:
            return StorageError(errno.EINVAL, (
                f"{path} is a scatterlab run file but its journal {jp.name} is missing "
                "(copied without it?): it reads with h5py but cannot be resumed"))
        return StorageError(errno.EINVAL, f"{path} is not a scatterlab run file (no run "
                            f"journal {jp.name} next to it)")
    return StorageError(errno.EINVAL, f"{path}: its journal {jp.name} holds no intact run "
                        "header (not a scatterlab run, or the journal is damaged at its "
                        "start): it cannot be resumed")


def recover(path: str | Path) -> RecoveryReport:
    """Make the run file agree with its journal (see the module docstring).

    Safe to call on a healthy file (it changes nothing that matters). Raises
    :class:`StorageError` when the journal has no header (not a scatterlab run).
    """
    path = Path(path)
    records, _ = read_journal(journal_path(path))
    if not records or records[0].get("t") != "header":
        raise _not_a_run(path)
    header = RunHeader.from_dict(records[0])
    points: list[dict[str, Any]] = []
    seen: set[int] = set()
    events: list[str] = []
    marked: set[int] = set()
    status = "interrupted"
    for r in records[1:]:
        if r["t"] == "point" and r["index"] not in seen:
            seen.add(r["index"])
            points.append(r)
        elif r["t"] == "frames_lost":
            marked.add(r["index"])
        elif r["t"] == "event":
            events.append(json.dumps(r))
        elif r["t"] == "status":
            status = r["status"]
    if len(points) < len(header.planned_label) and status == "finished":
        status = "interrupted"
    points = [_mark_lost(p) if p["index"] in marked else p for p in points]
    rebuilt = False
    salvaged_lost: list[int] = []
    try:
        f = h5py.File(path, "r+")
    except (OSError, KeyError, RuntimeError) as err:
        text = str(err)
        if "unable to lock" in text.lower() or "already open" in text.lower():
            raise StorageError(errno.EBUSY, f"{path} is open in another program (a run "
                               "still going?); close it first") from err
        f = _open_padded(path, text)
        if f is None:
            f, salvaged_lost = _rebuild(path, header, points, err)
            rebuilt = True
    try:
        try:
            frames_lost, dropped = _reconcile(f, header, points, events, rebuilt)
        except (KeyError, OSError, ValueError, RuntimeError) as err:
            # The file opened but its structure is damaged (e.g. metadata whose flush
            # failed on a full disk): rebuild it from the journal, salvaging frames.
            f.close()
            f, salvaged_lost = _rebuild(path, header, points, err)
            rebuilt = True
            frames_lost, dropped = _reconcile(f, header, points, events, rebuilt)
        frames_lost = sorted({*frames_lost, *salvaged_lost})
        newly = _mark_points_lost(path, f, points, frames_lost, marked)
        gone = marked.union(newly)
        if gone:  # zeros standing in for frames, counted over every recovery so far
            f["entry"].attrs["frames_lost"] = sum(len(p["frames"]) for p in points
                                                  if p["index"] in gone)
        f["entry"].attrs["status"] = status
        f["entry"].attrs["n_points"] = len(points)
        f.flush()
    finally:
        f.close()
    n_frames = sum(len(p["frames"]) for p in points)
    return RecoveryReport(header, len(points), n_frames, seen, status, rebuilt, dropped,
                          len(frames_lost), newly)


def _mark_lost(point: dict[str, Any]) -> dict[str, Any]:
    return {**point, "status": FRAMES_LOST, "note": FRAMES_LOST_NOTE}


def _mark_points_lost(path: Path, f: h5py.File, points: list[dict[str, Any]],
                      lost_frames: list[int], marked: set[int]) -> tuple[int, ...]:
    """Mark the points owning ``lost_frames`` (frame positions) as FRAMES_LOST.

    Their frames are zeros now; the mark goes into the points table (so analysis, which
    keeps status 0 only, leaves them out) and into the journal (so every later recovery,
    which rewrites the table from the journal, keeps it). Returns the newly marked point
    indices.
    """
    owner = [p["index"] for p in points for _ in p["frames"]]
    lost = sorted({owner[k] for k in lost_frames} - marked)
    if not lost:
        return ()
    journal = Journal(journal_path(path), fsync=True)
    try:
        for i in lost:
            journal.append({"t": "frames_lost", "index": i, "time": time.time()})
    finally:
        journal.close()
    rows = f["entry/points"]
    for k, p in enumerate(points):
        if p["index"] in lost:
            rows["status"][k] = FRAMES_LOST
            rows["note"][k] = FRAMES_LOST_NOTE
    return tuple(lost)


def _open_padded(path: Path, message: str) -> h5py.File | None:
    """Reopen a file whose last write failed after HDF5 had recorded its new end.

    HDF5 then refuses the file as "truncated file: eof = A, ..., stored_eof = B". The
    missing bytes belonged to the write that failed (an uncommitted point); padding the
    file with zeros to B makes it open again, and the reconciliation that follows keeps
    only committed rows and checks the newest frames' checksums.
    """
    m = re.search(r"truncated file: eof = (\d+).*stored_eof = (\d+)", message)
    if not m or int(m.group(2)) <= int(m.group(1)):
        return None
    try:
        os.truncate(path, int(m.group(2)))
        return h5py.File(path, "r+")
    except (OSError, RuntimeError):
        return None


def _rebuild(path: Path, header: RunHeader, points: list[dict[str, Any]],
             reason: BaseException) -> tuple[h5py.File, list[int]]:
    """A fresh file from the journal; every committed frame whose checksum still matches
    is copied from the damaged file (kept next to it as ``*.corrupt``). Returns the new
    file (open) and the positions of the frames that could not be salvaged (stored as
    zeros)."""
    bad = path.with_suffix(path.suffix + ".corrupt")
    if path.exists():
        os.replace(path, bad)
    f = _new_file(path, header)
    f["entry"].attrs["recovered_from"] = f"{bad.name}: {_first_line(reason)}"
    crcs = [fr[4] for p in points for fr in p["frames"]]
    if not crcs:
        return f, []
    old_frames = None
    old = None
    try:
        old = h5py.File(bad, "r")
        old_frames = old["entry/data/frames"]
    except (OSError, KeyError, RuntimeError):
        old_frames = None
    lost: list[int] = []
    ds = None
    try:
        for k, crc in enumerate(crcs):
            frame = None
            try:
                if old_frames is not None and k < old_frames.shape[0]:
                    frame = np.ascontiguousarray(old_frames[k])
                    if zlib.crc32(frame.tobytes()) != crc:
                        frame = None
            except (OSError, RuntimeError, ValueError):
                frame = None
            if ds is None:
                if frame is None and old_frames is None:
                    return f, list(range(len(crcs)))
                shape = frame.shape if frame is not None else old_frames.shape[1:]
                dtype = frame.dtype if frame is not None else old_frames.dtype
                ds = f["entry/data"].create_dataset(
                    "frames", shape=(len(crcs), *shape), maxshape=(None, *shape),
                    chunks=(1, *shape), dtype=dtype, compression="gzip",
                    compression_opts=1, shuffle=True)
                ds.attrs["units"] = "DN"
            if frame is None:
                lost.append(k)  # left as zeros; its point is marked FRAMES_LOST
            else:
                ds[k] = frame
    finally:
        if old is not None:
            old.close()
    return f, lost


def _reconcile(f: h5py.File, header: RunHeader, points: list[dict[str, Any]],
               events: list[str], rebuilt: bool) -> tuple[list[int], int]:
    pts = f["entry/points"]
    data = f["entry/data"]
    n = len(points)
    dropped = max(0, pts["index"].shape[0] - n)
    cols: dict[str, list[Any]] = {k: [] for k in (*FLOAT_FIELDS, *INT_FIELDS, *STR_FIELDS)}
    pos = np.full((n, max(len(header.axes), 1)), np.nan)
    frame_cols: dict[str, list[Any]] = {k: [] for k in FRAME_FIELDS}
    crcs: list[int] = []
    for k, p in enumerate(points):
        for j, name in enumerate(("theta_i", "phi_i", "theta_r", "phi_r")):
            cols[name].append(p["angles"][j])
        for name in ("t_start", "t_end", "exposure_us", "power_w", "signal"):
            cols[name].append(p[name])
        for name in ("index", "status", "frame_start", "retries"):
            cols[name].append(p[name])
        cols["n_frames"].append(len(p["frames"]))
        cols["label"].append(p["label"])
        cols["note"].append(p["note"])
        pos[k, :len(p["positions"])] = p["positions"]
        for fr in p["frames"]:
            frame_cols["frame_point"].append(p["index"])
            frame_cols["frame_exposure_us"].append(fr[0])
            frame_cols["frame_light"].append(fr[1])
            frame_cols["frame_timestamp"].append(fr[2])
            frame_cols["frame_saturated"].append(fr[3])
            crcs.append(fr[4])
    _put_rows(pts, 0, n, cols, pos)
    nf = len(crcs)
    frames_lost: list[int] = []
    if rebuilt:
        pass  # _rebuild checked every frame already
    elif "frames" in data:
        ds = data["frames"]
        if ds.shape[0] > nf:
            ds.resize(nf, axis=0)
        # The newest committed frames are the ones a crash could have torn: check them.
        for k in range(max(0, min(nf, ds.shape[0]) - 4), min(nf, ds.shape[0])):
            if zlib.crc32(np.ascontiguousarray(ds[k]).tobytes()) != crcs[k]:
                frames_lost.append(k)
        frames_lost += range(ds.shape[0], nf)
    else:
        frames_lost = list(range(nf))
    for name in FRAME_FIELDS:
        d = data[name]
        d.resize(nf, axis=0)
        if nf:
            d[:nf] = frame_cols[name]
    log = f["entry/events/log"]
    log.resize(len(events), axis=0)
    if events:
        log[:] = events
    return frames_lost, dropped
