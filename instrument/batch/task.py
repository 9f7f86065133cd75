"""One analysis of one run, as a batch task: :func:`run_task` → :class:`Outcome`.

A task is self-contained, so it runs the same in this process or in a Dask worker on
another machine: it gets the run's *path* (never an open file), opens the file itself, and
returns plain data. In order, it

1. reads what the run is (id, sample, plan kind, status) read-only; a file that is not a
   readable run, or a run still being written, is a failed task;
2. skips a run of a plan kind the analysis does not take ("not applicable");
3. takes the run's lock (``DIR/RUN/.lock``, an exclusive ``flock``), so no two analyses of
   one run — from this batch, another batch or a retry — run at once; the kernel drops it
   when the process dies, so a killed worker leaves no stale lock;
4. skips the run if its batch summary (``DIR/RUN/<pipeline>/batch_summary.json``) says it
   was analysed with the same options and the results file is there, unless ``force``;
5. runs the analysis (:mod:`.analyses`): the pipeline writes the results file itself,
   exactly as the single-run command does (ADR 0013, ADR 0070 "One writer per file"),
   atomically (:func:`instrument.run.results.write_results_file`: temporary file, fsync,
   rename); any exception becomes a failed outcome naming its cause, so one bad run never
   stops the batch;
6. writes the run's summary row next to the results file, atomically too: a task killed at
   any moment leaves the previous files or the new ones, never a torn one (and a results
   file without its summary row is analysed again).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from instrument.batch.analyses import AnalysisFailed, get_analysis
from instrument.run.results import (
    RESULTS_NAME,
    options_fingerprint,
    results_dir,
    results_path,
)
from instrument.run.runfile import read_summary

__all__ = ["LOCK_NAME", "STATUSES", "SUMMARY_NAME", "Outcome", "RunBusy", "record_options",
           "run_lock", "run_serial", "run_task"]

#: What became of a task.
STATUSES = ("analysed", "skipped", "not applicable", "failed")
#: The lock file in the run's folder (``DIR/RUN/.lock``).
LOCK_NAME = ".lock"
#: The batch's summary row of a run, next to the pipeline's results file.
SUMMARY_NAME = "batch_summary.json"
#: Seconds a task waits for another analysis of the same run to finish.
LOCK_WAIT_S = 600.0


class RunBusy(RuntimeError):
    """Another analysis held the run's lock for longer than the task would wait."""


@dataclass(frozen=True)
class Outcome:
    """What one task did to one run (plain data; one line of the summary table).

    Attributes
    ----------
    run : str
        The run file's path as given.
    analysis : str
    status : str
        One of :data:`STATUSES`.
    run_id, sample, kind : str
        From the run file ("" when it could not be read).
    result : str
        The answer in one line ("" when there is none).
    values : dict
        The answer as named columns (:class:`instrument.batch.analyses.Analysed`).
    flags : tuple of str
    cause : str
        Why it failed, was skipped or not applicable ("" when analysed).
    seconds : float
        Wall time of the task.
    cpu_seconds : float
        CPU time of the task's thread (below ``seconds`` when the process waited for a
        core or for the disk).
    worker : str
        ``host:pid`` of the process that ran it.
    detail : str
        The traceback of a failure (its last lines), for the HTML table.
    """

    run: str
    analysis: str
    status: str
    run_id: str = ""
    sample: str = ""
    kind: str = ""
    result: str = ""
    values: Mapping[str, Any] | None = None
    flags: tuple[str, ...] = ()
    cause: str = ""
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    worker: str = ""
    detail: str = ""

    @property
    def ok(self) -> bool:
        return self.status != "failed"


def record_options(analysis: str, options: Mapping[str, Any], report: bool) -> dict[str, Any]:
    """What the results file's fingerprint covers: the analysis, its options, and whether
    the report and figures were made."""
    return {"analysis": analysis, "options": dict(options), "report": bool(report)}


@contextlib.contextmanager
def run_lock(run_path: str | Path, *, wait_s: float = LOCK_WAIT_S,
             poll_s: float = 0.2) -> Iterator[Path]:
    """Hold the run's exclusive lock (``DIR/RUN/.lock``) for the block.

    Raises
    ------
    RunBusy
        Another process held it for ``wait_s``.
    """
    folder = results_dir(run_path, "fit").parent
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    raise RunBusy(f"another analysis of {run_path} held its lock {path} for "
                                  f"{wait_s:g} s") from None
                time.sleep(poll_s)
        try:
            yield path
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _cause(err: BaseException, run: str) -> str:
    """The failure in words: what kind of problem, and its message."""
    if isinstance(err, AnalysisFailed):
        return f"not usable: {err}"
    if isinstance(err, FileNotFoundError):
        return f"no such file: {err.filename or run}"
    if isinstance(err, OSError):
        # h5py's OSError for a non-HDF5, truncated or locked file does not always name it
        return f"cannot read {run} as a scatterlab run file (HDF5): {err}"
    if isinstance(err, KeyError):
        return f"{run} lacks what the analysis needs: {err.args[0] if err.args else err}"
    if isinstance(err, ValueError) and str(err):
        return str(err)  # the pipelines' ValueErrors say what is wrong and what to change
    return f"{type(err).__name__}: {err}" if str(err) else type(err).__name__


