"""Recovery: make a run file agree with its journal, and say in words what that took.

The journal ``<file>.journal`` is the commit log (docs/decisions/0010): a point is done when
its record is there. :func:`recover` makes the HDF5 file agree with it — truncates what was
never committed, rewrites the scalar tables and the event log from the journal, checks the
newest frames (every frame, when the file had been cut short) against their CRC-32s, and
rebuilds the file from the journal's header when it no longer opens, copying every frame
whose checksum still matches and keeping the damaged original as ``*.corrupt``. Points
whose frames are gone are marked "frames lost" (status 2) for good.

:func:`salvage` is for a run file whose journal is missing or unreadable: it writes a new
journal and a new file from what the damaged file still holds (the rows and frames that lie
before the damage), so the run can be resumed and the lost points measured again.

Every repair is described in :attr:`RecoveryReport.repairs` (what was lost, which points,
where the original went) and journalled as a ``repaired`` event, so it shows in the run
file's event log; the caller puts it on the console and in the catalog.

A point measured again (``scatterlab resume --remeasure-lost``) after its frames were lost
appends a new journal record with the same index: the newer record replaces the lost one
in the point's row, and the lost measurement's frames (zeros) stay in the frame stack with
``frame_point = -1`` (they belong to no point).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import h5py
import numpy as np

from instrument.run.health import (
    OPTIONAL_COLUMNS,
    Readable,
    inspect_run_file,
    is_lock_refusal,
    open_damaged,
    readable_points,
    recorded_length,
    row_count,
    unrecoverable_message,
)
from instrument.run.journal import Journal, read_journal
from instrument.run.layout import (
    DETECTOR_FIELDS,
    FLOAT_FIELDS,
    FRAME_FIELDS,
    FRAMES_LOST,
    FRAMES_LOST_NOTE,
    INT_FIELDS,
    STR_FIELDS,
    RunHeader,
    StorageError,
    detector_columns,
    grow_plan_tables,
    header_from_file,
    journal_path,
    new_run_file,
    put_rows,
)

__all__ = ["RecoveryReport", "describe_points", "journal_usable", "recover", "salvage"]

#: The newest committed frames checked against their checksums by every recovery (a kill
#: can tear only the write in flight, which touches the newest frames).
CHECK_NEWEST = 4


@dataclass(frozen=True)
class RecoveryReport:
    """What :func:`recover` (or :func:`salvage`) found and did.

    ``points_lost`` are the points whose frames this recovery found gone; ``lost`` every
    point whose frames are gone now (this recovery and earlier ones, not yet measured
    again). ``repairs`` says in words what this recovery changed (empty: nothing), and
    ``original`` where the damaged original went (``None`` when it was repaired in place
    or not at all). ``rows`` maps each point index to its row in the points table.
    """

    header: RunHeader
    n_points: int
    n_frames: int
    done: set[int]
    status: str
    rebuilt: bool
    dropped_rows: int
    frames_lost: int
    points_lost: tuple[int, ...] = ()
    lost: tuple[int, ...] = ()
    repairs: tuple[str, ...] = ()
    original: Path | None = None
    cut_short: tuple[int, int] | None = None
    journal_rebuilt: bool = False
    rows: dict[int, int] = field(default_factory=dict)

    @property
    def repaired(self) -> bool:
        return bool(self.repairs)


def describe_points(indices: Iterable[int]) -> str:
    """'3', '1, 2 and 5', or the first ten and a count for long lists."""
    idx = sorted(int(i) for i in indices)
    if len(idx) > 12:
        return ", ".join(map(str, idx[:10])) + f" and {len(idx) - 10} more"
    if len(idx) <= 1:
        return ", ".join(map(str, idx))
    return ", ".join(map(str, idx[:-1])) + f" and {idx[-1]}"


# ------------------------------------------------------------------------------ journal
@dataclass
class _Journalled:
    """The run as its journal tells it."""

    header: RunHeader
    points: list[dict[str, Any]]   # the standing record of each point, in row order
    frames: list[list[Any]]        # every frame written, in file order: exp, light, t, sat, crc
    owners: list[int]              # per frame: its point's index, -1 when superseded
    lost: set[int]                 # points whose frames are lost (after their last record)
    events: list[str]
    status: str

    @property
    def rows(self) -> dict[int, int]:
        return {p["index"]: k for k, p in enumerate(self.points)}


def journal_usable(path: str | Path) -> bool:
    """True when the run file's journal exists and starts with an intact run header (so
    :func:`recover` can work from it; otherwise only :func:`salvage` can)."""
    records, _ = read_journal(journal_path(path))
    return bool(records) and records[0].get("t") == "header"


def _not_a_run(path: Path) -> StorageError:
    """Why ``path`` (whose journal has no header) cannot be recovered from a journal."""
    jp = journal_path(path)
    state = inspect_run_file(path)
    if state.state in ("missing", "folder"):
        code = errno.ENOENT if state.state == "missing" else errno.EISDIR
        return StorageError(code, state.message)
    if not state.is_run:
        return StorageError(errno.EINVAL, state.message)
    if not jp.exists():
        return StorageError(errno.EINVAL, (
            f"{path} is a scatterlab run file but its journal {jp.name} is missing (copied "
            "without it?)" + ("; it is also damaged" if state.state == "damaged" else
                              ": it reads with h5py")))
    return StorageError(errno.EINVAL, f"{path}: its journal {jp.name} holds no intact run "
                        "header (damaged at its start)")


def _read_journal(path: Path) -> _Journalled:
    records, _ = read_journal(journal_path(path))
    if not records or records[0].get("t") != "header":
        raise _not_a_run(path)
    header = RunHeader.from_dict(records[0])
    points: list[dict[str, Any]] = []
    row: dict[int, int] = {}
    start: dict[int, int] = {}
    frames: list[list[Any]] = []
    owners: list[int] = []
    lost: set[int] = set()
    events: list[str] = []
    status = "interrupted"
    for r in records[1:]:
        t = r.get("t")
        if t == "point":
            i = r["index"]
            pos = len(frames)
            frames.extend(r["frames"])
            rec = {**r, "frame_start": pos}
            if i not in row:
                row[i] = len(points)
                points.append(rec)
                owners.extend([i] * len(r["frames"]))
            elif i in lost:  # measured again after its frames were lost: this one stands
                old = points[row[i]]
                for k in range(start[i], start[i] + len(old["frames"])):
                    owners[k] = -1
                points[row[i]] = rec
                owners.extend([i] * len(r["frames"]))
                lost.discard(i)
            else:  # a duplicate that nothing asked for: the first record stands
                owners.extend([-1] * len(r["frames"]))
                continue
            start[i] = pos
        elif t == "planned":  # an adaptive plan's decision: its points join the plan
            if r.get("first") == len(header.planned_label):
                header = header.with_planned(r["points"])
        elif t == "frames_lost":
            lost.add(r["index"])
        elif t == "event":
            events.append(json.dumps(r))
        elif t == "status":
            status = r["status"]
    if len(points) < len(header.planned_label) and status == "finished":
        status = "interrupted"
    points = [_mark_lost(p) if p["index"] in lost else p for p in points]
    return _Journalled(header, points, frames, owners, lost, events, status)


def _mark_lost(point: dict[str, Any]) -> dict[str, Any]:
    return {**point, "status": FRAMES_LOST, "note": FRAMES_LOST_NOTE}


# ------------------------------------------------------------------------------ recover
def recover(path: str | Path) -> RecoveryReport:
    """Make the run file agree with its journal (module docstring); say what it took.

    Safe to call on a healthy file (nothing is changed that matters, ``repairs`` is
    empty). Raises :class:`StorageError` when the journal has no header (the message says
    what the file is) or another program holds the file open.
    """
    return _recover(Path(path), fresh=False)


def _recover(path: Path, *, fresh: bool) -> RecoveryReport:
    """:func:`recover`; ``fresh``: the file was just made from the journal (salvage), so
    filling its tables is no repair to report."""
    j = _read_journal(path)
    rebuilt = False
    original: Path | None = None
    cut: tuple[int, int] | None = None
    check_all = False
    salvaged_lost: list[int] = []
    try:
        f = h5py.File(path, "r+")
    except (OSError, KeyError, RuntimeError) as err:
        text = str(err)
        if is_lock_refusal(text):
            raise StorageError(errno.EBUSY, f"{path} is open in another program (a run "
                               "still going?); close it first") from err
        cut = recorded_length(text)
        f = _open_padded(path, cut)
        check_all = f is not None  # the zeros standing in for the cut-off bytes
        if f is None:
            f, salvaged_lost, original = _rebuild(path, j, cut)
            rebuilt = True
    try:
        try:
            frames_lost, dropped, restored = _reconcile(f, j, rebuilt, check_all)
        except (KeyError, OSError, ValueError, RuntimeError):
            # The file opened but its structure is damaged (e.g. metadata whose flush
            # failed on a full disk): rebuild it from the journal, salvaging frames.
            f.close()
            f, salvaged_lost, original = _rebuild(path, j, cut)
            rebuilt = True
            frames_lost, dropped, restored = _reconcile(f, j, rebuilt, False)
        frames_lost = sorted({*frames_lost, *salvaged_lost})
        newly = _mark_points_lost(path, f, j, frames_lost)
        lost = j.lost.union(newly)
        n_lost_frames = sum(len(p["frames"]) for p in j.points if p["index"] in lost)
        if lost or "frames_lost" in f["entry"].attrs:
            f["entry"].attrs["frames_lost"] = n_lost_frames  # zeros standing in for frames
        repairs = _describe(path, j, rebuilt=rebuilt, original=original, cut=cut,
                            newly=newly, dropped=dropped, restored=0 if fresh else restored)
        if original is not None and not original.exists():
            original = None  # the file was missing: nothing was kept
        if repairs:
            _log_repair(path, f, repairs, newly, original)
        f["entry"].attrs["status"] = j.status
        f["entry"].attrs["n_points"] = len(j.points)
        f.flush()
    finally:
        f.close()
    return RecoveryReport(
        j.header, len(j.points), len(j.frames), {p["index"] for p in j.points}, j.status,
        rebuilt, dropped, len(frames_lost), newly, tuple(sorted(lost)), tuple(repairs),
        original, cut, False, j.rows)


def _describe(path: Path, j: _Journalled, *, rebuilt: bool, original: Path | None,
              cut: tuple[int, int] | None, newly: tuple[int, ...], dropped: int,
              restored: int) -> list[str]:
    """What a recovery changed, one sentence per repair (empty when nothing)."""
    out = []
    how = (f"cut short: {cut[0]} of its {cut[1]} bytes on disk" if cut and cut[1] > cut[0]
           else "it was missing" if original is not None and not original.exists()
           else "its HDF5 structure was damaged")
    if rebuilt:
        kept = (f"; the damaged original is kept as {original.name}"
                if original is not None and original.exists() else "")
        out.append(f"the run file could not be used as it was ({how}): rebuilt from the "
                   f"journal, every frame checked against its checksum{kept}")
    elif cut:
        out.append(f"the run file was {how} (a write that failed at its end): padded back "
                   "to its recorded length, every frame checked against its checksum")
    if newly:
        n = sum(len(p["frames"]) for p in j.points if p["index"] in newly)
        out.append(f"the frames of point(s) {describe_points(newly)} are lost ({n} frame(s); "
                   "zeros stand in for them): marked 'frames lost' (status 2) and left out "
                   "of analysis; their positions and readings are kept from the journal")
    if dropped:
        out.append(f"{dropped} point record(s) that were never committed discarded (the "
                   "point is measured again when the run continues)")
    if restored and not rebuilt:
        out.append(f"{restored} point row(s) written into the file from the journal (the "
                   "file lagged behind it)")
    return out


def _log_repair(path: Path, f: h5py.File, repairs: list[str], newly: tuple[int, ...],
                original: Path | None) -> None:
    """Journal the repair as an event and add it to the file's event log."""
    rec = {"t": "event", "kind": "repaired", "time": time.time(), "repairs": repairs,
           "points_lost": list(newly), "original": original.name if original else None}
    journal = Journal(journal_path(path), fsync=True)
    try:
        journal.append(rec)
    finally:
        journal.close()
    log = f["entry/events/log"]
    log.resize(log.shape[0] + 1, axis=0)
    log[-1] = json.dumps(rec)


