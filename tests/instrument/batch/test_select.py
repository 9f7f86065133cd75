"""Choosing the runs of a batch: files, folders, globs and catalog queries."""

from __future__ import annotations

import time
from datetime import datetime
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from instrument.batch.select import (
    STATUSES,
    CatalogQuery,
    QueryError,
    expand_paths,
    parse_query,
    query_catalog,
    select_runs,
)
from instrument.plans.planfile import KINDS
from instrument.run.catalog import Catalog, RunRow


def _t(text: str) -> float:
    return datetime.fromisoformat(text).timestamp()


@pytest.fixture
def catalog(tmp_path):
    """A catalog of six runs (the files exist: a batch checks them itself)."""
    rows = [
        ("glossy-1", "glossy tile", "brdf_in_plane", "finished", "2026-11-01T10:00"),
        ("glossy-2", "glossy tile", "brdf_in_plane", "aborted", "2026-11-02T10:00"),
        ("matte-1", "matte paper", "brdf_in_plane", "finished", "2026-11-03T23:59"),
        ("hemi-1", "glossy tile", "brdf_hemisphere", "finished", "2026-11-04T08:00"),
        ("wall-1", "wall", "lightfield", "finished", "2026-11-04T09:00"),
        ("flat-1", "", "flat_field", "finished", "2026-11-05T09:00"),
    ]
    with Catalog(tmp_path) as cat:
        for run_id, sample, kind, status, started in rows:
            path = tmp_path / f"{run_id}.h5"
            path.write_bytes(b"")
            cat.add(RunRow(run_id, sample, kind, "p", "sim", status, _t(started), None, 1, 1,
                           str(path)))
    return tmp_path


def _ids(paths: list[Path]) -> list[str]:
    return [p.stem for p in paths]


FIT_KINDS = ("brdf_in_plane", "brdf_hemisphere", "reference")


def test_catalog_queries_by_sample_kind_status_and_date(catalog):
    def q(text: str, kinds=FIT_KINDS) -> list[str]:
        return _ids(query_catalog(catalog, parse_query(text), kinds=kinds))

    # without a kind, the runs the analysis takes, oldest first
    assert q("") == ["glossy-1", "glossy-2", "matte-1", "hemi-1"]
    assert q("", kinds=("lightfield",)) == ["wall-1"]
    assert q("sample=glossy") == ["glossy-1", "glossy-2", "hemi-1"]
    assert q("sample=glossy,status=finished") == ["glossy-1", "hemi-1"]
    assert q("kind=brdf_hemisphere") == ["hemi-1"]
    assert q("since=2026-11-02 until=2026-11-03") == ["glossy-2", "matte-1"]  # whole days
    assert q("date=2026-11-03") == ["matte-1"]
    assert q("since=2026-11-03T12:00") == ["matte-1", "hemi-1"]
    assert q("status=interrupted") == []
    with pytest.raises(QueryError, match="not analysed by this analysis"):
        q("kind=lightfield")


def test_select_runs_joins_paths_and_query_once_each(catalog, tmp_path):
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / "x.h5").write_bytes(b"")
    (other / "sub").mkdir()
    (other / "sub" / "y.h5").write_bytes(b"")
    runs = select_runs([str(catalog / "matte-1.h5"), str(other)],
                       query=parse_query("sample=matte"), catalog=catalog, kinds=FIT_KINDS)
    assert _ids(runs) == ["matte-1", "x"]  # the catalog's matte-1 is the same file
    assert _ids(expand_paths([str(other / "**" / "*.h5")])) == ["y", "x"]  # sub/y < x
    assert _ids(expand_paths([str(other / "?.h5")])) == ["x"]
    with pytest.raises(QueryError, match="matches no run file"):
        expand_paths([str(other / "*.hdf5")])
    with pytest.raises(QueryError, match="no runs"):
        select_runs([])
    with pytest.raises(QueryError, match="no run catalog"):
        select_runs([], query=CatalogQuery(), catalog=other)


@pytest.mark.parametrize(("text", "says"), [
    ("colour=red", "unknown key 'colour'"),
    ("sample", "not key=value"),
    ("sample=", "not key=value"),
    ("kind=brdf", "not a plan kind"),
    ("status=done", "not a run status"),
    ("since=yesterday", "is not a date"),
    ("until=7d", "is not a date"),
    ("date=2026-11", "give one day"),
    ("date=2026-11-01 since=2026-10-01", "given twice"),
    ("sample=a sample=b", "given twice"),
    ("since=2026-11-05 until=2026-11-01", "since is not before until"),
])
def test_bad_queries_name_the_term(text, says):
    with pytest.raises(QueryError, match=says):
        parse_query(text)


def test_relative_since_counts_days_back():
    q = parse_query("since=1.5d")
    assert abs(q.since - (time.time() - 1.5 * 86400)) < 60
    assert "since=" in q.describe() and parse_query("").describe() == "(every run)"


_values = st.text(alphabet=st.characters(blacklist_categories=("Cs",),
                                         blacklist_characters=" ,\t\n\r\x0b\x0c\x1c\x1d\x1e"
                                         "\x1f\x85\xa0\u1680\u2000\u2001\u2002\u2003\u2004"
                                         "\u2005\u2006\u2007\u2008\u2009\u200a\u2028\u2029"
                                         "\u202f\u205f\u3000"), min_size=1, max_size=12)


@given(st.lists(st.tuples(st.sampled_from(["sample", "kind", "status", "since", "until",
                                           "date", "colour", ""]),
                          st.one_of(_values, st.sampled_from(KINDS), st.sampled_from(STATUSES),
                                    st.sampled_from(["2026-11-01", "2026-11-30T12:00",
                                                     "3d"]))),
                max_size=4),
       st.sampled_from([" ", ",", " , "]))
def test_fuzzed_queries_parse_or_fail_with_a_query_error(terms, sep):
    text = sep.join(f"{k}={v}" for k, v in terms)
    try:
        q = parse_query(text)
    except QueryError as err:
        assert str(err).startswith("catalog query:")
        return
    given_keys = {k for k, _ in terms}
    if q.kind is not None:
        assert q.kind in KINDS and "kind" in given_keys
    if q.status is not None:
        assert q.status in STATUSES
    if q.since is not None and q.until is not None:
        assert q.since < q.until
    if "sample" in given_keys:
        assert q.sample == dict(terms)["sample"]
