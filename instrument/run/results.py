"""Where analysis results go, and how they are written (ADR 0013).

Every output of an analysis of ``DIR/RUN.h5`` goes under ``DIR/RUN/<pipeline>/``
(:func:`results_dir`): its figures, its report and ``results.h5`` (:func:`results_path`), a
NeXus-style file whose ``/entry`` names the run, the program and a fingerprint of the
options (:func:`options_fingerprint`), and holds the analysis groups under
``/entry/analysis``. :func:`write_results_file` writes it atomically (temporary file, fsync,
rename), so a killed analysis leaves the previous results or none; :func:`already_done`
tells whether a run was analysed with the same options. The raw run file is written only
when the user asks (:func:`open_for_results`).

One writer at a time: every analysis that writes a run's outputs holds the run's lock
(:func:`run_lock`, an exclusive ``flock`` on ``DIR/RUN/.lock``) while it analyses and
writes, whether it is a single-run command or a batch task on a cluster; under it,
:func:`remove_stale_temporaries` clears what a killed writer left. Next to ``results.h5``
an analysis may keep a small JSON record (:func:`write_record`, atomic like the results
file; the batch summary row of the run, ADR 0070), trusted only while it names the run id
and options fingerprint of the results file beside it (:func:`read_record`).

The group helpers are the one way the pipelines build their groups: a group is replaced
whole (writing again supersedes an earlier analysis), text goes in as variable-length
UTF-8 strings, and plain-data results as JSON that any HDF5 reader can parse.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from instrument.run.locks import LockHeld, hold
from instrument.run.paths import PIPELINES, RESULTS_NAME, results_dir, results_path, run_folder
from instrument.run.runfile import as_text
from instrument.version import software_version

__all__ = [
    "LOCK_NAME",
    "LOCK_WAIT_S",
    "PIPELINES",
    "RECORD_NAME",
    "RESULTS_NAME",
    "RunBusy",
    "RunStillRunning",
    "already_done",
    "analysis_group",
    "jsonable",
    "open_for_results",
    "options_fingerprint",
    "put",
    "put_json",
    "read_record",
    "read_results_attrs",
    "remove_stale_temporaries",
    "replace_group",
    "results_dir",
    "results_path",
    "run_lock",
    "write_record",
    "write_results_file",
]

#: The lock file in the run's folder (``DIR/RUN/``), or in the folder an analysis was told
#: to write into.
LOCK_NAME = ".lock"
#: Seconds an analysis waits for another analysis of the same run to finish.
LOCK_WAIT_S = 600.0
#: The analysis record kept next to ``results.h5`` (:func:`write_record`).
RECORD_NAME = "batch_summary.json"

class RunStillRunning(RuntimeError):
    """The run file is still being written by a run; analyse it when the run ends."""


class RunBusy(RuntimeError):
    """Another analysis held the run's lock for longer than this one would wait."""


def replace_group(parent: h5py.Group, name: str, nx_class: str) -> h5py.Group:
    """A new, empty group ``name`` of NeXus class ``nx_class`` (an existing one is deleted)."""
    if name in parent:
        del parent[name]
    g = parent.create_group(name)
    g.attrs["NX_class"] = nx_class
    return g


def analysis_group(f: h5py.File, name: str | None = None) -> h5py.Group:
    """``/entry/analysis`` (created if missing), or its sub-group ``name`` (an NXprocess,
    created if missing, kept if present)."""
    entry = f["entry"]
    if "analysis" not in entry:
        entry.create_group("analysis").attrs["NX_class"] = "NXcollection"
    g = entry["analysis"]
    if name is None:
        return g
    if name not in g:
        g.create_group(name).attrs["NX_class"] = "NXprocess"
    return g[name]


@contextlib.contextmanager
def open_for_results(path: str | Path) -> Iterator[h5py.File]:
    """The run file open for writing results; refused while a run is still writing it."""
    with h5py.File(path, "r+") as f:
        if as_text(f["entry"].attrs.get("status", "")) == "running":
            raise RunStillRunning(f"{path} is still being written; analyse it when the run "
                                  "ends")
        yield f


