"""``scatterlab runs``: list and filter the run catalog.

Columns are as wide as their widest entry (a sample name is never cut). A run whose file
was repaired gets a line under it: the last repair, and the points whose frames are still
lost with the command that measures them again.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Set as AbstractSet
from pathlib import Path
from typing import TYPE_CHECKING

from instrument.run.paths import DEFAULT_RUNS_DIR

if TYPE_CHECKING:
    from instrument.run.catalog import RepairRow, RunRow

HELP = "list runs from the catalog (filter by status, sample...)"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("runs", help=HELP)
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


def table(rows: list[list[str]], right: AbstractSet[int] = frozenset()) -> list[str]:
    """Rows of cells as lines, each column as wide as its widest cell (the last one not
    padded); columns in ``right`` aligned right."""
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    lines = []
    for r in rows:
        cells = [c.rjust(w) if k in right else c.ljust(w)
                 for k, (c, w) in enumerate(zip(r, widths, strict=True))]
        cells[-1] = r[-1]
        lines.append("  ".join(cells))
    return lines


def run(args: argparse.Namespace) -> int:
    from instrument.run.catalog import CATALOG_NAME, Catalog

    since = None if args.since_days is None else time.time() - 86400 * args.since_days
    if not (Path(args.out) / CATALOG_NAME).is_file():  # listing never creates anything
        print(f"no runs in {args.out} (no {CATALOG_NAME} there; --out names the folder "
              "the runs were written to)")
        return 0
    with Catalog(args.out) as cat:
        cat.refresh_live()  # rows of runs whose process was killed say "interrupted"
        rows = cat.find(status=args.status, sample=args.sample, kind=args.kind, since=since,
                        limit=args.limit)
        repairs = {r.run_id: cat.repairs(r.run_id) for r in rows}
    if not rows:
        print(f"no runs in {args.out} match")
        return 0
    cells = [["run id", "sample", "kind", "status", "started", "ended", "points", "path"]]
    cells += [[r.run_id, r.sample, r.plan_kind, r.status, _t(r.started), _t(r.ended),
               f"{r.n_points}/{r.n_planned}", r.path] for r in rows]
    lines = table(cells, right={6})
    print(lines[0])
    for r, line in zip(rows, lines[1:], strict=True):
        print(line)
        for note in repair_notes(r, repairs[r.run_id]):
            print(f"    {note}")
    return 0


def repair_notes(row: RunRow, repairs: list[RepairRow]) -> list[str]:
    """Under a repaired run: its last repair and what is still lost."""
    if not repairs:
        return []
    last = repairs[-1]
    out = [f"repaired {_t(last.time)}: {'; '.join(last.what)}"]
    if len(repairs) > 1:
        out[0] += f" ({len(repairs)} repairs, see the run's event log)"
    from instrument.run.runfile import RunFileError, read_summary

    try:
        lost = read_summary(row.path).lost
    except (OSError, KeyError, RunFileError) as err:
        return [*out, f"the run file cannot be read now: {err}"]
    if lost:
        out.append(f"frames still lost: point(s) {', '.join(map(str, lost))}; measure them "
                   f"again: scatterlab resume --remeasure-lost {row.path}")
    return out
