"""What state a run file is in, said in words that name the problem.

Every command that opens a run file — the analyses, ``resume``, the summaries — asks
:func:`inspect_run_file` first, so a missing file, a folder, a file that is not HDF5, an
HDF5 file that is not a run, a run still being written and a damaged run file are named
the same way everywhere, and never with the HDF5 library's own text.

A damaged file is usually one cut short (a copy interrupted, a disk that filled while a
write was in flight): HDF5 then refuses it ("truncated file") although everything before
the cut is intact. :class:`ZeroPadded` presents such a file to h5py read-only, padded with
zeros to the length its superblock records, so the intact part can be read without
changing a byte of the damaged original; :func:`readable_points` says which points' rows
and frames lie wholly before the cut.
"""

from __future__ import annotations

import contextlib
import io
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from instrument.run.layout import header_from_file

if TYPE_CHECKING:
    from _typeshed import WriteableBuffer

__all__ = ["OPTIONAL_COLUMNS", "SALVAGE_WORDS", "FileState", "Readable", "ZeroPadded",
           "held_by_this_process", "inspect_run_file", "is_lock_refusal", "open_damaged",
           "readable_points", "recorded_length", "row_count", "unrecoverable_message"]

#: HDF5's word for a file shorter than its superblock says (the library's message text).
_TRUNCATED = re.compile(r"truncated file: eof = (\d+).*stored_eof = (\d+)")
#: HDF5's words for a file another process holds open (file locking).
_LOCKED = re.compile(r"unable to lock file|already open", re.IGNORECASE)


def journal_of(path: Path) -> Path:
    return Path(str(path) + ".journal")


@dataclass(frozen=True)
class FileState:
    """What :func:`inspect_run_file` found.

    ``state`` is one of ``ok``, ``missing``, ``folder``, ``not_hdf5``, ``not_run``,
    ``busy`` (another process writes it), ``damaged``; ``message`` says it in words
    (empty when ``ok``). For a damaged file, ``size``/``recorded_size`` are its length
    and the length HDF5 recorded (equal when it is damaged otherwise), ``has_journal``
    whether a journal can rebuild it, and ``readable``/``unreadable`` which points the
    file still holds intact (when it could be read at all).
    """

    path: Path
    state: str
    message: str = ""
    is_run: bool = False
    has_journal: bool = False
    size: int = 0
    recorded_size: int = 0
    n_planned: int = 0
    readable: tuple[int, ...] = ()
    unreadable: tuple[int, ...] = ()
    plan_kind: str = ""

    @property
    def ok(self) -> bool:
        return self.state == "ok"


def is_lock_refusal(message: str) -> bool:
    """True when HDF5 refused an open because another process holds the file."""
    return _LOCKED.search(message) is not None


def recorded_length(message: str) -> tuple[int, int] | None:
    """(actual, recorded) byte lengths from HDF5's "truncated file" refusal, or None."""
    m = _TRUNCATED.search(message)
    return (int(m.group(1)), int(m.group(2))) if m else None


class ZeroPadded(io.RawIOBase):
    """A read-only view of a file that reads as zeros from its end up to ``length``."""

    def __init__(self, path: str | Path, length: int) -> None:
        super().__init__()
        self._f = open(path, "rb")  # noqa: SIM115 - closed by close()
        self._real = self._f.seek(0, io.SEEK_END)
        self._length = max(int(length), self._real)
        self._pos = 0

    @property
    def real_size(self) -> int:
        return self._real

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self._length}[whence]
        self._pos = max(0, base + offset)
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, buffer: WriteableBuffer) -> int:
        view = memoryview(buffer).cast("B")
        end = min(self._pos + len(view), self._length)
        n = max(0, end - self._pos)
        if n == 0:
            return 0
        got = 0
        if self._pos < self._real:
            self._f.seek(self._pos)
            got = self._f.readinto(view[:min(n, self._real - self._pos)]) or 0
        view[got:n] = bytes(n - got)
        self._pos += n
        return n

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._f.close()
        super().close()


