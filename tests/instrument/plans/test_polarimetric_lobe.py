"""A two-pass lobe plan with ``[polarimetry]`` (DRR or PEM, ADR 0106 amendment): the plan is
accepted (over several filters too, the lobe fitted at a reference filter), ``scatterlab
plan`` prints the polarimetric estimate of the first pass and says a second pass follows,
the second pass is placed from the first pass's m00 with a σ model fitted to it
(:mod:`instrument.pipelines.polarimetry.lobe`) and keeps the polarimetry settings. The
runs through the engine are in
``tests/instrument/pipelines/polarimetry/test_polarimetric_lobe_run.py`` and
``test_polarimetric_spectral_lobe.py``.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.brdf import get_model
from analysis.brdf.geometry import make_geometry
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.pipelines.polarimetry.lobe import M00Noise, geometry_seconds
from instrument.plans.lobe import (
    ReferenceFilter,
    _angles_rad,
    candidate_pairs,
    place_points_modelled,
    reference_filter,
    second_pass_text,
)
from instrument.plans.planfile import PlanError, parse_plan

LOBE_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "glass lobe"
[sample]
name = "glass"
[scan]
theta_i = [50.0]
theta_r = {{ start = 30.0, stop = 70.0, step = 10.0 }}
{lobe}
[acquisition]
detectors = ["{detector}"]
{polarimetry}
"""

DRR = '[polarimetry]\nmode = "drr"\nsteps = 23\n'
PEM = '[polarimetry]\nmode = "pem"\n'
BENCH = {"drr": "sim-polarimetric", "pem": "sim-polarimetric-pem"}


def plan(lobe: str = "lobe = { points = 4 }", polarimetry: str = DRR) -> str:
    detector = "lockin" if 'mode = "pem"' in polarimetry else "power_meter"
    return LOBE_PLAN.format(lobe=lobe, polarimetry=polarimetry, detector=detector)


