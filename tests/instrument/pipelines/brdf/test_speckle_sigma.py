"""Laser speckle: the reduction's σ stay honest with a static sample, and shrink by the
right factor with a spinning one.

An in-plane scan of the simulated bench is rendered noise-free (tests/instrument/
sim_scan.py), each point speckled by the simulated camera's generator
(:mod:`hw_mocks.sim.speckle`: a frozen pattern per geometry and seed, or the average of the
patterns a spinning sample sweeps in the exposure), exposed on the EMVA 1288 sensor and
reduced by the absolute method; the speckle term of the reduction
(:func:`analysis.brdf.reduction.speckle_rel`, what ``reduce_run`` adds under a laser) is
put into each value's σ. The correct, instrument-aware model is fitted: over several seeds
the goodness-of-fit gate must not fire, and the pulls (estimate − truth)/σ must look like
N(0, 1). Without the speckle term the gate fires (the term is needed).

The beam is narrowed to 0.3 mm and the sensor is 96 px of 5.5 µm, so that a point's
speckle grid is small (σ_rel ≈ 3 % static: speckle dominates the shot noise by far); the
source is dimmed so that exposures last ~0.1 s, in which a sample spun at the K10CR1's
10 °/s sweeps several decorrelation angles.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.fit import FitResult, fit_brdf
from analysis.brdf.goodness import DEFAULT_ALPHA, GoodnessOfFit, goodness_of_fit
from analysis.brdf.reduction import BRDFPoints, receiver_model, speckle_rel, spin_patterns
from hw_mocks.sim.sensor import SensorParams
from instrument.pipelines.brdf.reduce import reduce_run
from tests.instrument.sim_scan import (
    LASER_NM,
    Rendered,
    Sample,
    ScanSetup,
    exposures_us,
    receiver,
    reduce_seed,
    render,
    speckled,
    spun_patterns,
    write_run_file,
)

SETUP = ScanSetup(theta_i_deg=(30.0, 50.0), theta_r_step=20.0, beam_radius_mm=0.3,
                  power_w=2e-9, sensor_px=96,
                  sensor=SensorParams(width=96, height=96, pixel_pitch_um=5.5))
SAMPLE = Sample("glossy", "lambert+ggx", (0.3, 0.5, 0.2))
#: The K10CR1 spinner's top speed (°/s).
SPIN = 10.0


def reduction_patterns(r: Rendered, spin_deg_s: float) -> np.ndarray:
    a = r.angles_rad
    return spin_patterns(a[:, 0], a[:, 1], a[:, 2], a[:, 3], spin_deg_s=spin_deg_s,
                         exposure_s=exposures_us(r) * 1e-6, wavelength_nm=LASER_NM,
                         beam_radius_mm=r.setup.beam_radius_mm,
                         solid_angle_sr=receiver(r.setup).solid_angle_sr)


def with_speckle_sigma(pts: BRDFPoints, r: Rendered, spin_deg_s: float) -> BRDFPoints:
    """The reduction's speckle term (as ``reduce_run`` adds it) in each value's σ."""
    rel = speckle_rel(pts.theta_i, pts.theta_r, wavelength_nm=LASER_NM,
                      beam_radius_mm=r.setup.beam_radius_mm,
                      solid_angle_sr=receiver(r.setup).solid_angle_sr,
                      patterns=reduction_patterns(r, spin_deg_s) if spin_deg_s else 1.0)
    return replace(pts, u_stat=np.hypot(pts.u_stat, pts.brdf * rel))


def fit_seed(r: Rendered, seed: int, *, speckle_sigma: bool, spin_deg_s: float = 0.0
             ) -> tuple[FitResult, GoodnessOfFit]:
    pts = reduce_seed(speckled(r, seed, spin_deg_s=spin_deg_s), seed)
    if speckle_sigma:
        pts = with_speckle_sigma(pts, r, spin_deg_s)
    model = receiver_model(get_model(SAMPLE.model), receiver(r.setup))
    a = r.angles_rad
    fit = fit_brdf(model, pts.brdf, a[:, 0], a[:, 1], a[:, 2], a[:, 3], sigma=pts.u_point,
                   start=np.array(SAMPLE.params))
    return fit, goodness_of_fit(fit.residuals, model.n_params)


def check_honest(r: Rendered, seeds: range, spin_deg_s: float) -> np.ndarray:
    """Gate quiet and pulls ~ N(0, 1) over ``seeds``; the reported σ per seed."""
    truth = np.array(SAMPLE.params)
    pulls, p_values, sigmas = [], [], []
    for seed in seeds:
        fit, gof = fit_seed(r, seed, speckle_sigma=True, spin_deg_s=spin_deg_s)
        p_values.append(gof.p_value)
        pulls.append((fit.params - truth) / fit.stderr)
        sigmas.append(fit.stderr)
    # the gate: no correct fit rejected (each fires with probability alpha = 1e-3)
    assert min(p_values) > DEFAULT_ALPHA, p_values
    z = np.array(pulls).ravel()
    # 24 pulls of N(0, 1): mean within ±3/√24, spread within the χ² range of 24 samples
    assert abs(z.mean()) < 3.0 / math.sqrt(z.size), z
    assert 0.5 < z.std() < 1.5, z
    return np.array(sigmas)


def test_reduction_and_simulation_count_the_same_patterns() -> None:
    # two implementations of one model (ADR 0098): the reduction's and the camera's
    r = render(SMALL, SAMPLE)
    np.testing.assert_allclose(reduction_patterns(r, SPIN), spun_patterns(r, SPIN),
                               rtol=1e-9)
    n = spun_patterns(r, SPIN)
    assert n.min() >= 1.0 and n.max() > 10.0  # near specular the pupil itself limits it


@pytest.mark.slow
def test_static_speckle_gate_quiet_and_pulls_normal() -> None:
    check_honest(render(SETUP, SAMPLE), range(1, 9), 0.0)


@pytest.mark.slow
def test_spinning_shrinks_sigma_and_keeps_it_honest() -> None:
    r = render(SETUP, SAMPLE)
    static = check_honest(r, range(1, 9), 0.0)
    spun = check_honest(r, range(1, 9), SPIN)
    # the same exposures (equal time): the speckle term shrinks by √N per point, and the
    # fitted σ with it (by less: shot noise and the other terms stay)
    assert np.all(spun.mean(axis=0) < 0.8 * static.mean(axis=0))


@pytest.mark.slow
def test_without_the_speckle_term_the_gate_fires() -> None:
    r = render(SETUP, SAMPLE)
    fired = [fit_seed(r, seed, speckle_sigma=False)[1].p_value < DEFAULT_ALPHA
             for seed in (1, 2)]
    assert all(fired)


#: A few points, for the run-file path (fast).
SMALL = replace(SETUP, theta_i_deg=(40.0,), theta_r_step=40.0, specular_half_width_deg=0.0,
                supersample=1)


@pytest.mark.parametrize("spin", [0.0, SPIN])
def test_reduce_run_adds_speckle_under_a_laser(tmp_path: Path, spin: float) -> None:
    r = render(SMALL, SAMPLE)
    spec = r.plan.spec
    r = replace(r, plan=replace(r.plan, spec=replace(
        spec, acquisition=replace(spec.acquisition, spin_deg_s=spin))))
    r = speckled(r, 4, spin_deg_s=spin)
    lamp = reduce_run(write_run_file(r, 4, tmp_path / "lamp.h5", coherence="incoherent"))
    laser = reduce_run(write_run_file(r, 4, tmp_path / "laser.h5", coherence="laser"))
    np.testing.assert_allclose(laser.points.brdf, lamp.points.brdf, rtol=1e-12)
    patterns = reduction_patterns(r, spin) if spin else 1.0
    rel = speckle_rel(laser.points.theta_i, laser.points.theta_r, wavelength_nm=LASER_NM,
                      beam_radius_mm=SMALL.beam_radius_mm,
                      solid_angle_sr=laser.provenance["solid_angle_sr"], patterns=patterns)
    expected = np.hypot(lamp.points.u_stat, lamp.points.brdf * rel)
    np.testing.assert_allclose(laser.points.u_stat, expected, rtol=1e-9)
    assert "speckle" in laser.provenance and "speckle" not in lamp.provenance
    assert ("spun" in laser.provenance["speckle"]) == (spin > 0)