def jsonable(x: Any) -> Any:
    """``json.dumps`` default for numpy values (anything else becomes its ``str``)."""
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return str(x)


def put(g: h5py.Group, name: str, value: Any) -> h5py.Dataset:
    """A dataset ``name``: text as a UTF-8 string, anything else as an array."""
    if isinstance(value, str):
        return g.create_dataset(name, data=value, dtype=h5py.string_dtype())
    return g.create_dataset(name, data=np.asarray(value))


def put_json(g: h5py.Group, name: str, value: Any) -> h5py.Dataset:
    """``value`` (plain data, numpy allowed) as JSON text in dataset ``name``."""
    return put(g, name, json.dumps(value, default=jsonable))


# ------------------------------------------------------------------------------ where
def options_fingerprint(options: Mapping[str, Any]) -> str:
    """SHA-256 of the options as canonical JSON (sorted keys; paths and numpy values as
    text and lists): equal options give equal fingerprints, across processes and machines."""
    text = json.dumps(dict(options), sort_keys=True, default=jsonable, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@contextlib.contextmanager
def write_results_file(run_path: str | Path, pipeline: str, *, run_id: str, program: str,
                       options: Mapping[str, Any], folder: str | Path | None = None
                       ) -> Iterator[h5py.Group]:
    """Write ``results.h5`` of ``pipeline`` for a run; yields its ``/entry/analysis`` group.

    The file goes to :func:`results_path` (``folder``, when given, instead of the run's
    own). It is built under a temporary name in the same folder, flushed to disk and
    renamed over the old one only when the block ends without an exception, so readers see
    the previous results or the new ones, never a mixture.
    """
    final = results_path(run_path, pipeline, folder)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.with_name(f".{final.name}.{os.getpid()}.tmp")
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["default"] = "entry"
            f.attrs["creator"] = "scatterlab"
            entry = f.create_group("entry")
            entry.attrs["NX_class"] = "NXentry"
            entry.attrs["run_id"] = run_id
            entry.attrs["run_file"] = os.path.relpath(Path(run_path).resolve(),
                                                      final.parent.resolve())
            entry.attrs["program"] = program
            entry.attrs["software_version"] = software_version()
            entry.attrs["date"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
            entry.attrs["options_json"] = json.dumps(dict(options), sort_keys=True,
                                                     default=jsonable)
            entry.attrs["options_sha256"] = options_fingerprint(options)
            yield analysis_group(f)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, final)
        with contextlib.suppress(OSError):  # the rename itself durable (POSIX folders)
            fd = os.open(final.parent, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def read_results_attrs(run_path: str | Path, pipeline: str,
                       folder: str | Path | None = None) -> dict[str, Any] | None:
    """The ``/entry`` attributes of a run's results file, or ``None`` if it has none."""
    path = results_path(run_path, pipeline, folder)
    if not path.is_file():
        return None
    try:
        with h5py.File(path, "r") as f:
            return {k: (as_text(v) if isinstance(v, bytes | str) else v)
                    for k, v in f["entry"].attrs.items()}
    except (OSError, KeyError):
        return None  # unreadable or foreign: not a result to rely on


def already_done(run_path: str | Path, pipeline: str, *, run_id: str,
                 options: Mapping[str, Any], folder: str | Path | None = None) -> bool:
    """True when the run's ``results.h5`` of ``pipeline`` names ``run_id`` and was made with
    the same options (ADR 0013: a rerun skips it unless forced). The options are those
    the pipeline records (``fit_options``, ``lightfield_options``, ``sphere_options`` of the
    pipelines)."""
    attrs = read_results_attrs(run_path, pipeline, folder)
    return (attrs is not None and attrs.get("run_id") == run_id
            and attrs.get("options_sha256") == options_fingerprint(options))


# ------------------------------------------------------------------------------ one writer
@contextlib.contextmanager
def run_lock(run_path: str | Path, *, folder: str | Path | None = None,
             wait_s: float = LOCK_WAIT_S, poll_s: float = 0.2, what: str = "an analysis",
             on_wait: Callable[[str], None] | None = None) -> Iterator[Path]:
    """Hold the run's exclusive lock for the block: ``DIR/RUN/.lock`` for the run file
    ``DIR/RUN.h5``, or ``.lock`` in ``folder`` (an analysis told to write elsewhere, e.g. a
    read-only run folder, locks what it writes).

    It is an ``flock`` on a descriptor of its own (:func:`instrument.run.locks.hold`): it
    excludes other processes and other threads of this one (and a nested call in the same
    thread would wait for itself, so the pipelines do not take it; the commands and batch
    tasks that call them do). The kernel drops it when the holder's process dies, so a
    killed analysis leaves no stale lock. The holder writes its process id and ``what``
    it does into the lock file; when the lock is taken, ``on_wait`` is told that (``process
    123: scatterlab fit RUN.h5``) at once, before the wait of up to ``wait_s`` seconds.

    Raises
    ------
    RunBusy
        Another analysis held it for ``wait_s``.
    """
    where = Path(folder) if folder is not None else run_folder(run_path)
    where.mkdir(parents=True, exist_ok=True)
    path = where / LOCK_NAME
    try:
        with hold(path, what, wait_s=wait_s, poll_s=poll_s, on_wait=on_wait):
            yield path
    except LockHeld as err:
        if err.path != path:
            raise
        raise RunBusy(f"another analysis of {run_path} ({err.holder}) held its lock {path} "
                      f"for {wait_s:g} s; run this one again when it has ended") from None


def remove_stale_temporaries(folder: str | Path) -> None:
    """Delete the temporary files a writer killed mid-write left in ``folder`` (results
    files and records). Call it holding the run's lock, so no live writer owns one."""
    folder = Path(folder)
    if folder.is_dir():
        for name in (RESULTS_NAME, RECORD_NAME):
            for tmp in folder.glob(f".{name}.*.tmp"):
                with contextlib.suppress(OSError):
                    tmp.unlink()


# ------------------------------------------------------------------------------ the record
def write_record(run_path: str | Path, pipeline: str, record: Mapping[str, Any], *,
                 folder: str | Path | None = None) -> Path:
    """Keep ``record`` (plain data) as JSON next to the pipeline's ``results.h5``, tied to
    it: the file also holds the results file's ``run_id`` and ``options_sha256``, so
    :func:`read_record` returns it only while that results file stands. Written like the
    results file (temporary name, fsync, rename). Returns its path.

    Raises
    ------
    FileNotFoundError
        There is no results file to tie it to.
    """
    attrs = read_results_attrs(run_path, pipeline, folder)
    final = results_path(run_path, pipeline, folder).with_name(RECORD_NAME)
    if attrs is None:
        raise FileNotFoundError(f"no results file {final.with_name(RESULTS_NAME)} to keep a "
                                "record of")
    body = {**dict(record), "run_id": attrs.get("run_id"),
            "options_sha256": attrs.get("options_sha256")}
    tmp = final.with_name(f".{final.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(body, fh, default=jsonable, sort_keys=True)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return final


def read_record(run_path: str | Path, pipeline: str,
                folder: str | Path | None = None) -> dict[str, Any] | None:
    """The record kept next to the pipeline's results file, or ``None`` when there is none
    or it belongs to another results file than the one there now (another run id or other
    options: written before the analysis that replaced it, or never completed)."""
    path = results_path(run_path, pipeline, folder).with_name(RECORD_NAME)
    attrs = read_results_attrs(run_path, pipeline, folder)
    if attrs is None or not path.is_file():
        return None
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(body, dict) or (body.get("run_id"), body.get("options_sha256")) != (
            attrs.get("run_id"), attrs.get("options_sha256")):
        return None
    return body
