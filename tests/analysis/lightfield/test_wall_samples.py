"""The focal stacks summed over the rays that meet the wall only give the stacks of every
(y, ray) pair, to rounding (analysis/lightfield/wall_samples.py; timing in BENCHMARKS.md,
"locate at n_theta 1024")."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield import LightField2D, theta_grid
from analysis.lightfield.localize import _sample_plan, _stacks, point_response
from analysis.lightfield.spectral import fourier_orders

DOMAIN = (-0.6, 0.6)


def _case(n_theta: int, seed: int) -> tuple[LightField2D, np.ndarray]:
    """A seeded field on a 60 mm wall (1 mm rows) and a Wiener-like filter (φ from 1 to 0
    over the top quarter of the passed orders)."""
    rng = np.random.default_rng(seed)
    rows = np.arange(-30.0, 30.0, 1.0)
    lf = LightField2D(rng.normal(size=(rows.size, n_theta)), rows,
                      theta_grid(DOMAIN, n_theta), DOMAIN, 0.0)
    p = np.abs(fourier_orders(n_theta)).astype(float)
    p_cut = n_theta // 6
    phi = np.clip((p_cut - p) / (0.25 * p_cut), 0.0, 1.0)
    return lf, phi


def _relative_errors(got, want) -> list[float]:
    return [float(np.max(np.abs(g - w)) / max(float(np.max(np.abs(w))), 1e-300))
            for g, w in zip(got, want, strict=True)]


@pytest.mark.parametrize(("n_theta", "seed"), [(128, 1), (256, 2), (512, 3)])
@pytest.mark.parametrize("filtered", [True, False])
def test_sums_over_rays_that_meet_the_wall_equal_those_over_every_pair(n_theta, seed,
                                                                      filtered):
    lf, phi = _case(n_theta, seed)
    # the default search's shape: the wall ± 60 mm across (two thirds of the pairs miss)
    y = np.arange(-90.0, 89.6, 0.5)
    zs = np.arange(-400.0, -59.0, 23.0)
    a, b = -0.35, 0.3
    ph = phi if filtered else None
    want = _stacks(lf, y, zs, a, b, ph, dense=True)
    got = _stacks(lf, y, zs, a, b, ph)
    assert max(_relative_errors(got, want)) < 1e-12


def test_a_point_response_reusing_the_grid_geometry_gives_the_same_stacks():
    """The measure and the matched filter's norm depend on the grid and the rays alone:
    the candidates' models take them from the data's stacks."""
    lf, phi = _case(256, 4)
    y = np.arange(-70.0, 70.1, 0.5)
    zs = np.arange(-300.0, -80.0, 17.0)
    a, b = -0.3, 0.3
    data = _stacks(lf, y, zs, a, b, phi)
    model = point_response(lf, -8.0, -200.0, phi)
    fresh = _stacks(model, y, zs, a, b, phi)
    reused = _stacks(model, y, zs, a, b, phi, geometry=(data[2], data[4]))
    for g, w in zip(reused, fresh, strict=True):
        assert np.array_equal(g, w)
    assert max(_relative_errors(reused, _stacks(model, y, zs, a, b, phi, dense=True))) < 1e-12


def test_a_grid_that_is_not_increasing_takes_the_reference_path():
    lf, phi = _case(128, 5)
    y = np.arange(60.0, -60.1, -1.0)
    zs = np.array([-250.0, -120.0])
    want = _stacks(lf, y[::-1], zs, -0.3, 0.3, phi)
    got = _stacks(lf, y, zs, -0.3, 0.3, phi)
    assert max(_relative_errors([g[:, ::-1] for g in got], want)) < 1e-12


@pytest.mark.parametrize(("n_theta", "seed"), [(128, 6), (256, 7)])
def test_a_point_response_through_the_sample_plan_gives_the_same_stacks(n_theta, seed):
    """The models' samples laid out once as sparse matrices (SamplePlan) give the sums of
    the runs, to rounding: the same samples and weights, added in another order."""
    lf, phi = _case(n_theta, seed)
    y = np.arange(-90.0, 89.6, 0.5)
    zs = np.arange(-400.0, -59.0, 13.0)
    a, b = -0.35, 0.3
    data = _stacks(lf, y, zs, a, b, phi)
    plan = _sample_plan(lf, y, zs, a, b, phi)
    assert plan is not None and plan.nbytes > 0
    for y0, z0 in ((-8.0, -200.0), (25.0, -90.0), (-70.0, -380.0)):
        model = point_response(lf, y0, z0, phi)
        runs = _stacks(model, y, zs, a, b, phi, geometry=(data[2], data[4]))
        planned = _stacks(model, y, zs, a, b, phi, geometry=(data[2], data[4]), plan=plan)
        assert max(_relative_errors(planned, runs)) < 1e-12
    # a random field too: the plan holds the geometry, not the point's shape
    noisy = lf.with_radiance(np.random.default_rng(seed).normal(size=lf.radiance.shape))
    runs = _stacks(noisy, y, zs, a, b, phi, geometry=(data[2], data[4]))
    planned = _stacks(noisy, y, zs, a, b, phi, geometry=(data[2], data[4]), plan=plan)
    assert max(_relative_errors(planned, runs)) < 1e-12


def test_no_plan_where_the_stacks_take_the_reference_path():
    lf, phi = _case(128, 8)
    y = np.arange(60.0, -60.1, -1.0)
    assert _sample_plan(lf, y, np.array([-250.0, -120.0]), -0.3, 0.3, phi) is None
