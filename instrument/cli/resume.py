"""``scatterlab resume RUN``: continue a paused, aborted or crashed run in the same file."""

from __future__ import annotations

import argparse
from pathlib import Path

from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile, parse_profile
from instrument.cli.run import add_common, drive
from instrument.run.catalog import Catalog
from instrument.run.runner import resume_run
from instrument.run.storage import StorageError, recover


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("resume", help="continue a run that did not finish (same file)")
    p.add_argument("run", help="run id (looked up in the --out catalog) or run file path")
    add_common(p)
    p.set_defaults(func=run)


def find_run(run: str, out: str) -> Path:
    path = Path(run)
    if path.suffix == ".h5" or path.exists():
        return path
    with Catalog(out) as cat:
        row = cat.get(run)
    if row is None:
        raise FileNotFoundError(f"no run {run!r} in the catalog of {out}")
    return Path(row.path)


def run(args: argparse.Namespace) -> int:
    try:
        path = find_run(args.run, args.out)
        report = recover(path)
    except (FileNotFoundError, StorageError) as err:
        print(f"error: {err.strerror or err}")  # the message, without "[Errno N]"
        return 2
    if report.status == "finished":
        print(f"run {report.header.run_id} is already finished ({report.n_points} points)")
        return 0
    lost = f", {report.frames_lost} frame(s) lost" if report.frames_lost else ""
    if report.points_lost:
        lost += (f"; point(s) {', '.join(map(str, report.points_lost))} marked status 2 "
                 "(frames lost: kept out of analysis)")
    print(f"run {report.header.run_id}: {report.n_points} of "
          f"{len(report.header.planned_label)} points on disk"
          f" ({'rebuilt from the journal' if report.rebuilt else 'file intact'}{lost})")
    profile = (load_profile(args.bench) if args.bench else
               parse_profile(report.header.profile_text,
                             source=f"bench profile stored in {path}"))
    with open_bench(profile) as bench:
        engine = resume_run(path, bench, fsync=not args.no_fsync)
        return drive(engine, args.quiet)
