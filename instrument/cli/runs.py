"""``scatterlab runs``: list and filter the run catalog."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from instrument.run.catalog import CATALOG_NAME, Catalog
from instrument.run.runner import DEFAULT_RUNS_DIR


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("runs", help="list runs from the catalog (filter by status, sample...)")
    p.add_argument("--out", default=str(DEFAULT_RUNS_DIR),
                   help=f"folder of the catalog (default: {DEFAULT_RUNS_DIR})")
    p.add_argument("--status", help="finished | running | paused | aborted | failed | interrupted "
                   "(killed mid-run: continue it with `scatterlab resume`)")
    p.add_argument("--sample", help="substring of the sample name")
    p.add_argument("--kind", help="plan kind, e.g. brdf_in_plane")
    p.add_argument("--since-days", type=float, help="only runs started in the last N days")
    p.add_argument("--limit", type=int, default=50, help="at most this many, newest first "
                   "(default: 50; 0 for all)")
    p.set_defaults(func=run)


def _t(t: float | None) -> str:
    return "-" if t is None else time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def run(args: argparse.Namespace) -> int:
    since = None if args.since_days is None else time.time() - 86400 * args.since_days
    if not (Path(args.out) / CATALOG_NAME).is_file():  # listing never creates anything
        print(f"no runs in {args.out} (no {CATALOG_NAME} there; --out names the folder "
              "the runs were written to)")
        return 0
    with Catalog(args.out) as cat:
        cat.refresh_live()  # rows of runs whose process was killed say "interrupted"
        rows = cat.find(status=args.status, sample=args.sample, kind=args.kind, since=since,
                        limit=args.limit)
    if not rows:
        print(f"no runs in {args.out} match")
        return 0
    header = (f"{'run id':<40} {'sample':<16} {'kind':<16} {'status':<11} "
              f"{'started':<16} {'ended':<16} {'points':>11}  path")
    print(header)
    for r in rows:
        pts = f"{r.n_points}/{r.n_planned}"
        print(f"{r.run_id:<40} {r.sample[:16]:<16} {r.plan_kind[:16]:<16} {r.status:<11} "
              f"{_t(r.started):<16} {_t(r.ended):<16} {pts:>11}  {r.path}")
    return 0