def _mark_points_lost(path: Path, f: h5py.File, j: _Journalled,
                      lost_frames: list[int]) -> tuple[int, ...]:
    """Mark the points owning ``lost_frames`` (frame positions) as FRAMES_LOST.

    Their frames are zeros now; the mark goes into the points table (so analysis, which
    keeps status 0 only, leaves them out) and into the journal (so every later recovery,
    which rewrites the table from the journal, keeps it). Returns the newly marked point
    indices.
    """
    lost = sorted({j.owners[k] for k in lost_frames if j.owners[k] >= 0} - j.lost)
    if not lost:
        return ()
    journal = Journal(journal_path(path), fsync=True)
    try:
        for i in lost:
            journal.append({"t": "frames_lost", "index": i, "time": time.time()})
    finally:
        journal.close()
    rows = f["entry/points"]
    for k, p in enumerate(j.points):
        if p["index"] in lost:
            rows["status"][k] = FRAMES_LOST
            rows["note"][k] = FRAMES_LOST_NOTE
    return tuple(lost)


def _open_padded(path: Path, cut: tuple[int, int] | None) -> h5py.File | None:
    """Reopen a file whose last write failed after HDF5 had recorded its new end.

    HDF5 then refuses the file as "truncated file: eof = A, ..., stored_eof = B". Padding
    the file with zeros to B makes it open again; the reconciliation that follows checks
    every frame against its checksum, since the cut may have taken committed frames too.
    """
    if cut is None or cut[1] <= cut[0]:
        return None
    try:
        os.truncate(path, cut[1])
        return h5py.File(path, "r+")
    except (OSError, RuntimeError):
        return None


