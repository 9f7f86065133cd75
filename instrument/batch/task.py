"""One analysis of one run, as a batch task: :func:`run_task` → :class:`Outcome`.

A task is self-contained, so it runs the same in this process or in a Dask worker on
another machine: it gets the run's *path* (never an open file), opens the file itself, and
returns plain data. In order, it

1. reads what the run is (id, sample, plan kind, status) read-only; a file that is not a
   readable run, or a run still being written, is a failed task;
2. skips a run of a plan kind the analysis does not take ("not applicable");
3. takes the run's lock (:func:`instrument.run.results.run_lock`, an exclusive ``flock``
   on ``DIR/RUN/.lock``, the lock the single-run commands take too), so no two analyses
   of one run — from this batch, another batch, a retry or ``scatterlab fit`` — write at
   once; the kernel drops it when the process dies, so a killed worker leaves no stale
   lock, and the task clears the temporary files a killed writer left;
4. skips the run if its results file says it was analysed with the same options
   (:func:`instrument.run.results.already_done` with exactly the options the pipeline
   records, so a run analysed by ``scatterlab fit`` counts too) and the row kept next to
   it (:func:`instrument.batch.analyses.keep_row`) says the answer was usable and the
   report was made if one is asked for; unless ``force``;
5. runs the analysis (:mod:`.analyses`): the pipeline writes ``DIR/RUN/<pipeline>/
   results.h5`` itself, atomically (temporary file, fsync, rename), and the report or
   figures when asked; then the task keeps the run's summary row next to it. Any
   exception becomes a failed outcome naming its cause, so one bad run never stops the
   batch.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from instrument.batch.analyses import AnalysisFailed, get_analysis, keep_row
from instrument.run.results import (
    LOCK_WAIT_S,
    already_done,
    read_record,
    remove_stale_temporaries,
    results_dir,
    run_lock,
)
from instrument.run.runfile import read_summary

__all__ = ["STATUSES", "Outcome", "run_serial", "run_task"]

#: What became of a task.
STATUSES = ("analysed", "skipped", "not applicable", "failed")


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
    redone : int
        How many times the task was given to another worker because the worker process
        analysing it died (killed, crashed, out of memory); 0 when it never was.
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
    redone: int = 0

    @property
    def ok(self) -> bool:
        return self.status != "failed"


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


def _done_before(spec_name: str, run: str, pipeline: str, run_id: str,
                 record: Mapping[str, Any], report: bool) -> dict[str, Any] | None:
    """The row kept by an earlier analysis that makes this one unnecessary, or None: the
    results file was made with the same options, and its row says the answer was usable
    and the report was made if one is wanted now."""
    if not already_done(run, pipeline, run_id=run_id, options=record):
        return None
    row = read_record(run, pipeline)
    if (row is None or row.get("analysis") != spec_name or row.get("status") != "analysed"
            or (report and not row.get("report"))):
        return None
    return row


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
    ident: dict[str, Any] = {}  # run_id, sample, kind: strings

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
        with run_lock(run, wait_s=lock_wait_s, what=f"scatterlab batch {analysis}"):
            folder = results_dir(run, spec.pipeline)
            remove_stale_temporaries(folder)
            if not force:
                prev = _done_before(analysis, run, spec.pipeline, s.run_id,
                                    spec.record(run, options), report)
                if prev is not None:
                    return outcome("skipped", result=prev.get("result", ""),
                                   values=prev.get("values"),
                                   flags=tuple(prev.get("flags", ())),
                                   cause="already analysed with the same options (--force "
                                         "analyses it again)")
            kept = keep_row(run, analysis,
                            lambda: spec.adapter(run, options, folder=folder, report=report),
                            report=report)
        if kept["status"] != "analysed":
            return outcome("failed", result=kept["result"], values=kept["values"],
                           flags=tuple(kept["flags"]), cause=kept["cause"])
        return outcome("analysed", result=kept["result"], values=kept["values"],
                       flags=tuple(kept["flags"]))
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
