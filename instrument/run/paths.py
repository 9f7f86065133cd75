"""Where things go: the runs folder, and each analysis's outputs next to its run (ADR 0013).

For a run file ``DIR/RUN.h5`` every output of an analysis goes under ``DIR/RUN/<pipeline>/``
(figures, the report, ``results.h5``), unless the user names another folder. This module
imports nothing heavy, so the command line can print these defaults without loading HDF5.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["DEFAULT_RUNS_DIR", "PIPELINES", "RESULTS_NAME", "results_dir", "results_path",
           "run_folder", "writer_lock_path"]

#: Where runs (and their catalog) go unless ``--out`` says otherwise.
DEFAULT_RUNS_DIR = Path("runs")
#: The pipelines, by the name of their folder next to the run.
PIPELINES = ("fit", "lightfield", "spheres")
#: The results file in each pipeline's folder.
RESULTS_NAME = "results.h5"


def run_folder(run_path: str | Path) -> Path:
    """``DIR/RUN/`` for the run file ``DIR/RUN.h5``: its analyses' folders and its lock
    (not created here)."""
    p = Path(run_path)
    return p.parent / p.stem


def results_dir(run_path: str | Path, pipeline: str) -> Path:
    """``DIR/RUN/<pipeline>/`` for the run file ``DIR/RUN.h5`` (not created here)."""
    if pipeline not in PIPELINES:
        raise ValueError(f"unknown pipeline {pipeline!r}; one of {', '.join(PIPELINES)}")
    return run_folder(run_path) / pipeline


def results_path(run_path: str | Path, pipeline: str, folder: str | Path | None = None
                 ) -> Path:
    """``DIR/RUN/<pipeline>/results.h5``, or ``results.h5`` in ``folder`` when given."""
    if folder is not None:
        return Path(folder) / RESULTS_NAME
    return results_dir(run_path, pipeline) / RESULTS_NAME


def writer_lock_path(run_path: str | Path) -> Path:
    """``DIR/RUN.h5.lock``, beside the run's journal: held by the one process that
    continues the run (``scatterlab resume``), so a second one is told who it is."""
    p = Path(run_path)
    return p.with_name(p.name + ".lock")