@contextlib.contextmanager
def _read_damaged(path: Path, cut: tuple[int, int] | None) -> Iterator[h5py.Dataset | None]:
    """The frame stack of a damaged file, read-only (through zero padding when it was cut
    short), or None when it cannot be read at all."""
    with contextlib.ExitStack() as stack:
        frames = None
        try:
            f = stack.enter_context(h5py.File(path, "r"))
            frames = f["entry/data/frames"]
        except (OSError, KeyError, RuntimeError):
            try:
                length = cut[1] if cut else path.stat().st_size
                f, _ = stack.enter_context(open_damaged(path, length))
                frames = f["entry/data/frames"]
            except (OSError, KeyError, RuntimeError, ValueError):
                frames = None
        yield frames


def _rebuild(path: Path, j: _Journalled, cut: tuple[int, int] | None
             ) -> tuple[h5py.File, list[int], Path]:
    """A fresh file from the journal; every committed frame whose checksum still matches
    is copied from the damaged file (kept next to it as ``*.corrupt``). Returns the new
    file (open), the positions of the frames that could not be salvaged (stored as zeros)
    and where the original went."""
    bad = path.with_suffix(path.suffix + ".corrupt")
    if path.exists():
        os.replace(path, bad)
    f = new_run_file(path, j.header)
    f["entry"].attrs["recovered_from"] = bad.name
    crcs = [fr[4] for fr in j.frames]
    if not crcs:
        return f, [], bad
    lost: list[int] = []
    with _read_damaged(bad, cut) as old:
        ds = None
        for k, crc in enumerate(crcs):
            frame = None
            try:
                if old is not None and k < old.shape[0]:
                    frame = np.ascontiguousarray(old[k])
                    if zlib.crc32(frame.tobytes()) != crc:
                        frame = None
            except (OSError, RuntimeError, ValueError):
                frame = None
            if ds is None:
                if frame is None and old is None:
                    return f, [k for k in range(len(crcs)) if j.owners[k] >= 0], bad
                # old is not None here: a missing frame and no old file returned above
                shape = frame.shape if frame is not None else cast(Any, old).shape[1:]
                dtype = frame.dtype if frame is not None else cast(Any, old).dtype
                ds = _frame_stack(f, len(crcs), shape, dtype)
            if frame is None:
                if j.owners[k] >= 0:
                    lost.append(k)  # left as zeros; its point is marked FRAMES_LOST
            else:
                ds[k] = frame
    return f, lost, bad