@pytest.mark.parametrize("mode", ["drr", "pem"])
def test_scatterlab_plan_prints_the_polarimetric_first_pass_and_the_second(
        mode: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "lobe.toml"
    path.write_text(plan(polarimetry=DRR if mode == "drr" else PEM), encoding="utf-8")
    assert main(["plan", str(path), "--bench", BENCH[mode], "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    # 5 θr + the search of ±5° at 1° around 50° (50 once): 15 geometries
    per = 23 if mode == "drr" else 8
    assert f"{15 * per} points" in out
    assert "this is the first pass of a two-pass lobe plan" in out
    assert "adds 4 polarimetric geometries (the same [polarimetry] at each) placed by " \
        "Fisher information" in out
    assert ("condition number" in out) if mode == "drr" else ("κ" in out)


def test_the_second_pass_keeps_the_polarimetry_and_spectral_settings() -> None:
    first = plan(polarimetry=PEM + "reads = 4\n") + "[spectral]\nfilters = [2]\n"
    spec = parse_plan(first)
    assert spec.polarimetry is not None and spec.scan["lobe"] == {"points": 4}
    text = second_pass_text(first, [(50.0, 49.5), (50.0, 50.5)], "run-1.h5")
    data = tomllib.loads(text)
    assert data["polarimetry"] == {"mode": "pem", "reads": 4}
    assert data["spectral"] == {"filters": [2]}
    assert data["scan"] == {"points": [[50.0, 49.5], [50.0, 50.5]], "first_pass": "run-1.h5"}
    assert parse_plan(text).polarimetry == spec.polarimetry


def test_a_polarimetric_lobe_over_several_filters_names_its_reference_filter(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Accepted over several filters (it was refused); the lobe is fitted at the filter
    nearest the band's centre, or at lobe.reference_filter, and the plan says which."""
    profile = load_profile("sim-polarimetric-pem-spectral")  # 550 and 650 nm
    two = plan(polarimetry=PEM) + "[spectral]\nfilters = [2, 1]\n"
    ref = reference_filter(parse_plan(two), profile)
    # 550 and 650 nm are equally far from the centre, 600 nm: the shorter wavelength
    assert ref == ReferenceFilter(1, 550.0, False, 600.0)
    named = plan(lobe="lobe = { points = 4, reference_filter = 2 }", polarimetry=PEM) \
        + "[spectral]\nfilters = [1, 2]\n"
    assert reference_filter(parse_plan(named), profile) == ReferenceFilter(2, 650.0, True,
                                                                           600.0)
    # one filter, or none: the run's own wavelength
    assert reference_filter(parse_plan(plan(polarimetry=PEM) + "[spectral]\nfilters = [2]\n"),
                            profile) is None
    path = tmp_path / "lobe.toml"
    path.write_text(two, encoding="utf-8")
    assert main(["plan", str(path), "--bench", "sim-polarimetric-pem-spectral", "--out",
                 str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "the lobe is fitted at filter 1 (550 nm; the filter nearest the band's centre, " \
        "600 nm; lobe.reference_filter names another); the second pass reads every " \
        "filter" in out, out
    path.write_text(named, encoding="utf-8")
    assert main(["plan", str(path), "--bench", "sim-polarimetric-pem-spectral", "--out",
                 str(tmp_path)]) == 0
    assert "fitted at filter 2 (650 nm; named by lobe.reference_filter)" in \
        capsys.readouterr().out


@pytest.mark.parametrize(("lobe", "tables", "words"), [
    ("reference_filter = 3", "[spectral]\nfilters = [1, 2]\n",
     "slot 3 is not one of the plan's [spectral] filters [1, 2]"),
    ("reference_filter = 0", "[spectral]\nfilters = [1, 2]\n", "an integer from 1 to 12"),
    ("reference_filter = 1.5", "[spectral]\nfilters = [1, 2]\n", "an integer from 1 to 12"),
    ('reference_filter = "550"', "[spectral]\nfilters = [1, 2]\n",
     "an integer from 1 to 12"),
    ("reference_filter = 1", "", "it needs [polarimetry] and [spectral] filters"),
])
def test_a_reference_filter_that_cannot_be_used_is_refused_naming_it(
        lobe: str, tables: str, words: str) -> None:
    text = plan(lobe=f"lobe = {{ points = 4, {lobe} }}", polarimetry=PEM) + tables
    with pytest.raises(PlanError) as err:
        parse_plan(text)
    assert {e.path for e in err.value.errors} == {"scan.lobe.reference_filter"}
    assert words in str(err.value), str(err.value)
    # and without [polarimetry]: the scalar lobe has no reference filter
    scalar = plan(lobe="lobe = { points = 4, reference_filter = 1 }", polarimetry="") \
        + "[spectral]\nfilters = [1, 2]\n"
    with pytest.raises(PlanError, match=r"scan\.lobe\.reference_filter"):
        parse_plan(scalar)


lobe_tables = st.fixed_dictionaries(
    {"points": st.integers(1, 10000)},
    optional={"step_deg": st.floats(0.01, 10.0), "search_half_width_deg": st.floats(0.5, 45.0),
              "search_step_deg": st.floats(0.05, 10.0),
              "prior": st.sampled_from(["ggx", "phong"])})
drr_tables = st.fixed_dictionaries(
    {"mode": st.just("drr")},
    optional={"steps": st.sampled_from([23, 25, 36, 72]), "ratio": st.sampled_from([5, -5, 3.5])})
pem_tables = st.fixed_dictionaries(
    {"mode": st.just("pem")},
    optional={"amplitude_waves": st.floats(0.05, 1.0), "reads": st.integers(4, 100),
              "time_constants": st.floats(1.0, 100.0)})


def value(v: object) -> str:
    """A TOML scalar."""
    return f'"{v}"' if isinstance(v, str) else repr(v)


def toml_inline(table: dict[str, object]) -> str:
    return "{ " + ", ".join(f"{k} = {value(v)}" for k, v in table.items()) + " }"


@settings(max_examples=60, deadline=None)
@given(lobe=lobe_tables, pol=st.one_of(drr_tables, pem_tables))
def test_any_valid_lobe_with_any_valid_polarimetry_table_is_a_valid_plan(
        lobe: dict[str, object], pol: dict[str, object]) -> None:
    body = "\n".join(f"{k} = {value(v)}" for k, v in pol.items())
    spec = parse_plan(plan(lobe=f"lobe = {toml_inline(lobe)}",
                           polarimetry=f"[polarimetry]\n{body}\n"))
    assert spec.scan["lobe"]["points"] == lobe["points"]
    assert spec.polarimetry is not None and spec.polarimetry["mode"] == pol["mode"]
    # and its second pass reads back with the same polarimetry
    text = second_pass_text(spec.source_text, [(50.0, 50.25)], "first.h5")
    assert parse_plan(text).polarimetry == spec.polarimetry


# --- the σ model of m00 ---------------------------------------------------------------------
def test_the_sigma_model_recovers_floor_signal_and_relative_terms() -> None:
    m00 = np.geomspace(1e-3, 30.0, 25)
    a, b, c = 4e-8, 2e-6, 1e-5
    noise = M00Noise.fit(m00, np.sqrt(a + b * m00 + c * m00**2))
    np.testing.assert_allclose([noise.a, noise.b, noise.c], [a, b, c], rtol=1e-6)
    # σ measured with a few per cent scatter (a ten-step Mueller reduction's σ): the model
    # predicts σ within that scatter over the whole range
    rng = np.random.default_rng(3)
    sigma = np.sqrt(a + b * m00 + c * m00**2) * (1.0 + 0.03 * rng.standard_normal(m00.size))
    noisy = M00Noise.fit(m00, sigma)
    ratio = noisy.sigma(m00) / np.sqrt(a + b * m00 + c * m00**2)
    assert np.all(np.abs(ratio - 1.0) < 0.1), ratio


@settings(max_examples=80, deadline=None)
@given(pairs=st.lists(st.tuples(st.floats(0.0, 1e3), st.floats(1e-9, 1e2)), min_size=1,
                      max_size=30))
def test_the_sigma_model_is_positive_and_finite_for_any_pairs(
        pairs: list[tuple[float, float]]) -> None:
    m, s = np.array(pairs).T
    noise = M00Noise.fit(m, s)
    assert min(noise.a, noise.b, noise.c) >= 0.0
    pred = noise.sigma(np.concatenate([m, [0.0, 2e3]]))
    assert np.all(np.isfinite(pred)) and np.all(pred > 0)


def test_the_sigma_model_refuses_pairs_it_cannot_fit() -> None:
    with pytest.raises(ValueError, match="positive finite σ"):
        M00Noise.fit([1.0, 2.0], [0.1, 0.0])
    with pytest.raises(ValueError, match="equal length"):
        M00Noise.fit([], [])


# --- placement ------------------------------------------------------------------------------
def test_points_are_placed_on_the_lobe_with_the_sigma_model_and_cost_per_geometry() -> None:
    """A glass-like lobe (Lambert + GGX) seen at 30…70° every 10° and ±5° around specular:
    with σ from the σ model, the second pass's points fall on the lobe, and they shrink σ
    of the lobe width."""
    profile = load_profile("sim-polarimetric")
    spec = parse_plan(plan('lobe = { points = 4, step_deg = 0.5, prior = "lambert+ggx" }'))
    model = get_model("lambert+ggx")
    p = np.array([0.1, 0.5, 0.1])  # ρd, ks, α (rad)
    first_pairs = [(50.0, float(t)) for t in (30, 40, 45, 46, 47, 48, 49, 50, 51, 52, 53,
                                              54, 55, 60, 70)]
    first = _angles_rad(first_pairs)
    f1 = model.evaluate_geometry(p, make_geometry(*first.T))
    noise = M00Noise(1e-10, 0.0, 1e-4)  # a floor and 1 % of the value
    cands = candidate_pairs(spec, profile, 0.5)
    secs = geometry_seconds(spec, profile, cands[0], 0.5)
    assert secs > 16 * 0.1  # sixteen retarder steps are not free
    pl = place_points_modelled(model, p, first_angles_rad=first,
                               first_sigma=noise.sigma(f1), candidates=cands, n_points=4,
                               sigma_of=noise.sigma, geometry_s=secs, min_separation_deg=0.25)
    assert len(pl.pairs) == 4 and pl.seconds == pytest.approx(4 * secs)
    # on the lobe: where the model is at least 15 % of its peak (within ~16° of the
    # mirror direction), not on the diffuse floor at the range's ends
    f2 = model.evaluate_geometry(p, make_geometry(*_angles_rad(pl.pairs).T))
    assert np.all(f2 > 0.15 * f1.max()), (pl.pairs, f2)
    target = model.param_names[-1]
    assert pl.sigma_both[target] < pl.sigma_first[target]
