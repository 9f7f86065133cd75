"""``scatterlab batch ANALYSIS RUN...``: one analysis over many runs, on a Dask cluster.

ANALYSIS is ``fit``, ``reconstruct``, ``locate`` or ``spheres``, with the options of the
single-run command of that name (the same option definitions; ``fit``'s polarimetric
options — calibration, pBRDF start values, parameters held — go to the polarimetric runs
only, and a calibration that cannot be used with one of them stops the batch before it
analyses anything). Runs are named by files,
folders, globs or a catalog query. By default a local cluster of worker processes (one per
core, one BLAS thread each) analyses them; ``--scheduler`` uses an existing cluster,
``--workers 0`` analyses them here one after another without Dask. Each run's outputs go
to ``DIR/RUN/<pipeline>/`` next to its file; a summary table (CSV and HTML) of all runs is
written at the end. A run that fails is reported with its cause and the others go on; a
run already analysed with the same options is skipped unless ``--force``.

Exit status: 0 every run analysed, skipped or not applicable; 1 some failed; 2 on errors in
the command itself; 130 interrupted (finished runs keep their results: the same command
continues with the rest).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from instrument.cli import fit, locate, reconstruct, spheres
from instrument.cli._cluster import ClusterUnavailable, add_cluster_options, open_cluster
from instrument.cli._format import fmt_s
from instrument.run.paths import DEFAULT_RUNS_DIR

if TYPE_CHECKING:
    from instrument.batch.task import Outcome

HELP = "analyse many runs at once, on this machine or a Dask cluster"

#: name → (help, the single-run command's option adder, its plain-options function)
_ANALYSES: dict[str, tuple[str, Callable[..., Any], Callable[..., Any]]] = {
    "fit": ("BRDF reduction, model fits and selection of each run",
            fit.add_fit_options, fit.fit_options),
    "reconstruct": ("the hidden object's light field of each light-field run",
                    reconstruct.add_reconstruction_options,
                    reconstruct.reconstruction_options),
    "locate": ("the hidden objects of each light-field run",
               locate.add_locate_options, locate.locate_options),
    "spheres": ("SH relighting and consistency of each sphere capture",
                spheres.add_sphere_options, spheres.sphere_options),
}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("batch", help="analyse many runs at once, on this machine or a Dask "
                       "cluster (fit, reconstruct, locate, spheres)",
                       description="One analysis (fit, reconstruct, locate or spheres, with "
                       "the options of the single-run command) over many runs named by files, "
                       "folders, globs or a catalog query; on a local cluster of worker "
                       "processes by default, on an existing Dask cluster with --scheduler, "
                       "or here one after another with --workers 0. Outputs go next to each "
                       "run (DIR/RUN/<pipeline>/), a summary table (CSV, HTML) at the end.")
    analyses = p.add_subparsers(dest="analysis", metavar="ANALYSIS")
    analyses.required = True
    for name, (text, add_options, options_of) in _ANALYSES.items():
        q = analyses.add_parser(name, help=text,
                                description=f"scatterlab batch {name}: {text}, with the "
                                f"options of 'scatterlab {name}'.")
        q.add_argument("runs", nargs="*", metavar="RUN",
                       help="run files, folders (their *.h5) or globs, quoted so that the "
                       "shell leaves them: 'runs/*.h5', 'data/**/*.h5'")
        q.add_argument("--catalog-query", default=None, metavar="QUERY",
                       help="runs from the catalog: key=value terms, e.g. 'sample=glossy "
                       "kind=brdf_in_plane status=finished since=2026-11-01 "
                       "until=2026-11-30' (also date=YYYY-MM-DD, since=7d)")
        q.add_argument("--catalog", default=str(DEFAULT_RUNS_DIR), metavar="DIR",
                       help=f"folder of the catalog (default: {DEFAULT_RUNS_DIR})")
        add_options(q)
        q.add_argument("--force", action="store_true",
                       help="analyse runs again even when analysed with the same options")
        q.add_argument("--no-report", action="store_true",
                       help="no report or figures per run (the results files and the summary "
                       "table are still written)")
        q.add_argument("--summary-dir", default=None, metavar="DIR",
                       help="folder for the summary table (default: the runs' common folder)")
        add_cluster_options(q, local_by_default=True)
        q.add_argument("--no-dashboard", action="store_true",
                       help="do not start the Dask dashboard of the local cluster")
        q.set_defaults(func=run, options_of=options_of)


class BatchProgress:
    """Outcome subscriber: a bar with counts and ETA, and a line per failure."""

    def __init__(self, n_total: int, stream: TextIO | None = None, *, width: int = 30,
                 plain_interval_s: float = 5.0) -> None:
        self.n_total = n_total
        self.stream = stream or sys.stdout
        self.width = width
        self.plain_interval_s = plain_interval_s
        self.outcomes: list[Outcome] = []
        self.t0 = time.monotonic()
        self._plain = self.t0
        self._tty = getattr(self.stream, "isatty", lambda: False)()

    def counts(self) -> dict[str, int]:
        c: dict[str, int] = {}
        for o in self.outcomes:
            c[o.status] = c.get(o.status, 0) + 1
        return c

    def text(self) -> str:
        n = len(self.outcomes)
        frac = n / max(1, self.n_total)
        elapsed = time.monotonic() - self.t0
        eta = elapsed / n * (self.n_total - n) if n else float("nan")
        counts = ", ".join(f"{v} {k}" for k, v in self.counts().items())
        eta_s = fmt_s(eta) if eta == eta else "?"
        return (f"[{'#' * int(frac * self.width):<{self.width}}] {n}/{self.n_total} "
                f"{frac:4.0%} elapsed {fmt_s(elapsed)} ETA {eta_s}  {counts}")

    def __call__(self, o: Outcome) -> None:
        self.outcomes.append(o)
        if o.redone:
            times = "" if o.redone == 1 else f" ({o.redone} times)"
            self._line(f"  redone: {o.run}: the worker process analysing it died (killed, "
                       f"crashed or out of memory){times}; another worker analysed it "
                       "again from the start")
        if o.status == "failed":
            self._line(f"  failed: {o.run}: {o.cause}")
        now = time.monotonic()
        done = len(self.outcomes) == self.n_total
        if self._tty:
            self.stream.write("\r\033[K" + self.text() + ("\n" if done else ""))
            self.stream.flush()
        elif done or now - self._plain >= self.plain_interval_s:
            self._plain = now
            self._line(self.text())

    def _line(self, text: str) -> None:
        self.stream.write(("\r\033[K" if self._tty else "") + text + "\n")
        self.stream.flush()


def _summary_dir(args: argparse.Namespace, runs: list[Path]) -> Path:
    if args.summary_dir:
        return Path(args.summary_dir)
    return Path(os.path.commonpath([str(p.resolve().parent) for p in runs]))


def run(args: argparse.Namespace) -> int:
    from instrument.batch.analyses import get_analysis
    from instrument.batch.select import parse_query, select_runs
    from instrument.batch.summary import write_csv, write_html
    from instrument.batch.task import run_serial
    from instrument.version import software_version

    analysis = get_analysis(args.analysis)
    try:
        options = args.options_of(args)
        query = parse_query(args.catalog_query) if args.catalog_query is not None else None
        runs = select_runs(args.runs, query=query, catalog=args.catalog, kinds=analysis.kinds)
    except (ValueError, OSError) as err:  # QueryError is a ValueError
        print(f"error: {err}")
        return 2
    if args.retries < 0:
        print(f"error: --retries must be ≥ 0, got {args.retries}")
        return 2
    if analysis.name == "fit":
        from instrument.batch.polarimetric_options import batch_notes, check_runs

        try:  # a calibration that cannot be used stops the batch before it writes anything
            by_kind = check_runs(runs, options.get("polarimetric"))
        except ValueError as err:  # CalibrationError is a ValueError
            print(f"error: {err}")
            return 2
        for note in batch_notes(by_kind, options.get("polarimetric")):
            print(note)
    if not runs:
        print(f"no runs match the catalog query ({query.describe() if query else ''}) in "
              f"{args.catalog}")
        return 0
    print(f"batch {analysis.name}: {len(runs)} run(s)"
          + (f" ({'; '.join(str(r) for r in runs[:3])}{' …' if len(runs) > 3 else ''})"))
    progress = BatchProgress(len(runs))
    report = not args.no_report
    where = "here, one after another"
    t0 = time.monotonic()
    interrupted = False
    try:
        with open_cluster(args, local_by_default=True,
                          dashboard=not args.no_dashboard) as client:
            if client is None:
                run_serial(analysis.name, runs, options, report=report, force=args.force,
                           on_outcome=progress)
            else:
                from instrument.batch.cluster import describe, run_on_cluster

                where = f"Dask: {describe(client)}"
                run_on_cluster(client, analysis.name, runs, options, report=report,
                               force=args.force, on_outcome=progress)
    except ClusterUnavailable as err:
        print(f"error: {err}")
        return 2
    except KeyboardInterrupt:
        interrupted = True
        print(f"\ninterrupted after {len(progress.outcomes)} of {len(runs)} runs; finished "
              "runs keep their results, and the same command continues with the rest")
    wall = time.monotonic() - t0
    done = progress.outcomes
    by_run = {o.run: o for o in done}
    outcomes = [by_run[str(r)] for r in runs if str(r) in by_run]
    try:
        folder = _summary_dir(args, runs)
        folder.mkdir(parents=True, exist_ok=True)
        stem = folder / f"batch-{analysis.name}-{time.strftime('%Y%m%d-%H%M%S')}"
        csv_path = write_csv(outcomes, stem.with_suffix(".csv"))
        about = {"analysis": analysis.name, "options": json.dumps(options, sort_keys=True),
                 "where": where, "wall time": fmt_s(wall),
                 "software": software_version()}
        html_path = write_html(outcomes, stem.with_suffix(".html"),
                               title=f"scatterlab batch {analysis.name}", about=about)
    except OSError as err:
        print(f"error: cannot write the summary table: {err}")
        return 2
    counts = ", ".join(f"{v} {k}" for k, v in progress.counts().items())
    print(f"{len(outcomes)} of {len(runs)} run(s) in {fmt_s(wall)}: {counts}")
    failed = [o for o in outcomes if o.status == "failed"]
    for o in failed:
        print(f"  FAILED {o.run}: {o.cause}")
    print(f"summary: {csv_path}\n         {html_path}")
    if interrupted:
        return 130
    return 1 if failed else 0