def _frame_stack(f: h5py.File, n: int, shape: tuple[int, ...], dtype: Any) -> h5py.Dataset:
    ds = f["entry/data"].create_dataset(
        "frames", shape=(n, *shape), maxshape=(None, *shape), chunks=(1, *shape),
        dtype=dtype, compression="gzip", compression_opts=1, shuffle=True)
    ds.attrs["units"] = "DN"
    return ds


def _reconcile(f: h5py.File, j: _Journalled, rebuilt: bool, check_all: bool
               ) -> tuple[list[int], int, int]:
    """Rewrite the tables from the journal; returns (lost frame positions, uncommitted
    rows dropped, rows the file lacked)."""
    header, points = j.header, j.points
    pts = f["entry/points"]
    data = f["entry/data"]
    n = len(points)
    had = pts["index"].shape[0]
    dropped = max(0, had - n)
    restored = max(0, n - had)
    cols: dict[str, list[Any]] = {k: [] for k in (*FLOAT_FIELDS, *INT_FIELDS, *STR_FIELDS)}
    pos = np.full((n, max(len(header.axes), 1)), np.nan)  # no axis moved: one NaN column
    for k, p in enumerate(points):
        for jj, name in enumerate(("theta_i", "phi_i", "theta_r", "phi_r")):
            cols[name].append(p["angles"][jj])
        for name in ("t_start", "t_end", "exposure_us", "power_w", "signal"):
            cols[name].append(p[name])
        for name in ("index", "status", "frame_start", "retries"):
            cols[name].append(p[name])
        cols["n_frames"].append(len(p["frames"]))
        cols["label"].append(p["label"])
        cols["note"].append(p["note"])
        pos[k, :len(p["positions"])] = p["positions"]
    put_rows(pts, 0, n, {**cols, **detector_columns(pts, [p.get("extra", {}) for p in points])},
             pos)
    nf = len(j.frames)
    frame_cols = {
        "frame_point": j.owners,
        "frame_exposure_us": [fr[0] for fr in j.frames],
        "frame_light": [fr[1] for fr in j.frames],
        "frame_timestamp": [fr[2] for fr in j.frames],
        "frame_saturated": [fr[3] for fr in j.frames],
    }
    frames_lost: list[int] = []
    if rebuilt:
        pass  # _rebuild checked every frame already
    elif "frames" in data:
        ds = data["frames"]
        if ds.shape[0] > nf:
            ds.resize(nf, axis=0)
        # The newest committed frames are the ones a crash could have torn: check them
        # (all of them when the file had been cut short and padded with zeros).
        first = 0 if check_all else max(0, min(nf, ds.shape[0]) - CHECK_NEWEST)
        for k in range(first, min(nf, ds.shape[0])):
            if j.owners[k] < 0:
                continue
            if zlib.crc32(np.ascontiguousarray(ds[k]).tobytes()) != j.frames[k][4]:
                frames_lost.append(k)
        frames_lost += [k for k in range(ds.shape[0], nf) if j.owners[k] >= 0]
    else:
        frames_lost = [k for k in range(nf) if j.owners[k] >= 0]
    for name in FRAME_FIELDS:
        d = data[name]
        d.resize(nf, axis=0)
        if nf:
            d[:nf] = frame_cols[name]
    if header.adaptive:  # a growing plan: the journal's decisions (ADR 0091)
        grow_plan_tables(f["entry/plan"], header)
    log = f["entry/events/log"]
    log.resize(len(j.events), axis=0)
    if j.events:
        log[:] = j.events
    return frames_lost, dropped, restored