@contextlib.contextmanager
def open_damaged(path: str | Path, recorded: int) -> Iterator[tuple[h5py.File, int]]:
    """A cut-short HDF5 file open read-only through :class:`ZeroPadded`; yields the file
    and the byte length actually on disk (data at or beyond it reads as zeros)."""
    raw = ZeroPadded(path, recorded)
    try:
        with h5py.File(raw, "r") as f:
            yield f, raw.real_size
    finally:
        raw.close()


def _chunks_within(ds: h5py.Dataset, end: int) -> np.ndarray:
    """Per leading-axis index of a chunked dataset: True where its chunk is stored wholly
    before byte ``end`` (False where unallocated or cut off)."""
    n = ds.shape[0]
    ok = np.zeros(n, dtype=bool)
    try:
        _mark_stored(ds, end, ok)
    except (OSError, RuntimeError, ValueError):
        ok[:] = False  # its chunk index itself lies beyond the cut
    return ok


def _mark_stored(ds: h5py.Dataset, end: int, ok: np.ndarray) -> None:
    if ds.chunks is None:
        off = ds.id.get_offset()
        ok[:] = off is not None and off + ds.id.get_storage_size() <= end
        return
    step = ds.chunks[0]
    for k in range(ds.id.get_num_chunks()):
        info = ds.id.get_chunk_info(k)
        if info.byte_offset is None:
            continue
        start = info.chunk_offset[0]
        if info.byte_offset + info.size <= end:
            ok[start:start + step] = True


#: Point columns a salvage can do without (label from the plan, no note, no retries, the
#: frames found through ``frame_point``): a row is readable when every other one is.
OPTIONAL_COLUMNS = ("label", "note", "retries", "frame_start", "n_frames")


@dataclass(frozen=True)
class Readable:
    """What :func:`readable_points` found: ``rows`` maps each point index whose row is
    intact to its row; ``spans`` gives its frames (first position, count); ``intact``
    holds the points whose frames are intact too (a point without frames counts as
    intact); ``n_rows`` is the number of rows the table holds, readable or not."""

    rows: dict[int, int]
    spans: dict[int, tuple[int, int]]
    intact: set[int]
    n_rows: int


def readable_points(f: h5py.File, end: int) -> Readable:
    """Which points of a run file lie wholly before byte ``end`` (see :class:`Readable`)."""
    pts = f["entry/points"]
    n = pts["index"].shape[0]
    row_ok = np.ones(n, dtype=bool)
    whole: dict[str, np.ndarray] = {}
    for name, ds in pts.items():
        if isinstance(ds, h5py.Dataset) and ds.shape and ds.shape[0] == n:
            whole[name] = _chunks_within(ds, end)
            if name not in OPTIONAL_COLUMNS:
                row_ok &= whole[name]
    ok_rows = np.flatnonzero(row_ok)
    data = f["entry/data"]
    frame_point = _read_rows(data.get("frame_point"),
                             np.arange(data["frame_point"].shape[0])
                             if "frame_point" in data else np.zeros(0, dtype=np.int64))
    index = _read_rows(pts["index"], ok_rows)
    if index is None:
        return Readable({}, {}, set(), n)
    rows = {int(i): int(r) for i, r in zip(index, ok_rows, strict=True)}
    spans: dict[int, tuple[int, int]] = {}
    has_span = whole.get("frame_start", row_ok) & whole.get("n_frames", row_ok)
    start = _read_rows(pts["frame_start"], ok_rows) if has_span[ok_rows].all() else None
    count = _read_rows(pts["n_frames"], ok_rows) if has_span[ok_rows].all() else None
    for k, i in enumerate(rows):
        if start is not None and count is not None:
            spans[i] = (int(start[k]), int(count[k]))
        elif frame_point is not None:  # the frames of point i, found by their owner
            mine = np.flatnonzero(frame_point == i)
            if mine.size and np.all(np.diff(mine) == 1):
                spans[i] = (int(mine[0]), int(mine.size))
            elif not mine.size:
                spans[i] = (0, 0)
    frames = data.get("frames")
    frame_ok = (_chunks_within(frames, end) if frames is not None
                else np.zeros(0, dtype=bool))
    for name in ("frame_exposure_us", "frame_light", "frame_timestamp", "frame_saturated"):
        table = data.get(name)  # a frame is usable with its exposure and lighting only
        if isinstance(table, h5py.Dataset) and table.shape[0] >= frame_ok.size:
            frame_ok &= _chunks_within(table, end)[:frame_ok.size]
        else:
            frame_ok[:] = False
    intact = set()
    for i, (a, c) in spans.items():
        if c == 0 or (a + c <= frame_ok.size and frame_ok[a:a + c].all()):
            intact.add(i)
    return Readable(rows, spans, intact, n)


