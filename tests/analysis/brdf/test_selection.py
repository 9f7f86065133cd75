"""Model selection with an explicit noise model and grouped cross-validation."""

import numpy as np
import pytest

from analysis.brdf import get_model, parse_model_list
from analysis.brdf.selection import (
    cross_validate,
    grouped_folds,
    incidence_groups,
    select_model,
)

from .synth import noisy, scan_angles

CANDIDATES = "lambert,oren_nayar,lambert+ggx,oren_nayar+ggx"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lambertian_data_select_lambert(seed: int) -> None:
    angles = scan_angles(15, out_of_plane=False)
    y, sig, _ = noisy(get_model("lambert"), [0.8], angles, seed=seed, rel=0.02)
    res = select_model(parse_model_list(CANDIDATES), y, *angles, sigma=sig, run_cv=False)
    assert res.chosen == "lambert"
    assert [r.name for r in res.table] == CANDIDATES.split(",")
    # the bigger models fit no better than noise
    assert res.fits["lambert"].reduced_chi2 == pytest.approx(1.0, abs=0.3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_glossy_data_select_lambert_plus_ggx(seed: int) -> None:
    angles = scan_angles(15, out_of_plane=False)
    y, sig, _ = noisy(get_model("lambert+ggx"), [0.3, 0.5, 0.2], angles, seed=seed, rel=0.03)
    res = select_model(parse_model_list(CANDIDATES), y, *angles, sigma=sig, run_cv=False)
    assert res.chosen == "lambert+ggx"
    row = {r.name: r for r in res.table}
    assert row["lambert"].bic - row["lambert+ggx"].bic > 100


def test_rough_diffuse_data_select_oren_nayar() -> None:
    angles = scan_angles(15, out_of_plane=False)
    y, sig, _ = noisy(get_model("oren_nayar"), [0.7, 0.35], angles, seed=3, rel=0.02)
    res = select_model(parse_model_list(CANDIDATES), y, *angles, sigma=sig, run_cv=False)
    assert res.chosen == "oren_nayar"


def test_cross_validation_criterion_and_table() -> None:
    angles = scan_angles(12, out_of_plane=False)
    y, sig, _ = noisy(get_model("lambert+ggx"), [0.3, 0.5, 0.2], angles, seed=7, rel=0.03)
    res = select_model(
        parse_model_list("lambert,lambert+ggx"), y, *angles, sigma=sig, criterion="cv",
        n_folds=3,
    )
    assert res.chosen == "lambert+ggx"
    row = {r.name: r for r in res.table}
    # held-out mean r² ≈ 1 for the true model (noise only), ≫ 1 for the wrong one
    assert row["lambert+ggx"].cv_score == pytest.approx(1.0, abs=0.5)
    assert row["lambert"].cv_score > 20
    assert np.isfinite(row["lambert"].cv_stderr)
    assert "one-standard-error" in res.rule


def test_folds_never_split_an_incidence_angle() -> None:
    ti = np.repeat(np.radians([0.0, 10.0, 20.0, 30.0, 40.0]), 7)
    groups = incidence_groups(ti)
    folds = grouped_folds(groups, 3, seed=1)
    assert len(folds) == 3
    assert np.all(np.sum(folds, axis=0) == 1)  # every point in exactly one test fold
    for test in folds:
        assert set(np.unique(ti[test])).isdisjoint(np.unique(ti[~test]))


def test_read_back_jitter_does_not_split_an_incidence_angle() -> None:
    # a hemisphere run at one set θi: read-backs scatter by ~10⁻⁵ rad around it
    rng = np.random.default_rng(4)
    ti = np.radians(30.0) + 1e-5 * rng.standard_normal(40)
    assert np.unique(incidence_groups(ti)).size == 1
    tr = np.radians(np.linspace(0, 80, 40))
    m = get_model("lambert")
    cv, _ = cross_validate(m, m.evaluate([0.5], ti, 0.0, tr, np.pi), ti, 0.0, tr, np.pi)
    assert np.isnan(cv)  # one incidence angle: nothing to cross-validate over
    two = np.concatenate([ti, ti + np.radians(20.0)])
    assert np.unique(incidence_groups(two)).size == 2


def test_cv_needs_two_incidence_angles() -> None:
    tr = np.radians(np.linspace(0, 80, 20))
    m = get_model("lambert")
    y = m.evaluate([0.5], 0.3, 0.0, tr, np.pi)
    cv, se = cross_validate(m, y, 0.3, 0.0, tr, np.pi)
    assert np.isnan(cv) and np.isnan(se)


def test_duplicate_candidates_rejected() -> None:
    angles = scan_angles(5, out_of_plane=False)
    y, sig, _ = noisy(get_model("lambert"), [0.5], angles, seed=0)
    with pytest.raises(ValueError):
        select_model(parse_model_list("lambert,lambert"), y, *angles, sigma=sig)
    with pytest.raises(ValueError):
        select_model(parse_model_list("lambert"), y, *angles, sigma=sig, criterion="r2")


def test_selection_result_serialises_to_plain_values() -> None:
    import json

    angles = scan_angles(6, out_of_plane=False)
    y, sig, _ = noisy(get_model("lambert"), [0.5], angles, seed=0)
    res = select_model(parse_model_list("lambert,lambert+ggx"), y, *angles, sigma=sig,
                       run_cv=False)
    d = json.loads(json.dumps(res.to_dict()))
    assert d["chosen"] == "lambert"
    assert [r["name"] for r in d["table"]] == ["lambert", "lambert+ggx"]
    assert d["fits"]["lambert"]["param_names"] == ["rho"]