def _detail(err: BaseException, limit: int = 4000) -> str:
    """The end of the traceback (where it failed), for a failure nobody expected."""
    text = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    return text[-limit:]


def _remove_stale_temporaries(folder: Path) -> None:
    """Delete temporary files left by a task killed while writing (called with the run's
    lock held, so no live writer owns one)."""
    if folder.is_dir():
        for pattern in (f".{RESULTS_NAME}.*.tmp", f".{SUMMARY_NAME}.*.tmp"):
            for tmp in folder.glob(pattern):
                with contextlib.suppress(OSError):
                    tmp.unlink()


def _write_summary(folder: Path, run_id: str, record: Mapping[str, Any],
                   row: Mapping[str, Any]) -> None:
    """The summary row with the run id and the options' fingerprint, written atomically
    (temporary file, fsync, rename)."""
    final = folder / SUMMARY_NAME
    tmp = folder / f".{SUMMARY_NAME}.{os.getpid()}.tmp"
    text = json.dumps({"run_id": run_id, "options_sha256": options_fingerprint(record),
                       "options": record, "row": row}, default=str, allow_nan=True)
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, final)


def _previous(run_path: str | Path, pipeline: str, run_id: str,
              record: Mapping[str, Any]) -> dict[str, Any] | None:
    """The summary row an earlier task stored for the same run and options, when its
    results file is still there (None otherwise: analyse again)."""
    folder = results_dir(run_path, pipeline)
    if not results_path(run_path, pipeline).is_file():
        return None
    try:
        stored = json.loads((folder / SUMMARY_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if (not isinstance(stored, dict) or stored.get("run_id") != run_id
            or stored.get("options_sha256") != options_fingerprint(record)):
        return None
    row = stored.get("row")
    return row if isinstance(row, dict) else None


def run_task(analysis: str, run_path: str | Path, options: Mapping[str, Any], *,
             report: bool = True, force: bool = False,
             lock_wait_s: float = LOCK_WAIT_S) -> Outcome:
    """Analyse one run (module docstring); never raises for a problem of the run.

    ``report``: make the analysis's report and figures in ``DIR/RUN/<pipeline>/``.
    ``lock_wait_s``: how long to wait for another analysis of the run to finish.
    """
    t0 = time.perf_counter()
    c0 = time.thread_time()
    spec = get_analysis(analysis)
    run = str(run_path)
    ident: dict[str, str] = {}

    def outcome(status: str, **kw: Any) -> Outcome:
        return Outcome(run, analysis, status, seconds=time.perf_counter() - t0,
                       cpu_seconds=time.thread_time() - c0, worker=_worker_name(), **ident,
                       **kw)

    try:
        s = read_summary(run)
        ident = {"run_id": s.run_id, "sample": s.sample_name, "kind": s.plan_kind}
        if s.plan_kind not in spec.kinds:
            return outcome("not applicable", cause=f"a {s.plan_kind or 'unknown'} run; "
                           f"{analysis} takes {', '.join(spec.kinds)}")
        if s.status == "running":
            return outcome("failed", cause="the run is still being written (status "
                           "'running'); analyse it when it ends, or resume it if its "
                           "process was killed")
        record = record_options(analysis, options, report)
        with run_lock(run, wait_s=lock_wait_s):
            folder = results_dir(run, spec.pipeline)
            _remove_stale_temporaries(folder)
            prev = None if force else _previous(run, spec.pipeline, s.run_id, record)
            if prev is not None:
                return outcome("skipped", result=prev.get("result", ""),
                               values=prev.get("values"), flags=tuple(prev.get("flags", ())),
                               cause="already analysed with the same options (--force "
                                     "analyses it again)")
            folder.mkdir(parents=True, exist_ok=True)
            done = spec.adapter(run, options, folder=folder, report=report)
            flags = list(done.flags)
            if s.status != "finished":
                flags.append(f"run status {s.status!r}: not every planned point was measured")
            row = {**done.row(), "flags": flags, **ident}
            _write_summary(folder, s.run_id, record, row)
        return outcome("analysed", result=done.result, values=done.values, flags=tuple(flags))
    except Exception as err:  # one run's problem is reported, the batch goes on
        row = err.row if isinstance(err, AnalysisFailed) and err.row else {}
        return outcome("failed", result=row.get("result", ""), values=row.get("values"),
                       flags=tuple(row.get("flags", ())), cause=_cause(err, run),
                       detail=_detail(err))


def run_serial(analysis: str, runs: Sequence[str | Path], options: Mapping[str, Any], *,
               report: bool = True, force: bool = False,
               on_outcome: Callable[[Outcome], None] | None = None) -> list[Outcome]:
    """Every run analysed one after the other in this process (no Dask)."""
    out = []
    for run in runs:
        o = run_task(analysis, run, options, report=report, force=force)
        out.append(o)
        if on_outcome is not None:
            on_outcome(o)
    return out
