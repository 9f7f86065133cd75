"""The same hidden sample on both goniometer types (ADR 0099): the simulated world renders
the same BRDF for the same scattering angles, so a type (ii) scan (``sim``) and a type (i)
scan (``sim-type-i``) of one sample fit to the same parameters."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.fit import fit_brdf
from analysis.brdf.reduction import receiver_model
from instrument.bench.profile import load_profile
from instrument.plans.build import build_plan
from instrument.plans.planfile import parse_plan
from tests.instrument.sim_scan import (
    Sample,
    ScanSetup,
    noise_free,
    receiver,
    reduce_seed,
    render,
)

SETUP = ScanSetup()
SAMPLE = Sample("glossy", "lambert+ggx", (0.3, 0.5, 0.2))


def _both():
    r_ii = render(SETUP, SAMPLE)
    plan_i = build_plan(parse_plan(SETUP.plan_text()), load_profile("sim-type-i"))
    return r_ii, render(SETUP, SAMPLE, plan=plan_i)


def _key(angles_rad: np.ndarray) -> list[tuple[float, ...]]:
    return [tuple(np.round(a, 9)) for a in angles_rad]


@pytest.mark.slow
def test_the_same_sample_fits_to_the_same_parameters_on_both_types():
    r_ii, r_i = _both()
    # noise-free: the same angles read the same BRDF, to rounding (the world computes
    # every ray in the sample frame; the bench only places the source and the camera)
    f_ii, f_i = noise_free(r_ii), noise_free(r_i)
    at_ii = dict(zip(_key(r_ii.angles_rad), f_ii.brdf, strict=True))
    common = [(v, at_ii[k]) for k, v in zip(_key(r_i.angles_rad), f_i.brdf, strict=True)
              if k in at_ii]
    assert len(common) == len(at_ii)
    got, want = np.array(common).T
    assert np.allclose(got, want, rtol=1e-9, atol=0.0)
    # one noisy scan on each bench, fitted with the model the receiver sees
    seen = receiver_model(get_model(SAMPLE.model), receiver(SETUP))
    fits = []
    for r, seed in ((r_ii, 1), (r_i, 2)):
        pts = reduce_seed(r, seed)
        fits.append(fit_brdf(seen, pts.brdf, *r.angles_rad.T, sigma=pts.u_point))
    a, b = fits
    sigma = np.hypot(a.stderr, b.stderr)
    assert np.all(np.abs(a.params - b.params) <= 3.0 * sigma), (a.params, b.params, sigma)
    # and each is the truth within its own σ (3σ: the fits can fail, for a reason)
    for f in fits:
        assert np.all(np.abs(f.params - np.array(SAMPLE.params)) <= 3.0 * f.stderr)
