"""One geometry's reduction without the engine: steps synthesised from a known matrix
through the nominal instrument matrix (the pipeline's own forward model), so these check
the pipeline's plumbing — units, transmitted groups, the realizability flag — while the
slow closed loops check the physics against the simulated world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.polarimetry.drr import drr_angles, instrument_matrix
from analysis.polarimetry.elements import depolariser, linear_retarder
from instrument.pipelines.polarimetry.readings import PolarimetricRun, StepGroup
from instrument.pipelines.polarimetry.reduce import Scale, reduce_group

TRAIN = {"optics": {
    "source": [{"kind": "polariser", "mount": "psg_polariser", "orientation_deg": 0.0},
               {"kind": "retarder", "mount": "psg_retarder", "orientation_deg": 0.0,
                "retardance_deg": [90.0]}],
    "detector": [{"kind": "retarder", "mount": "psa_retarder", "orientation_deg": 0.0,
                  "retardance_deg": [90.0]},
                 {"kind": "polariser", "mount": "psa_polariser", "orientation_deg": 0.0}]},
    "polarimetry": {"mode": "drr", "steps": 36, "ratio": 5.0}}


def _group(m: np.ndarray, *, theta_r: float = 40.0, seed: int = 0,
           rel: float = 1e-4) -> tuple[PolarimetricRun, StepGroup]:
    g_ang, a_ang = drr_angles(36)
    w = instrument_matrix(g_ang, a_ang, psg_retardance=math.pi / 2,
                          psa_retardance=math.pi / 2)
    clean = w @ m.ravel()
    sigma = rel * np.max(np.abs(clean)) * np.ones(36)
    rng = np.random.default_rng(seed)
    group = StepGroup(theta_i=30.0, phi_i=0.0, theta_r=theta_r, phi_r=180.0,
                      wavelength_nm=633.0, rows=np.arange(36), step=np.arange(36),
                      psg_retarder_deg=g_ang, psa_retarder_deg=a_ang,
                      psg_polariser_deg=0.0, psa_polariser_deg=0.0,
                      intensity=clean + sigma * rng.standard_normal(36), sigma=sigma)
    prun = PolarimetricRun(run=None, train=TRAIN, polarimetry=TRAIN["polarimetry"],  # type: ignore[arg-type]
                           groups=(group,), noise_source="test")
    return prun, group


def test_a_reflected_group_is_a_brdf_and_a_transmitted_one_a_transmittance():
    m = 1e-6 * depolariser(1.0, 0.2) @ linear_retarder(0.3, 1.0)
    scale = Scale(source_w=2e-3, solid_angle_sr=2e-4, source="test", direct_w=1.9e-3)
    prun, g = _group(m)
    point = reduce_group(prun, g, None, scale)
    factor = 2e-3 * 2e-4 * math.cos(math.radians(40.0))
    np.testing.assert_allclose(point.brdf.m * factor, point.raw.m, rtol=1e-12)
    pull = (point.brdf.m - m / factor) / point.brdf.sigma
    assert np.all(np.abs(pull) < 4.0)
    assert point.decomposition is not None
    assert point.decomposition.value("depolarisation_power") == pytest.approx(0.8, abs=0.01)
    prun, g = _group(m, theta_r=180.0)
    through = reduce_group(prun, g, None, scale)
    assert g.transmitted and g.label().startswith("straight through")
    np.testing.assert_allclose(through.brdf.m * 1.9e-3, through.raw.m, rtol=1e-12)


def test_an_unphysical_matrix_is_flagged_and_kept_as_measured():
    m = 1e-6 * np.diag([1.0, 1.0, 1.0, 1.3])  # |m33| > m00: no physical system does this
    prun, g = _group(m, rel=1e-5)
    scale = Scale(source_w=1.0, solid_angle_sr=1.0, source="test")
    point = reduce_group(prun, g, None, scale)
    assert point.realizability.flagged
    assert point.realizability.eigenvalues[0] < 0
    # not projected: the reduced matrix is the least-squares one, |m33/m00| still > 1
    assert point.brdf.m_normalised[3, 3] == pytest.approx(1.3, abs=0.01)
