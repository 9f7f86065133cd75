"""Writing a run: one HDF5 file per run (NeXus-style, plain h5py) plus its commit journal.

The file's layout is :mod:`instrument.run.layout`; recovery (making the file agree with the
journal after a crash or damage, and saying what that took) is
:mod:`instrument.run.recovery`. Both are re-exported here for the engine and the runner.

Durability (docs/decisions/0010): the journal ``<file>.journal`` is the commit log. A
point is complete when its record is in the journal; its frames are written and flushed
to the HDF5 file *before* that record is appended. Scalar rows are written to the HDF5
file in batches (every ``sync_interval_s`` and whenever frames are flushed), so a kill -9
can leave the HDF5 tables behind the journal, never ahead of it in a way that counts.

Space is reserved on disk before every HDF5 write (``posix_fallocate``), so a full disk
fails before anything is written. HDF5 does not know of that reservation; when the run
file is closed the reservation left over is given back (the file is cut to the length
HDF5 allocated), so a finished file holds no unused space at its end.

A point whose frames were lost to a damaged file can be measured again into the same
file (``resume --remeasure-lost``): its new frames are appended, its row is rewritten in
place, and the journal's newer record stands.
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
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from instrument.run.frame_chunks import encode_frames
from instrument.run.journal import Journal
from instrument.run.layout import (
    FLOAT_FIELDS,
    FRAMES_LOST,
    FRAMES_LOST_NOTE,
    INT_FIELDS,
    REMEASURED_NOTE,
    STATUS_OK,
    STATUS_SKIPPED,
    STR_FIELDS,
    RunHeader,
    StorageError,
    clean_error,
    detector_columns,
    end_of_allocation,
    grow_plan_tables,
    iso_time,
    journal_path,
    new_run_file,
    put_rows,
)
from instrument.run.recovery import RecoveryReport, recover, salvage

__all__ = ["FRAMES_LOST", "FRAMES_LOST_NOTE", "STATUS_OK", "STATUS_SKIPPED", "FrameData",
           "PointRecord", "RecoveryReport", "RunHeader", "RunStore", "StorageError",
           "free_space_probe", "journal_path", "recover", "salvage"]

#: Disk space reserved per point besides its frames: new chunks of the scalar tables
#: (at most 1024 rows × 8 B × ~20 datasets) and metadata.
RESERVE_BYTES = 512 * 1024


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
    #: Readings of :data:`~instrument.run.layout.DETECTOR_FIELDS` (missing: NaN).
    extra: dict[str, float] = field(default_factory=dict)


# --------------------------------------------------------------------------- writer


class RunStore:
    """Writes one run. Not thread-safe: the engine's writer thread owns it."""

    def __init__(self, path: Path, h5: h5py.File, journal: Journal, header: RunHeader, *,
                 n_points: int, n_frames: int, fsync: bool, sync_interval_s: float,
                 min_free_bytes: int, rows: dict[int, int] | None = None,
                 lost: tuple[int, ...] = ()) -> None:
        self.path = path
        self.header = header
        self._h5 = h5
        self._journal = journal
        self.n_points = n_points
        self.n_frames = n_frames
        self.fsync = fsync
        self.sync_interval_s = sync_interval_s
        self.min_free_bytes = min_free_bytes
        #: Points whose frames were lost to a damaged file: appending one of them measures
        #: it again (its row is rewritten in place, see the module docstring).
        self.lost = tuple(lost)
        self._rows = {i: r for i, r in (rows or {}).items() if i in set(lost)}
        #: What the recovery before this reopening repaired, in words (empty: nothing).
        self.repairs: tuple[str, ...] = ()
        self._pending: list[tuple[PointRecord, int, int]] = []
        self._pending_replaced: list[tuple[int, PointRecord, int, int]] = []
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
        # No run file yet: there is nothing to resume, the run is started again.
        _check_free(path.parent, min_free_bytes, 0, then="free space or choose another "
                    "folder for run files, then start the run again")
        h5 = new_run_file(path, header)
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
        """Recover ``path`` and open it to append; returns the store and the done indices.

        The points whose frames are lost count as done; ``store.lost`` names them, and
        appending one measures it again.
        """
        path = Path(path)
        report = recover(path)
        h5 = h5py.File(path, "r+")
        journal = Journal(journal_path(path), fsync=fsync)
        store = cls(path, h5, journal, report.header, n_points=report.n_points,
                    n_frames=report.n_frames, fsync=fsync, sync_interval_s=sync_interval_s,
                    min_free_bytes=min_free_bytes, rows=report.rows, lost=report.lost)
        store.repairs = report.repairs
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
        row = self._rows.get(rec.index)
        if row is not None and not rec.note:
            rec.note = REMEASURED_NOTE
        try:
            frame_start = self.n_frames
            if rec.frames:
                self._write_frames(rec.index, rec.frames)
            entry = _point_json(rec, frame_start)
            if row is None:
                self._pending.append((rec, frame_start, len(rec.frames)))
            else:
                self._pending_replaced.append((row, rec, frame_start, len(rec.frames)))
            if writes_hdf5:
                self._sync_tables(extra=int(row is None))
            self._journal.append(entry)
        except (OSError, RuntimeError) as err:
            # h5py reports failed writes/flushes as OSError or RuntimeError (H5Fflush).
            self._pending.clear()
            self._pending_replaced.clear()
            if isinstance(err, StorageError):
                raise
            raise StorageError(_errno_of(err),
                               f"writing point {rec.index} to {self.path} failed: "
                               f"{_first_line(err)}") from err
        if row is None:
            self.n_points += 1
        else:  # measured again: committed, so it is no longer lost
            del self._rows[rec.index]
            self.lost = tuple(i for i in self.lost if i != rec.index)
        self.n_frames = frame_start + len(entry["frames"])

    def extend_plan(self, rows: list[dict[str, Any]], decision: dict[str, Any]) -> None:
        """Commit points an adaptive plan has just decided (ADR 0091): the journal's
        ``planned`` record first (when it returns, the points are part of the run), then
        the file's planned tables, flushed. A kill between the two leaves the file's tables
        behind the journal, and :func:`recover` extends them from it; no point of the new
        rows is measured before this returns.

        ``rows`` hold, per point, ``targets`` (one per axis, NaN where it has none),
        ``angles`` (θi, φi, θr, φr), ``label``, ``light``, ``exposure_us`` (NaN: the
        policy's) and optionally ``meta``; ``decision`` is what the plan said about them
        (JSON), kept with the record.
        """
        if not self.header.adaptive:
            raise ValueError(f"{self.path} holds a fixed plan: its planned points cannot grow")
        first = len(self.header.planned_label)
        try:
            self._journal.append({"t": "planned", "first": first, "points": rows,
                                  "decision": decision})
            self.header = self.header.with_planned(rows)
            grow_plan_tables(self._h5["entry/plan"], self.header)
            self._h5.flush()
        except (OSError, RuntimeError) as err:
            if isinstance(err, StorageError):
                raise
            raise StorageError(_errno_of(err), f"adding planned points to {self.path} "
                               f"failed: {_first_line(err)}") from err

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

    def journal_event(self, record: dict[str, Any]) -> None:
        """Log an event after a storage error closed or abandoned the store: the journal
        alone (a journal line is a few hundred bytes), from which every recovery, and so
        every ``resume``, rewrites the file's event log.

        Raises
        ------
        StorageError
            Even the journal could not be written.
        """
        if not self._closed:
            raise ValueError("the store is open: use event()")
        try:
            journal = Journal(journal_path(self.path), fsync=self.fsync)
            try:
                journal.append({"t": "event", "time": time.time(), **record})
            finally:
                journal.close()
        except OSError as err:
            raise StorageError(_errno_of(err), f"logging an event in "
                               f"{journal_path(self.path)} failed: {_first_line(err)}"
                               ) from err

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
            entry.attrs["end_time"] = iso_time(time.time())
            entry.attrs["n_points"] = self.n_points
            self._h5.flush()
            self._journal.append({"t": "status", "status": status, "time": time.time(),
                                  "n_points": self.n_points})
        finally:
            self._h5.close()
            self._journal.close()
        self._give_back_reserve()

    def _give_back_reserve(self) -> None:
        """Cut the closed file to the length HDF5 allocated: the last space reservation
        (:meth:`_reserve`) lies beyond it, unused. Only bytes HDF5 does not use are cut,
        so a crash here leaves a valid file either way."""
        end = end_of_allocation(self.path)
        try:
            if end is not None and self.path.stat().st_size > end:
                os.truncate(self.path, end)
                if self.fsync:
                    _fsync_path(self.path)
        except OSError:
            pass  # the file is complete; the space is merely not given back

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
            raise clean_error(err.errno or errno.ENOSPC,
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
        # compressed on parallel threads without the GIL, to HDF5's own bytes
        # (instrument.run.frame_chunks); None: h5py's filters do it
        chunks = encode_frames([f.data for f in frames], ds)
        for k, f in enumerate(frames):
            if chunks is None:
                ds[n0 + k] = f.data
            else:
                ds.id.write_direct_chunk((n0 + k, *(0,) * (ds.ndim - 1)), chunks[k])
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
        for row, rec, frame_start, n_frames in self._pending_replaced:
            pts = self._h5["entry/points"]
            old, n_old = int(pts["frame_start"][row]), int(pts["n_frames"][row])
            if n_old:  # the lost measurement's frames now belong to no point
                self._h5["entry/data/frame_point"][old:old + n_old] = -1
            _write_rows(pts, row, [(rec, frame_start, n_frames)], len(self.header.axes))
        self._pending_replaced.clear()
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


def _disk_free(folder: Path) -> int:
    return shutil.disk_usage(folder).free


#: Bytes free on the file system of a folder; :func:`free_space_probe` puts another
#: measure in its place (an emulated small disk), the way the emulators inject faults.
_free_bytes: Callable[[Path], int] = _disk_free


@contextlib.contextmanager
def free_space_probe(probe: Callable[[Path], int]) -> Iterator[None]:
    """Measure free space with ``probe(folder) -> bytes`` for the block (every run of this
    process): a disk nearly full without filling one."""
    global _free_bytes
    old, _free_bytes = _free_bytes, probe
    try:
        yield
    finally:
        _free_bytes = old


def _check_free(folder: Path, min_free: int, needed: int, *,
                then: str = "free space, then `scatterlab resume`") -> None:
    free = _free_bytes(folder)
    if free < min_free + needed:
        need = f" (point needs {needed / 2**20:.2f} MiB)" if needed else ""
        raise clean_error(
            errno.ENOSPC,
            f"disk nearly full: {free / 2**20:.1f} MiB free in {folder}, the run keeps "
            f"at least {min_free / 2**20:.1f} MiB free{need}; {then}",
        )


def _point_json(rec: PointRecord, frame_start: int) -> dict[str, Any]:
    return {
        "t": "point", "index": rec.index, "label": rec.label, "status": rec.status,
        "note": rec.note, "t_start": rec.t_start, "t_end": rec.t_end,
        "positions": list(rec.positions), "angles": list(rec.angles),
        "exposure_us": rec.exposure_us, "power_w": rec.power_w, "signal": rec.signal,
        "retries": rec.retries, "frame_start": frame_start, "extra": dict(rec.extra),
        "frames": [[f.exposure_us, bool(f.light), f.timestamp, f.saturated,
                    zlib.crc32(np.ascontiguousarray(f.data).tobytes())] for f in rec.frames],
    }


def _write_rows(grp: h5py.Group, n0: int, recs: list[tuple[PointRecord, int, int]],
                n_axes: int) -> None:
    n1 = n0 + len(recs)
    cols: dict[str, list[Any]] = {k: [] for k in (*FLOAT_FIELDS, *INT_FIELDS, *STR_FIELDS)}
    pos = np.full((len(recs), max(n_axes, 1)), np.nan)  # a plan that moves no axis: 1 NaN
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
    put_rows(grp, n0, n1, {**cols, **detector_columns(grp, [r.extra for r, _, _ in recs])},
             pos, shrink=False)
