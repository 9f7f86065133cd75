"""Laser speckle with a static sample: the reduction's σ stay honest.

An in-plane scan of the simulated bench is rendered noise-free (tests/instrument/
sim_scan.py), each point speckled by the simulated camera's generator
(:mod:`hw_mocks.sim.speckle`: a frozen pattern per geometry and seed), exposed on the
EMVA 1288 sensor and reduced by the absolute method; the speckle term of the reduction
(:func:`analysis.brdf.reduction.speckle_rel`, what ``reduce_run`` adds under a laser) is
put into each value's σ. The correct, instrument-aware model is fitted: over several seeds
the goodness-of-fit gate must not fire, and the pulls (estimate − truth)/σ must look like
N(0, 1). Without the speckle term the gate fires (the test shows the term is needed).

The beam is narrowed to 0.3 mm and the sensor is 96 px of 5.5 µm, so that a point's
speckle grid is small (σ_rel ≈ 3 %: speckle dominates the shot noise by far).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.fit import fit_brdf
from analysis.brdf.goodness import DEFAULT_ALPHA, goodness_of_fit
from analysis.brdf.reduction import BRDFPoints, receiver_model, speckle_rel
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.speckle import SpeckleOptics, speckle_image, speckle_seed
from instrument.pipelines.brdf.reduce import reduce_run
from tests.instrument.sim_scan import (
    Rendered,
    Sample,
    ScanSetup,
    receiver,
    reduce_seed,
    render,
    write_run_file,
)

SETUP = ScanSetup(theta_i_deg=(30.0, 50.0), theta_r_step=20.0, beam_radius_mm=0.3,
                  power_w=2e-5, sensor_px=96,
                  sensor=SensorParams(width=96, height=96, pixel_pitch_um=5.5))
SAMPLE = Sample("glossy", "lambert+ggx", (0.3, 0.5, 0.2))
WAVELENGTH_NM = 633.0


def _optics(setup: ScanSetup) -> SpeckleOptics:
    image_mm = 1.0 / (1.0 / setup.focal_length_mm - 1.0 / setup.distance_mm)
    return SpeckleOptics(WAVELENGTH_NM, image_mm / setup.aperture_mm,
                         setup.sensor_params().pixel_pitch_um)


def speckled(r: Rendered, seed: int) -> Rendered:
    """Every point's image speckled: one frozen pattern per geometry for this seed."""
    optics = _optics(r.setup)
    rates = np.array([speckle_image(rate, optics, [speckle_seed(seed, angles, 0)])
                      for rate, angles in zip(r.photon_rate, r.angles_rad, strict=True)])
    return replace(r, photon_rate=rates)


def with_speckle_sigma(pts: BRDFPoints, setup: ScanSetup) -> BRDFPoints:
    rel = speckle_rel(pts.theta_i, pts.theta_r, wavelength_nm=WAVELENGTH_NM,
                      beam_radius_mm=setup.beam_radius_mm,
                      solid_angle_sr=receiver(setup).solid_angle_sr)
    return replace(pts, u_stat=np.hypot(pts.u_stat, pts.brdf * rel))


def fit_seed(r: Rendered, seed: int, *, speckle_sigma: bool):
    pts = reduce_seed(speckled(r, seed), seed)
    if speckle_sigma:
        pts = with_speckle_sigma(pts, r.setup)
    model = receiver_model(get_model(SAMPLE.model), receiver(r.setup))
    a = r.angles_rad
    fit = fit_brdf(model, pts.brdf, a[:, 0], a[:, 1], a[:, 2], a[:, 3], sigma=pts.u_point,
                   start=np.array(SAMPLE.params))
    return fit, goodness_of_fit(fit.residuals, model.n_params)


@pytest.mark.slow
def test_static_speckle_gate_quiet_and_pulls_normal() -> None:
    r = render(SETUP, SAMPLE)
    truth = np.array(SAMPLE.params)
    pulls, p_values = [], []
    for seed in range(1, 9):
        fit, gof = fit_seed(r, seed, speckle_sigma=True)
        p_values.append(gof.p_value)
        pulls.append((fit.params - truth) / fit.stderr)
    # the gate: no correct fit rejected (each fires with probability alpha = 1e-3)
    assert min(p_values) > DEFAULT_ALPHA, p_values
    z = np.array(pulls).ravel()
    # 24 pulls of N(0, 1): mean within ±3/√24, spread within the χ² range of 24 samples
    assert abs(z.mean()) < 3.0 / math.sqrt(z.size), z
    assert 0.5 < z.std() < 1.5, z


@pytest.mark.slow
def test_without_the_speckle_term_the_gate_fires() -> None:
    r = render(SETUP, SAMPLE)
    fired = [fit_seed(r, seed, speckle_sigma=False)[1].p_value < DEFAULT_ALPHA
             for seed in (1, 2)]
    assert all(fired)


#: A few points, for the run-file path (fast).
SMALL = replace(SETUP, theta_i_deg=(40.0,), theta_r_step=40.0, specular_half_width_deg=0.0,
                supersample=1)


def test_reduce_run_adds_speckle_under_a_laser(tmp_path: Path) -> None:
    r = speckled(render(SMALL, SAMPLE), 4)
    lamp = reduce_run(write_run_file(r, 4, tmp_path / "lamp.h5", coherence="incoherent"))
    laser = reduce_run(write_run_file(r, 4, tmp_path / "laser.h5", coherence="laser"))
    np.testing.assert_allclose(laser.points.brdf, lamp.points.brdf, rtol=1e-12)
    rel = speckle_rel(laser.points.theta_i, laser.points.theta_r,
                      wavelength_nm=WAVELENGTH_NM, beam_radius_mm=SMALL.beam_radius_mm,
                      solid_angle_sr=laser.provenance["solid_angle_sr"])
    expected = np.hypot(lamp.points.u_stat, lamp.points.brdf * rel)
    np.testing.assert_allclose(laser.points.u_stat, expected, rtol=1e-9)
    assert "speckle" in laser.provenance and "speckle" not in lamp.provenance
