"""Results files next to the run (ADR 0013): where they go, atomic writes, the fingerprint."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from instrument.run.results import (
    already_done,
    options_fingerprint,
    put_json,
    read_results_attrs,
    results_dir,
    results_path,
    write_results_file,
)


def test_results_go_into_a_folder_named_after_the_run(tmp_path):
    run = tmp_path / "runs" / "20261124-brdf-ab12.h5"
    assert results_dir(run, "fit") == tmp_path / "runs" / "20261124-brdf-ab12" / "fit"
    assert results_path(run, "spheres").name == "results.h5"
    with pytest.raises(ValueError, match="unknown pipeline"):
        results_dir(run, "fits")


def test_a_results_file_names_its_run_program_and_options(tmp_path):
    run = tmp_path / "r.h5"
    opts = {"models": ["lambert", "lambert+ggx"], "criterion": "bic", "flat": None}
    with write_results_file(run, "fit", run_id="r-1", program="scatterlab fit",
                            options=opts) as g:
        put_json(g, "results_json", {"chi2": np.float64(3.5)})
    path = results_path(run, "fit")
    with h5py.File(path, "r") as f:
        e = f["entry"]
        assert e.attrs["run_id"] == "r-1"
        assert e.attrs["run_file"] == "../../r.h5"
        assert json.loads(e.attrs["options_json"]) == opts
        assert json.loads(f["entry/analysis/results_json"][()]) == {"chi2": 3.5}
    assert already_done(run, "fit", run_id="r-1", options=dict(reversed(opts.items())))
    assert not already_done(run, "fit", run_id="r-1", options={**opts, "criterion": "aic"})
    assert not already_done(run, "fit", run_id="r-2", options=opts)
    assert not already_done(run, "spheres", run_id="r-1", options=opts)
    assert list(path.parent.iterdir()) == [path]  # no temporary file left


def test_a_failed_write_keeps_the_previous_results(tmp_path):
    run = tmp_path / "r.h5"
    with write_results_file(run, "spheres", run_id="r", program="p", options={"a": 1}) as g:
        put_json(g, "results_json", {"v": 1})
    with pytest.raises(RuntimeError, match="boom"), \
            write_results_file(run, "spheres", run_id="r", program="p", options={"a": 2}) as g:
        put_json(g, "results_json", {"v": 2})
        raise RuntimeError("boom")
    assert read_results_attrs(run, "spheres")["options_sha256"] == options_fingerprint({"a": 1})
    assert sorted(p.name for p in results_dir(run, "spheres").iterdir()) == ["results.h5"]


def test_an_unreadable_results_file_is_not_done(tmp_path):
    run = tmp_path / "r.h5"
    path = results_path(run, "fit")
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not hdf5")
    assert read_results_attrs(run, "fit") is None
    assert not already_done(run, "fit", run_id="r", options={})


@given(st.dictionaries(st.text(max_size=8),
                       st.one_of(st.none(), st.booleans(), st.integers(), st.text(max_size=8),
                                 st.lists(st.integers(), max_size=4)), max_size=6))
def test_the_fingerprint_ignores_key_order_and_sees_every_value(opts):
    assert options_fingerprint(opts) == options_fingerprint(dict(reversed(opts.items())))
    changed = {**opts, "\x00extra": 1}
    assert options_fingerprint(changed) != options_fingerprint(opts)


def test_paths_in_options_fingerprint_as_text(tmp_path):
    assert options_fingerprint({"flat": Path("a/b.h5")}) == options_fingerprint(
        {"flat": "a/b.h5"})
