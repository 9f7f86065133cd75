"""``scatterlab resume RUN``: continue a paused, aborted or crashed run in the same file.

The run file is made to agree with its journal first (or, without a usable journal,
rebuilt from what the file still holds); every repair is printed and recorded in the
catalog, finished run or not. ``--remeasure-lost`` measures again, into the same file, the
points whose frames a damaged file lost.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from instrument.cli._client import add_server, call
from instrument.cli.run import add_common

if TYPE_CHECKING:
    from instrument.run.recovery import RecoveryReport

HELP = "continue a run that did not finish, or repair one (same file)"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("resume", help=HELP)
    p.add_argument("run", nargs="?", default=None,
                   help="run id (looked up in the --out catalog) or run file path; "
                   "without it, with --server: the bench server's paused run, or the "
                   "interrupted or aborted run at the head of its queue")
    p.add_argument("--remeasure-lost", action="store_true",
                   help="also measure again the points whose frames a damaged file lost "
                   "(they are marked status 2); finished runs too")
    add_common(p)
    add_server(p)
    p.add_argument("--answer", choices=("resume", "retry", "skip"), default="resume",
                   help="with --server, after a device fault: try the failed point again "
                   "(retry) or store it as skipped (skip)")
    p.set_defaults(func=run)


def find_run(run: str, out: str) -> Path:
    from instrument.run.catalog import CATALOG_NAME, Catalog

    path = Path(run)
    if path.suffix == ".h5" or path.exists():
        return path
    if not (Path(out) / CATALOG_NAME).is_file():
        raise FileNotFoundError(f"{run}: no such run file, and no run catalog in {out} to "
                                "look the id up in")
    with Catalog(out) as cat:
        row = cat.get(run)
    if row is None:
        raise FileNotFoundError(f"no run {run!r} in the catalog of {out}")
    return Path(row.path)


def print_repairs(report: RecoveryReport, path: Path) -> None:
    """Every repair a recovery made, and what it left lost."""
    for line in report.repairs:
        print(f"  repaired: {line}")
    if report.repairs:
        print(f"  (recorded in the run's event log and in the catalog of {path.parent})")


def run(args: argparse.Namespace) -> int:
    if args.run is None:
        # the bench server's run (a client command); with RUN, today's direct resume
        if not (args.server or os.environ.get("SCATTERLAB_SERVER")):
            print("error: give the run to resume (id or file), or --server URL to resume "
                  "the bench server's run")
            return 2
        return call(args, lambda c: print(c.resume(args.answer)))
    from instrument.run.health import inspect_run_file
    from instrument.run.locks import LockHeld, hold
    from instrument.run.paths import writer_lock_path

    try:
        path = find_run(args.run, args.out)
    except FileNotFoundError as err:
        print(f"error: {err.strerror or err}")
        return 2
    if not path.is_file() or not inspect_run_file(path).is_run:
        return _resume(args, path)  # recovery names what is wrong with it (no lock file)
    lock = writer_lock_path(path)
    try:
        # One process continues a run: a second resume is told who, instead of meeting
        # the first one's open file somewhere inside recovery.
        with hold(lock, f"scatterlab resume {path.name}"):
            return _resume(args, path)
    except LockHeld as err:
        if err.path != lock:
            raise
        print(f"error: run {path.name} is being continued by {err.holder} (lock {lock}); "
              "wait for it to end, or stop it, then resume again")
        return 2


def _resume(args: argparse.Namespace, path: Path) -> int:
    from instrument.run.recovery import describe_points
    from instrument.run.runner import recover_run
    from instrument.run.storage import StorageError

    try:
        report = recover_run(path)
    except StorageError as err:
        print(f"error: {err.strerror or err}")  # the message, without "[Errno N]"
        return 2
    path = Path(path).resolve()
    h = report.header
    n_planned = len(h.planned_label)
    where = (f"rebuilt; the original is kept as {report.original.name}" if report.original
             else "repaired in place" if report.repaired else "file intact")
    print(f"run {h.run_id} ({report.status}): {report.n_points} of {n_planned} points on "
          f"disk ({where})")
    print_repairs(report, path)
    lost = report.lost
    again = lost if args.remeasure_lost else ()
    if lost and not args.remeasure_lost:
        print(f"  the frames of point(s) {describe_points(lost)} are lost: they are left out "
              "of analysis; measure them again into this file with:\n"
              f"    scatterlab resume --remeasure-lost {path}")
    if report.status == "finished" and not again:
        print(f"run {h.run_id} is already finished ({report.n_points} points); nothing to "
              "continue")
        return 1 if lost else 0
    if again:
        print(f"  measuring point(s) {describe_points(again)} again into {path.name}")
    from instrument.bench.devices import open_bench
    from instrument.bench.profile import load_profile, parse_profile
    from instrument.cli.run import drive
    from instrument.run.runner import resume_run

    profile = (load_profile(args.bench) if args.bench else
               parse_profile(h.profile_text, source=f"bench profile stored in {path}"))
    with open_bench(profile) as bench:
        engine = resume_run(path, bench, fsync=not args.no_fsync,
                            remeasure_lost=args.remeasure_lost)
        return drive(engine, args.quiet)