# ------------------------------------------------------------------------------ salvage
def salvage(path: str | Path) -> RecoveryReport:
    """Recover a run file whose journal is missing or unreadable from what it holds.

    The readable points (rows and frames before any damage) are written into a new
    journal and a new file; points whose rows survive but whose frames do not are kept
    and marked "frames lost"; points whose rows are cut off are not in the new file (the
    run continues with them). The original is kept next to it as ``*.corrupt`` (damaged)
    or ``*.orig`` (intact but without its journal), an unreadable journal as
    ``*.journal.corrupt``.

    Raises
    ------
    StorageError
        The file is missing, not a scatterlab run, held open, or unreadable.
    """
    path = Path(path)
    state = inspect_run_file(path)
    if not state.is_run:
        raise StorageError(errno.EINVAL if state.state != "missing" else errno.ENOENT,
                           state.message or f"{path} is not a scatterlab run file")
    if state.state == "busy":
        raise StorageError(errno.EBUSY, state.message)
    damaged = state.state == "damaged"
    cut = (state.size, state.recorded_size) if damaged else None
    try:
        content = _salvageable(path, cut)
    except (KeyError, OSError, RuntimeError, ValueError) as err:
        how = (f"cut short: {cut[0]} of its {cut[1]} bytes on disk"
               if cut and cut[1] > cut[0] else "its HDF5 structure is damaged")
        raise StorageError(errno.EIO, unrecoverable_message(path, how)) from err
    header, records, lost, events, status, sources, n_rows = content
    original = path.with_suffix(path.suffix + (".corrupt" if damaged else ".orig"))
    jp = journal_path(path)
    if jp.exists():
        os.replace(jp, jp.with_suffix(jp.suffix + ".corrupt"))
    os.replace(path, original)
    readable = [r["index"] for r in records if r["index"] not in lost]
    cut_off = n_rows - len(records)
    how = f"cut short: {cut[0]} of its {cut[1]} bytes on disk; " if cut else ""
    words = [f"its journal was missing or unreadable: a new journal and run file were made "
             f"from what {'the damaged' if damaged else 'the'} file holds ({how}points "
             f"{describe_points(readable) or 'none'} readable); the original is kept as "
             f"{original.name}"]
    if lost:
        n = sum(len(r["frames"]) for r in records if r["index"] in lost)
        words.append(f"the frames of point(s) {describe_points(lost)} are lost ({n} frame(s); "
                     "zeros stand in for them): marked 'frames lost' (status 2) and left out "
                     "of analysis; their positions and readings are kept")
    if cut_off > 0:
        words.append(f"{cut_off} point record(s) were cut off: those points are measured "
                     "again when the run continues")
    repair = {"t": "event", "kind": "repaired", "time": time.time(), "repairs": words,
              "points_lost": sorted(lost), "original": original.name}
    tmp = jp.with_name(jp.name + ".tmp")
    tmp.unlink(missing_ok=True)
    journal = Journal(tmp, fsync=True)
    try:
        journal.append({"t": "header", **header.as_dict()})
        for r in records:
            journal.append(r)
        for i in sorted(lost):
            journal.append({"t": "frames_lost", "index": i, "time": time.time()})
        for e in events:
            journal.append(e)
        journal.append(repair)
        if status in ("finished", "aborted", "paused", "failed"):
            journal.append({"t": "status", "status": status, "time": time.time(),
                            "n_points": len(records)})
    finally:
        journal.close()
    os.replace(tmp, jp)
    _copy_frames(path, header, original, cut, sources)
    report = _recover(path, fresh=True)
    return replace(report, repairs=(*words, *report.repairs), original=original,
                   cut_short=cut, journal_rebuilt=True,
                   points_lost=tuple(sorted(set(report.points_lost) | lost)))