def _read_rows(ds: h5py.Dataset | None, rows: np.ndarray) -> np.ndarray | None:
    """Rows ``rows`` of a dataset (only their chunks are read), or None if unreadable."""
    if ds is None:
        return None
    try:
        return ds[rows] if rows.size else np.zeros(0, dtype=ds.dtype)
    except (OSError, RuntimeError, ValueError, TypeError):
        return None


def row_count(f: h5py.File) -> int:
    """Rows the points table says it holds (its shape is in the object header)."""
    try:
        return int(f["entry/points/index"].shape[0])
    except (KeyError, OSError, RuntimeError, ValueError):
        return int(f["entry"].attrs.get("n_points", 0))


def _points_text(indices: Iterable[int]) -> str:
    idx = sorted(int(i) for i in indices)
    if len(idx) > 12:
        return ", ".join(map(str, idx[:10])) + f" … ({len(idx)} in all)"
    return ", ".join(map(str, idx))


#: What ``scatterlab resume`` does with a damaged run file that has no journal but whose
#: run record (plan, bench profile) reads (:func:`instrument.run.recovery.salvage`).
SALVAGE_WORDS = ("`scatterlab resume {path}` makes a new run file of the readable points "
                 "(the damaged one is kept beside it as .corrupt) and measures the rest")


def unrecoverable_message(path: Path, cut: str) -> str:
    """The one sentence for a damaged file without a journal whose run record cannot be
    read: every command (the analyses through :func:`inspect_run_file`, ``resume`` through
    :func:`instrument.run.recovery.salvage`) says it in these words."""
    return (f"{path} is a damaged HDF5 file ({cut}) with no run journal next to it, and its "
            "run record (plan and bench profile) cannot be read: nothing in it can be "
            "recovered")


def _damaged(path: Path, size: int, recorded: int, has_journal: bool) -> FileState:
    """A file HDF5 refuses: read what lies before the cut, say what it is."""
    cut = (f"cut short: {size} of its {recorded} bytes on disk" if recorded > size
           else "its HDF5 structure is damaged")
    try:
        with open_damaged(path, recorded) as (f, end):
            entry = f["entry"]
            if "run_id" not in entry.attrs:
                raise KeyError("run_id")
            kind = entry.attrs.get("plan_kind", "")
            kind = kind.decode() if isinstance(kind, bytes) else str(kind)
            n_planned = int(entry.attrs.get("n_planned", 0))
            try:
                found = readable_points(f, end)
                rows, intact, n_rows = found.rows, found.intact, found.n_rows
            except (KeyError, OSError, RuntimeError, ValueError):
                rows, intact, n_rows = {}, set(), row_count(f)
            if not has_journal:
                header_from_file(f)  # what a salvage needs first (recovery.salvage)
    except (KeyError, OSError, RuntimeError, ValueError):
        if has_journal:
            return FileState(path, "damaged", (
                f"{path} is a damaged scatterlab run file ({cut}); `scatterlab resume "
                f"{path}` rebuilds it from its journal"), True, True, size, recorded)
        return FileState(path, "damaged", unrecoverable_message(path, cut), False, False,
                         size, recorded)
    readable = tuple(sorted(intact))
    lost = tuple(sorted(set(rows) - intact))
    parts = [f"points {_points_text(readable)} readable" if readable
             else "no point readable"]
    if lost:
        parts.append(f"the frames of points {_points_text(lost)} lost")
    if n_rows > len(rows):
        parts.append(f"{n_rows - len(rows)} point record(s) cut off")
    if n_planned > n_rows:
        parts.append(f"{n_planned - n_rows} planned point(s) not measured yet")
    what = "; ".join(parts)
    if has_journal:
        msg = (f"{path} is a damaged scatterlab run file ({cut}; {what}); `scatterlab "
               f"resume {path}` repairs it from its journal")
    else:
        msg = (f"{path} is a damaged scatterlab run file ({cut}) with no journal to rebuild "
               f"it from; {what} (of {n_planned} planned); {SALVAGE_WORDS.format(path=path)}")
    return FileState(path, "damaged", msg, True, has_journal, size, recorded, n_planned,
                     readable, lost, kind)


