"""Which runs a batch analyses: paths, globs, folders and catalog queries.

A query is a few ``key=value`` terms separated by spaces or commas, matched against the run
catalog (:class:`instrument.run.catalog.Catalog`)::

    sample=glossy kind=brdf_in_plane status=finished since=2026-11-01 until=2026-11-30

``sample`` is a substring of the sample name, ``kind`` a plan kind, ``status`` a run status;
``since``/``until`` are dates (``YYYY-MM-DD``, local time; ``until`` includes that day) or
date-times (``YYYY-MM-DDTHH:MM``), or ``since`` a number of days back (``since=7d``);
``date=YYYY-MM-DD`` is that one day.
"""

from __future__ import annotations

import glob
import re
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from datetime import datetime, timedelta
from pathlib import Path

from instrument.plans.planfile import KINDS
from instrument.run.catalog import CATALOG_NAME, Catalog

__all__ = ["CatalogQuery", "QueryError", "expand_paths", "parse_query", "query_catalog",
           "select_runs"]

#: Statuses a catalog row can hold (instrument.run.catalog and the engine's end statuses).
STATUSES = ("created", "running", "paused", "finished", "aborted", "failed", "interrupted")


class QueryError(ValueError):
    """A run selection that cannot be used; the message names the term or pattern."""


@dataclass(frozen=True)
class CatalogQuery:
    """Filters of a catalog query (None: not filtered); times are epoch seconds."""

    sample: str | None = None
    kind: str | None = None
    status: str | None = None
    since: float | None = None
    until: float | None = None

    def describe(self) -> str:
        parts = []
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            if f.name in ("since", "until"):
                v = time.strftime("%Y-%m-%d %H:%M", time.localtime(v))
            parts.append(f"{f.name}={v}")
        return " ".join(parts) or "(every run)"


_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}$")
_DAYS = re.compile(r"^(\d+(?:\.\d+)?)d$")


def _parse_time(key: str, text: str, *, end_of_day: bool = False) -> float:
    m = _DAYS.match(text)
    if m and key == "since":
        return time.time() - 86400.0 * float(m.group(1))
    try:
        t = datetime.fromisoformat(text)
    except ValueError:
        raise QueryError(f"catalog query: {key}={text!r} is not a date: use YYYY-MM-DD, "
                         f"YYYY-MM-DDTHH:MM" + (" or Nd (N days back)" if key == "since"
                                                 else "")) from None
    if end_of_day and _DATE.match(text):
        t += timedelta(days=1)
    return t.timestamp()


def parse_query(text: str) -> CatalogQuery:
    """A :class:`CatalogQuery` from ``key=value`` terms (module docstring).

    Raises
    ------
    QueryError
        An unknown key, a term without ``=``, a repeated key, an unknown kind or status,
        a date that does not parse, or ``since`` after ``until``.
    """
    values: dict[str, str] = {}
    for term in (t for t in re.split(r"[\s,]+", text.strip()) if t):
        key, sep, value = term.partition("=")
        key = key.strip().lower()
        if not sep or not value:
            raise QueryError(f"catalog query: {term!r} is not key=value (keys: sample, kind, "
                             "status, since, until, date)")
        if key not in ("sample", "kind", "status", "since", "until", "date"):
            raise QueryError(f"catalog query: unknown key {key!r} in {term!r}; use sample, "
                             "kind, status, since, until or date")
        if key in values or (key == "date" and ("since" in values or "until" in values)) \
                or (key in ("since", "until") and "date" in values):
            raise QueryError(f"catalog query: {key!r} given twice (or with date=)")
        values[key] = value
    if "kind" in values and values["kind"] not in KINDS:
        raise QueryError(f"catalog query: kind={values['kind']!r} is not a plan kind; one of "
                         f"{', '.join(KINDS)}")
    if "status" in values and values["status"] not in STATUSES:
        raise QueryError(f"catalog query: status={values['status']!r} is not a run status; "
                         f"one of {', '.join(STATUSES)}")
    since = until = None
    if "date" in values:
        if not _DATE.match(values["date"]):
            raise QueryError(f"catalog query: date={values['date']!r}: give one day, "
                             "YYYY-MM-DD")
        since = _parse_time("date", values["date"])
        until = _parse_time("date", values["date"], end_of_day=True)
    if "since" in values:
        since = _parse_time("since", values["since"])
    if "until" in values:
        until = _parse_time("until", values["until"], end_of_day=True)
    if since is not None and until is not None and since >= until:
        raise QueryError("catalog query: since is not before until")
    return CatalogQuery(values.get("sample"), values.get("kind"), values.get("status"),
                        since, until)


def query_catalog(folder: str | Path, query: CatalogQuery, *,
                  kinds: Sequence[str] = ()) -> list[Path]:
    """Run files of the catalog in ``folder`` that match ``query``, oldest first.

    Without a ``kind`` in the query, only runs of ``kinds`` are taken (the plan kinds the
    analysis applies to), when given.

    Raises
    ------
    QueryError
        ``folder`` has no catalog, or the query names a kind outside ``kinds``.
    """
    if not (Path(folder) / CATALOG_NAME).is_file():
        raise QueryError(f"no run catalog in {folder} (no {CATALOG_NAME}); --catalog names "
                         "the folder the runs were written to")
    if query.kind is not None and kinds and query.kind not in kinds:
        raise QueryError(f"catalog query: kind={query.kind} runs are not analysed by this "
                         f"analysis (it takes {', '.join(kinds)})")
    with Catalog(folder) as cat:
        cat.refresh_live()  # a run killed mid-way reads "interrupted", not "running"
        rows = cat.find(status=query.status, sample=query.sample, kind=query.kind,
                        since=query.since)
    if query.kind is None and kinds:
        rows = [r for r in rows if r.plan_kind in kinds]
    if query.until is not None:
        rows = [r for r in rows if r.started < query.until]
    rows.sort(key=lambda r: r.started)
    base = Path(folder)
    return [p if p.is_absolute() else base / p for p in (Path(r.path) for r in rows)]


def expand_paths(patterns: Iterable[str]) -> list[Path]:
    """Run files named by ``patterns``: a file, a folder (its ``*.h5``) or a glob (``*``,
    ``?``, ``[...]``, ``**`` for any depth), in the order given, sorted within a pattern.

    Raises
    ------
    QueryError
        A pattern that matches no run file (named, so a typo is not a silent empty batch).
    """
    out: list[Path] = []
    for pat in patterns:
        p = Path(pat)
        if p.is_dir():
            found = sorted(q for q in p.glob("*.h5") if q.is_file())
        elif glob.has_magic(pat):
            found = sorted(Path(q) for q in glob.glob(pat, recursive=True)
                           if Path(q).is_file())
        else:
            found = [p]  # a missing file is reported by its task, with the others analysed
        if not found:
            raise QueryError(f"{pat!r} matches no run file")
        out.extend(found)
    return out


def select_runs(patterns: Sequence[str] = (), *, query: CatalogQuery | None = None,
                catalog: str | Path | None = None, kinds: Sequence[str] = ()) -> list[Path]:
    """The union of ``patterns`` and the catalog query, each run once (by resolved path),
    in the order found.

    Raises
    ------
    QueryError
        Nothing to select from, or a pattern or query that cannot be used.
    """
    if not patterns and query is None:
        raise QueryError("no runs: give run files, globs or folders, or --catalog-query")
    found = expand_paths(patterns)
    if query is not None:
        found += query_catalog(catalog if catalog is not None else "runs", query, kinds=kinds)
    seen: set[Path] = set()
    runs = []
    for p in found:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            runs.append(p)
    return runs