def _salvageable(path: Path, cut: tuple[int, int] | None
                 ) -> tuple[RunHeader, list[dict[str, Any]], set[int], list[dict[str, Any]], str,
                            list[int], int]:
    """Read what a run file still holds: (header, point records, points whose frames are
    lost, event records, status, old frame position per new frame, rows in the table)."""
    with contextlib.ExitStack() as stack:
        if cut is None:
            f = stack.enter_context(h5py.File(path, "r"))
            end = path.stat().st_size
        else:
            f, end = stack.enter_context(open_damaged(path, cut[1]))
        header = header_from_file(f)  # without it nothing can be rebuilt: the caller says so
        e = f["entry"]
        try:
            found = readable_points(f, end)
        except (KeyError, OSError, RuntimeError, ValueError):
            # as inspect_run_file says: no point readable, the run is measured again
            found = Readable({}, {}, set(), row_count(f))
        rows, n_rows = found.rows, found.n_rows
        order = sorted(rows, key=cast("Callable[[int], int]", rows.get))
        at = np.array([rows[i] for i in order], dtype=np.int64)
        p = e["points"]
        # col and fcol: arrays, or None for a column that did not read; the rows are used
        # only when every column they need read (checked below)
        col: dict[str, Any] = {name: _read_or_none(p[name], at) for name in
               (*FLOAT_FIELDS, *INT_FIELDS, *STR_FIELDS, "positions")}
        xcol = {name: _read_or_none(p[name], at) for name in DETECTOR_FIELDS if name in p}
        if any(v is None for c, v in col.items() if c not in OPTIONAL_COLUMNS):
            order = []  # a column the rows need did not read after all: none is readable
        d = e["data"]
        fcol: dict[str, Any] = {name: _read_or_none(d[name]) for name in FRAME_FIELDS
                                if name in d}
        if any(v is None for v in fcol.values()) or len(fcol) < len(FRAME_FIELDS):
            fcol = {}
        frames = d.get("frames")
        records: list[dict[str, Any]] = []
        lost: set[int] = set()
        sources: list[int] = []
        for k, i in enumerate(order):
            a, n = found.spans.get(i, (0, 0))
            ok = i in found.intact and (n == 0 or (bool(fcol) and frames is not None))
            fr = []
            for j in range(a, a + n):
                meta = ([float(fcol["frame_exposure_us"][j]), bool(fcol["frame_light"][j]),
                         float(fcol["frame_timestamp"][j]), float(fcol["frame_saturated"][j])]
                        if fcol and j < fcol["frame_point"].size
                        else [float("nan"), True, float("nan"), float("nan")])
                crc = -1
                if ok:
                    try:
                        crc = zlib.crc32(np.ascontiguousarray(frames[j]).tobytes())
                    except (OSError, RuntimeError, ValueError):
                        ok = False
                fr.append([*meta, crc])
                sources.append(j)
            if not ok:
                lost.add(i)
                fr = [[*m[:4], -1] for m in fr]

            def value(name: str, default: Any, k: int = k) -> Any:
                v = col[name]
                return default if v is None else v[k]

            label = value("label", header.planned_label[i] if i < len(header.planned_label)
                          else "sample")
            records.append({
                "t": "point", "index": i,
                "label": label.decode() if isinstance(label, bytes) else str(label),
                "status": int(col["status"][k]),
                "note": _text_of(value("note", "")),
                "t_start": float(col["t_start"][k]), "t_end": float(col["t_end"][k]),
                "positions": [float(x) for x in col["positions"][k]],
                "angles": [float(col[c][k]) for c in ("theta_i", "phi_i", "theta_r",
                                                      "phi_r")],
                "exposure_us": float(col["exposure_us"][k]),
                "power_w": float(col["power_w"][k]), "signal": float(col["signal"][k]),
                "retries": int(value("retries", 0)), "frame_start": 0, "frames": fr,
                "extra": {name: float(v[k]) for name, v in xcol.items() if v is not None}})
        events = []
        with contextlib.suppress(KeyError, OSError, RuntimeError, ValueError):
            for line in e["events/log"].asstr()[()]:
                with contextlib.suppress(ValueError):
                    ev = json.loads(line)
                    if isinstance(ev, dict) and ev.get("t") == "event":
                        events.append(ev)
        status = "interrupted"  # written at the end of a run: often beyond the cut
        with contextlib.suppress(KeyError, OSError, RuntimeError, ValueError):
            status = _text_of(e.attrs.get("status", status))
    return header, records, lost, events, status, sources, n_rows


def _read_or_none(ds: h5py.Dataset, rows: np.ndarray | None = None) -> np.ndarray | None:
    """A dataset (only ``rows`` of it, when given), or None when the damage left it
    unreadable."""
    try:
        if rows is None:
            return cast(np.ndarray | None, ds[()])
        return ds[rows] if rows.size else np.zeros((0, *ds.shape[1:]), dtype=ds.dtype)
    except (OSError, RuntimeError, ValueError, KeyError, TypeError):
        return None


def _text_of(value: Any) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _copy_frames(path: Path, header: RunHeader, original: Path,
                 cut: tuple[int, int] | None, sources: list[int]) -> None:
    """The new run file: the layout from ``header`` and the frames at ``sources`` of the
    original copied in order (what cannot be read stays zeros; recovery marks it)."""
    f = new_run_file(path, header)
    try:
        f["entry"].attrs["recovered_from"] = original.name
        if not sources:
            return
        with _read_damaged(original, cut) as old:
            if old is None:
                return
            ds = _frame_stack(f, len(sources), old.shape[1:], old.dtype)
            for k, src in enumerate(sources):
                with contextlib.suppress(OSError, RuntimeError, ValueError):
                    ds[k] = old[src]
    finally:
        f.close()
