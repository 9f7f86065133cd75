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
4. skips the run if its results file says it was analysed with the same options
   (:func:`instrument.run.results.already_done`), unless ``force``;
5. runs the analysis (:mod:`.analyses`); any exception becomes a failed outcome naming
   its cause, so one bad run never stops the batch;
6. writes the results file atomically (:func:`instrument.run.results.write_results_file`:
   temporary file, fsync, rename): a task killed at any moment leaves the previous results
   file or the new one, never a torn one.
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

import h5py

from instrument.batch.analyses import AnalysisFailed, get_analysis
from instrument.run.results import (
    RESULTS_NAME,
    already_done,
    put_json,
    results_dir,
    results_path,
    write_results_file,
)
from instrument.run.runfile import as_text, read_summary

__all__ = ["LOCK_NAME", "STATUSES", "Outcome", "RunBusy", "record_options", "run_lock",
           "run_serial", "run_task"]

#: What became of a task.
STATUSES = ("analysed", "skipped", "not applicable", "failed")
#: The lock file in the run's folder (``DIR/RUN/``).
LOCK_NAME = ".lock"
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
    """Delete temporary results files left by a task killed while writing (called with the
    run's lock held, so no live writer owns one)."""
    if folder.is_dir():
        for tmp in folder.glob(f".{RESULTS_NAME}.*.tmp"):
            with contextlib.suppress(OSError):
                tmp.unlink()


def _previous(run_path: str | Path, pipeline: str) -> dict[str, Any]:
    """The summary row an earlier analysis stored in the results file ({} if none)."""
    try:
        with h5py.File(results_path(run_path, pipeline), "r") as f:
            g = f.get("entry/analysis/summary_json")
            return {} if g is None else json.loads(as_text(g[()]))
    except (OSError, ValueError):
        return {}


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
            _remove_stale_temporaries(results_dir(run, spec.pipeline))
            if not force and already_done(run, spec.pipeline, run_id=s.run_id,
                                          options=record):
                prev = _previous(run, spec.pipeline)
                return outcome("skipped", result=prev.get("result", ""),
                               values=prev.get("values"), flags=tuple(prev.get("flags", ())),
                               cause="already analysed with the same options (--force "
                                     "analyses it again)")
            out_dir = results_dir(run, spec.pipeline) if report else None
            if out_dir is not None:
                out_dir.mkdir(parents=True, exist_ok=True)
            done = spec.adapter(run, options, out_dir=out_dir)
            flags = list(done.flags)
            if s.status != "finished":
                flags.append(f"run status {s.status!r}: not every planned point was measured")
            row = {**done.row(), "flags": flags, **ident}
            with write_results_file(run, spec.pipeline, run_id=s.run_id,
                                    program=f"scatterlab batch {analysis}",
                                    options=record) as g:
                put_json(g, "summary_json", row)
                put_json(g, "results_json", done.details)
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