def inspect_run_file(path: str | Path) -> FileState:
    """Open ``path`` read-only and say what it is (see :class:`FileState`)."""
    path = Path(path)
    has_journal = journal_of(path).is_file()
    if path.is_dir():
        return FileState(path, "folder", f"{path} is a folder, not a run file; give the "
                         "run's .h5 file")
    if not path.exists():
        return FileState(path, "missing", f"{path}: no such run file")
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError as err:
        return FileState(path, "missing", f"{path} cannot be read ({err.strerror or err})")
    if head != b"\x89HDF\r\n\x1a\n":
        # A destroyed file with its journal is still a run: resume rebuilds it.
        if has_journal and _journal_has_header(journal_of(path)):
            return FileState(path, "damaged", (
                f"{path} is a damaged scatterlab run file (its HDF5 header is gone); "
                f"`scatterlab resume {path}` rebuilds it from its journal"), True, True, size)
        return FileState(path, "not_hdf5", f"{path} is not a scatterlab run file (not an "
                         "HDF5 file)")
    try:
        with h5py.File(path, "r") as f:
            entry = f.get("entry")
            if not isinstance(entry, h5py.Group) or "run_id" not in entry.attrs:
                return FileState(path, "not_run", f"{path} is an HDF5 file but not a "
                                 "scatterlab run file (no /entry with a run id)")
            kind = entry.attrs.get("plan_kind", "")
            kind = kind.decode() if isinstance(kind, bytes) else str(kind)
            status = entry.attrs.get("status", "")
            status = status.decode() if isinstance(status, bytes) else str(status)
    except OSError as err:
        text = str(err)
        if is_lock_refusal(text):
            return FileState(path, "busy", f"{path} is open for writing in another program "
                             "(a run still going?); analyse it when the run has ended",
                             True, has_journal, size)
        lengths = recorded_length(text)
        recorded = lengths[1] if lengths else size
        return _damaged(path, size, recorded, has_journal)
    return FileState(path, "ok", "", True, has_journal, size, size, plan_kind=kind) \
        if status != "running" or not held_by_this_process(path) else \
        FileState(path, "busy", f"{path} is still being written by a run; analyse it when "
                  "the run has ended", True, has_journal, size, size, plan_kind=kind)


def held_by_this_process(path: Path) -> bool:
    """True while this process holds ``path`` open for writing (an engine in this
    process: HDF5 lets a process reopen its own file, so only h5py's open file ids tell;
    another process is found by its lock refusing an open)."""
    for fid in h5py.h5f.get_obj_ids(types=h5py.h5f.OBJ_FILE):
        try:
            same = Path(fid.name.decode()).resolve() == path.resolve()
        except (OSError, ValueError):
            continue
        if same and fid.get_intent() & h5py.h5f.ACC_RDWR:
            return True
    return False


def _journal_has_header(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            first = fh.readline(1 << 20)
    except OSError:
        return False
    return b'"t":"header"' in first
