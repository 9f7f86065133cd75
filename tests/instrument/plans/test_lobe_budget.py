"""The lobe planner's error budget (instrument.plans.lobe_budget): the σ the fit will give a
reading, predicted before it is taken — the same terms, the same propagation."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.fit import fit_brdf
from analysis.brdf.geometry import make_geometry
from analysis.brdf.reduction import with_correlated_uncertainty, with_scale_uncertainty
from instrument.bench.profile import parse_profile
from instrument.plans.build import build_plan
from instrument.plans.lobe import Placement, SecondPass, SinglePass, _angles_rad
from instrument.plans.lobe_budget import (
    CLIPPED,
    OPEN,
    ErrorBudget,
    NDStep,
    angular_sigma,
    point_budget,
    predicted_covariance,
    shared_covariance,
)
from instrument.plans.planfile import parse_plan
from instrument.plans.tradeoff import (
    Prior,
    ScanOption,
    full_well_e,
    peak_electron_rate,
    setup_from_profile,
)
from tests.instrument.sim_scan import Sample, ScanSetup, profile_text

MODEL = get_model("lambert+ggx")
PARAMS = np.array([0.3, 0.5, 0.05])
#: Signed (θi, θr) around the mirror direction at θi = 40° and two far from it.
PAIRS = [(40.0, 40.0 + d) for d in np.arange(-12.0, 12.01, 0.5)] + [(40.0, -30.0),
                                                                     (40.0, 70.0)]


def _det(power_w: float):
    setup = ScanSetup(power_w=power_w, fill=0.5, max_exposure_us=10_000.0)
    sample = Sample("sharp", "lambert+ggx", (0.3, 0.5, 0.05))
    profile = parse_profile(profile_text(setup, sample))
    spec = parse_plan(setup.plan_text())
    _, det = setup_from_profile(profile, spec, prior=Prior("lambert+ggx", tuple(PARAMS)))
    return replace(det, fill=setup.fill)


def test_angular_term_is_the_slope_times_each_stage_sigma() -> None:
    a = _angles_rad(PAIRS)
    s_i, s_r = math.radians(0.01), math.radians(0.02)
    got = angular_sigma(MODEL, PARAMS, a, s_i, s_r)
    h = 1e-6  # a far smaller step than the budget's: the slope of a smooth model agrees
    up, dn = a.copy(), a.copy()
    up[:, 2] += h
    dn[:, 2] -= h
    d_r = (MODEL.evaluate_geometry(PARAMS, make_geometry(*up.T))
           - MODEL.evaluate_geometry(PARAMS, make_geometry(*dn.T))) / (2 * h)
    only_r = angular_sigma(MODEL, PARAMS, a, 0.0, s_r)
    np.testing.assert_allclose(only_r, np.abs(d_r) * s_r, rtol=1e-3, atol=1e-12)
    # the sample stage moves θi too: with both, never less than the arm's term alone
    assert np.all(got >= only_r - 1e-15) and np.any(got > 1.01 * only_r)
    assert np.all(angular_sigma(MODEL, PARAMS, a, 0.0, 0.0) == 0.0)


def test_a_peak_that_would_clip_is_read_through_the_lightest_filter_that_holds_it() -> None:
    det = _det(3e-5)
    a = _angles_rad(PAIRS)
    option = ScanOption(1.0, 10_000.0, 1)
    f = MODEL.evaluate_geometry(PARAMS, make_geometry(*a.T))
    _, peak = peak_electron_rate(f, a[:, 0], a[:, 2], det)
    at_min = peak * det.min_exposure_us * 1e-6 / (0.8 * full_well_e(det))
    assert at_min.max() > 10  # the peak clips in the open beam at the shortest exposure
    bare = point_budget(MODEL, PARAMS, a, det=det, option=option, budget=ErrorBudget())
    np.testing.assert_array_equal(bare.level == CLIPPED, at_min >= 1)
    assert np.all(np.isnan(bare.sigma[~bare.measurable]))
    nd = (NDStep(2, 0.1, 1e-4), NDStep(3, 0.01, 1e-5, calibrated=False),
          NDStep(4, 0.001, 1e-6))
    budget = ErrorBudget(filters=nd, filter_move_s=0.4)
    pb = point_budget(MODEL, PARAMS, a, det=det, option=option, budget=budget,
                      readout_s=0.02)
    want = np.where(at_min < 1, OPEN, np.where(at_min * 0.1 < 1, 0,
                                               np.where(at_min * 0.01 < 1, 1, 2)))
    want = np.where(at_min * 0.001 >= 1, CLIPPED, want)
    np.testing.assert_array_equal(pb.level, want)
    assert set(pb.level.tolist()) >= {OPEN, 0, 1}
    # a wheel too light for the peak: what clips behind its densest filter is not placed
    weak = point_budget(MODEL, PARAMS, a, det=det, option=option,
                        budget=ErrorBudget(filters=nd[:1]))
    np.testing.assert_array_equal(weak.level == CLIPPED, at_min * 0.1 >= 1)
    assert (weak.level == CLIPPED).any()
    # a filter costs the clipped open frame and the wheel's turn; the open beam nothing
    np.testing.assert_allclose(pb.extra_s[pb.level >= 0], 0.4 + 10e-6 + 0.02)
    assert np.all(pb.extra_s[pb.level == OPEN] == 0)
    # a calibrated filter's error is shared, an uncalibrated one's is in each σ (10⁻³ here)
    assert np.all(pb.rel_shared[pb.level == 0] == pytest.approx(1e-3))
    assert np.all(pb.rel_shared[pb.level != 0] == 0)
    on1 = pb.level == 1
    assert np.all(pb.sigma[on1] >= 1e-3 * pb.f[on1])
    assert list(pb.slots(budget)[pb.level == 0]) == [2] * int(np.sum(pb.level == 0))


def test_predicted_covariance_is_the_fits_own_propagation() -> None:
    """Noise-free readings fitted as analyse fits them, their shared and common errors
    propagated as analyse propagates them: the same covariance as predicted."""
    a = _angles_rad(PAIRS)
    f = MODEL.evaluate_geometry(PARAMS, make_geometry(*a.T))
    sigma = 0.01 * f + 1e-4
    slots = np.where(np.abs(np.array(PAIRS)[:, 1] - 40.0) < 1.0, 2, -1)
    shared = shared_covariance(f, slots, np.where(slots == 2, 2e-3, 0.0))
    assert shared is not None and np.count_nonzero(shared) == int(np.sum(slots == 2)) ** 2
    fit = fit_brdf(MODEL, f, *a.T, sigma=sigma, start=PARAMS)
    fit = with_scale_uncertainty(fit, MODEL, *a.T, sigma=sigma, scale_rel=0.01)
    fit = with_correlated_uncertainty(fit, MODEL, *a.T, sigma=sigma, cov=shared)
    cov = predicted_covariance(MODEL, PARAMS, a, sigma, shared=shared, scale_rel=0.01)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), fit.stderr, rtol=1e-4)


def _second_pass(both: float, alone: float) -> SecondPass:
    pl = Placement([(40.0, 40.5)], 3.0, [3.0], {"ggx.alpha": 2e-5}, {"ggx.alpha": both})
    return SecondPass(build_plan(parse_plan(ScanSetup().plan_text()),
                                 parse_profile(profile_text(ScanSetup(),
                                                            Sample("s", "lambert", (0.5,))))),
                      pl, "lambert+ggx", "ok", "ggx.alpha", 40.0, 12.0,
                      SinglePass(7.5, 78, 52.0, {"ggx.alpha": alone}))


def test_a_second_pass_that_cannot_beat_one_pass_of_equal_time_is_refused() -> None:
    no = _second_pass(3.1e-5, 2.9e-5)
    assert not no.worthwhile
    line = no.refusal()
    assert "\n" not in line and "3.1e-05" in line and "2.9e-05" in line
    assert "θr every 7.5°" in line and "52 s" in line
    assert _second_pass(1.0e-5, 2.9e-5).worthwhile
