"""Which pBRDF the data need: Mueller matrices of the world's hidden samples (written
independently of the analysis, :mod:`hw_mocks.sim.polarised_sample`), reduced from
seeded noisy DRR readings, select the variant the sample has and pass the gate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.polarimetry import PolarimetryInputError, drr_angles, instrument_matrix, reduce
from analysis.polarimetry.pbrdf import pbrdf
from analysis.polarimetry.pbrdf_selection import PBRDF_VARIANTS, select_pbrdf
from hw_mocks.sim.polarised_sample import MicrofacetPolarisedSample

_UP = np.array([0.0, 1.0, 0.0])


def _world(sample: MicrofacetPolarisedSample, ti: float, tr: float) -> np.ndarray:
    """The world's Mueller BRDF at an in-plane point (the source at +x, the receiver at −x)."""
    wi = np.array([math.sin(ti), 0.0, math.cos(ti)])
    wr = np.array([[-math.sin(tr), 0.0, math.cos(tr)]])
    return sample.mueller(wi, wr, _UP)[0]


def _data(sample: MicrofacetPolarisedSample, seed: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    g, a = drr_angles(36)
    w = instrument_matrix(g, a, psg_retardance=math.radians(127),
                          psa_retardance=math.radians(127))
    geos = [(ti, tr) for ti in np.radians([30.0, 50.0, 70.0])
            for tr in np.radians(np.linspace(10.0, 80.0, 8))]
    ms, covs = [], []
    for ti, tr in geos:
        truth = _world(sample, ti, tr)
        sigma = 0.01 * truth[0, 0] + 1e-4  # 1 % of the reading plus a floor
        est = reduce(w @ truth.ravel() + sigma * rng.standard_normal(36), sigma, w)
        ms.append(est.m)
        covs.append(est.cov)
    ti, tr = np.array(geos).T
    return np.array(ms), np.array(covs), ti, np.zeros_like(ti), tr, np.full_like(ti, math.pi)


def test_the_world_sample_and_the_analysis_model_agree_at_points():
    # two independent implementations (world: 3-D Jones; analysis: frame rotations)
    sample = MicrofacetPolarisedSample(n=1.5, k=0.3, slope_rms=0.2, albedo=0.3)
    for ti, tr in ((0.5, 0.6), (0.9, 0.7), (1.2, 0.3)):
        np.testing.assert_allclose(_world(sample, ti, tr),
                                   pbrdf((1.5, 0.3, 0.2, 0.3), ti, 0.0, tr, math.pi)[0],
                                   atol=1e-12)


@pytest.mark.parametrize(("sample", "expected"), [
    (MicrofacetPolarisedSample(n=1.5, slope_rms=0.2), "fresnel_dielectric"),
    (MicrofacetPolarisedSample(n=1.5, slope_rms=0.2, albedo=0.3),
     "fresnel_dielectric+diffuse"),
    (MicrofacetPolarisedSample(n=1.4, k=7.6, slope_rms=0.2), "fresnel_metal"),
])
@pytest.mark.parametrize("seed", [0, 1])
def test_selection_chooses_what_the_sample_has(sample, expected, seed):
    sel = select_pbrdf(*_data(sample, seed), start=(1.5, 0.0, 0.2, 0.1))
    assert sel.chosen == expected, [(r.name, round(r.bic, 1)) for r in sel.table]
    assert sel.chosen_fit.goodness.adequate, sel.chosen_fit.goodness.verdict()
    assert [r.name for r in sel.table] == list(PBRDF_VARIANTS)
    assert "fewest parameters" in sel.rule


def test_selection_input_checks():
    m, cov, *ang = _data(MicrofacetPolarisedSample(n=1.5, slope_rms=0.2), 0)
    with pytest.raises(PolarimetryInputError) as err:
        select_pbrdf(m, cov, *ang, start=(1.5, 0, 0.2, 0.1), variants=("lambert",))
    assert err.value.argument == "variants"
    with pytest.raises(PolarimetryInputError) as err:
        select_pbrdf(m, cov, *ang, start=(1.5, 0, 0.2, 0.1), criterion="cv")
    assert err.value.argument == "criterion"
