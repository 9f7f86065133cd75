"""The summary table of a batch: one row per run, as CSV (for programs) and HTML (to read).

Columns: the run (path, id, sample, plan kind), what became of it (analysed, skipped,
not applicable, failed) and why, the answer in words (``result``), the answer as named
columns (the chosen model and every parameter with its σ, the located objects, the
relighting error…: the union over the runs, empty where a run has none), the flags, and
the task's time and worker.
"""

from __future__ import annotations

import csv
import html
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from instrument.batch.task import Outcome

__all__ = ["summary_columns", "write_csv", "write_html"]

_HEAD = ("run", "run_id", "sample", "kind", "analysis", "status", "result")
_TAIL = ("flags", "cause", "seconds", "cpu_seconds", "worker")


def summary_columns(outcomes: Sequence[Outcome]) -> list[str]:
    """The table's columns: fixed ones around the union of the value names, in the order
    they first appear."""
    names: dict[str, None] = {}
    for o in outcomes:
        for k in o.values or {}:
            names.setdefault(k, None)
    return [*_HEAD, *names, *_TAIL]


def _cell(o: Outcome, col: str) -> Any:
    if col == "flags":
        return "; ".join(o.flags)
    if col in ("seconds", "cpu_seconds"):
        return round(getattr(o, col), 3)
    if col in _HEAD or col in _TAIL:
        return getattr(o, col)
    return (o.values or {}).get(col, "")


def _csv_value(v: Any) -> Any:
    # repr keeps every digit of a float, so the CSV reads back value for value
    return repr(v) if isinstance(v, float) else v


def write_csv(outcomes: Sequence[Outcome], path: str | Path) -> Path:
    """The table as CSV (UTF-8, a header line; floats with all their digits)."""
    path = Path(path)
    cols = summary_columns(outcomes)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for o in outcomes:
            w.writerow([_csv_value(_cell(o, c)) for c in cols])
    return path


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return str(v)


_STYLE = """
body { font-family: sans-serif; margin: 1.5em; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.5em; vertical-align: top; }
th { background: #eee; position: sticky; top: 0; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.failed { background: #fde2e2; } tr.skipped { color: #555; }
tr.not-applicable { color: #888; }
.flags { color: #8a4b00; } details { max-width: 60em; } pre { white-space: pre-wrap; }
"""


def write_html(outcomes: Sequence[Outcome], path: str | Path, *, title: str,
               about: Mapping[str, str] | Sequence[tuple[str, str]] = ()) -> Path:
    """The table as a stand-alone HTML page; ``about`` lines (options, cluster, counts)
    go above it."""
    path = Path(path)
    cols = summary_columns(outcomes)
    counts: dict[str, int] = {}
    for o in outcomes:
        counts[o.status] = counts.get(o.status, 0) + 1
    e = html.escape
    lines = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{e(title)}</h1>", "<ul>",
        *(f"<li><b>{e(k)}</b>: {e(v)}</li>" for k, v in dict(about).items()),
        f"<li><b>runs</b>: {len(outcomes)} — "
        + ", ".join(f"{n} {e(s)}" for s, n in counts.items()) + "</li>",
        f"<li><b>written</b>: {e(time.strftime('%Y-%m-%d %H:%M:%S'))}</li>", "</ul>",
        "<table><thead><tr>", *(f"<th>{e(c)}</th>" for c in cols), "</tr></thead><tbody>",
    ]
    for o in outcomes:
        lines.append(f'<tr class="{e(o.status.replace(" ", "-"))}">')
        for c in cols:
            v = _cell(o, c)
            if c == "cause" and o.detail:
                lines.append(f"<td>{e(o.cause)}<details><summary>traceback</summary>"
                             f"<pre>{e(o.detail)}</pre></details></td>")
            elif c == "flags":
                lines.append(f'<td class="flags">{"<br>".join(e(f) for f in o.flags)}</td>')
            elif isinstance(v, int | float) and not isinstance(v, bool):
                lines.append(f'<td class="num">{e(_fmt(v))}</td>')
            else:
                lines.append(f"<td>{e(_fmt(v))}</td>")
        lines.append("</tr>")
    lines += ["</tbody></table>", "</body></html>"]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
