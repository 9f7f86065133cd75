"""The ducc0 backend of the transforms against the project's own (reference) transform.

Both compute the same Gauss–Legendre quadrature on the same nodes, so they agree to
rounding: 1e-11 relative at L = 2048 for the coefficients, the maps in rms and the cross
round trips (ducc0 synthesis → reference analysis and back). A convention mismatch (a lost
(−1)^m, a √2, a ring order) would show as differences of order 1.

The one place where the maps differ more is the few rings nearest each pole: there a map
of degree L changes by |∂f/∂θ| ≈ L·max|f| per radian, and one rounding of cos θ_j moves the
ring by ε/θ_j, so any evaluation through cos θ is uncertain by ≈ L·max|f|·ε/θ_1 —
8e-8 of max|f| ≈ 3000 (2.7e-11 relative) at L = 2048 against a bound of 2.5e-7. The
max-norm comparison of maps therefore uses 1e-10; the quadrature weights of those rings
(~θ_1²) make it invisible in the coefficients.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.sh.ducc import (
    set_transform_defaults,
    transform_defaults,
)
from analysis.sh.transform import analysis, gl_grid, synthesis
from analysis.sh.validation import SHInputError


@pytest.fixture
def restore_defaults():
    old = transform_defaults()
    yield
    set_transform_defaults(backend=old.backend, nthreads=old.nthreads)


def _agreement(lmax: int) -> dict[str, float]:
    """Differences ducc0 vs reference, relative to the largest (rms: to the rms) value."""
    rng = np.random.default_rng(1000 + lmax)
    grid = gl_grid(lmax, precompute=False)
    c = rng.standard_normal((lmax + 1) ** 2)
    f_ref = synthesis(c, grid=grid, backend="reference")
    f_duc = synthesis(c, grid=grid, backend="ducc0", nthreads=1)
    # analysis of a map that is not band-limited to L (white noise): both must compute the
    # same quadrature, aliasing included
    g = rng.standard_normal(grid.shape)
    a_ref = analysis(g, grid=grid, backend="reference")
    a_duc = analysis(g, grid=grid, backend="ducc0", nthreads=1)
    cross = max(np.max(np.abs(analysis(f_duc, grid=grid, backend="reference") - c)),
                np.max(np.abs(analysis(f_ref, grid=grid, backend="ducc0") - c)))
    return {
        "map_max": float(np.max(np.abs(f_duc - f_ref)) / np.max(np.abs(f_ref))),
        "map_rms": float(np.sqrt(np.mean((f_duc - f_ref) ** 2) / np.mean(f_ref**2))),
        "coeffs": float(np.max(np.abs(a_duc - a_ref)) / np.max(np.abs(a_ref))),
        "cross_round_trip": float(cross / np.max(np.abs(c))),
    }


@pytest.mark.parametrize("lmax", [0, 1, 2, 3, 16, 41, 64, 130])
def test_ducc0_agrees_with_the_reference(lmax: int) -> None:
    err = _agreement(lmax)
    assert max(err.values()) <= 1e-12, err


@pytest.mark.slow
@pytest.mark.timeout(1800)  # the reference takes ~30 s at L = 2048 on an idle dev box
def test_ducc0_agrees_with_the_reference_at_l_2048() -> None:
    err = _agreement(2048)
    assert err["coeffs"] <= 1e-11 and err["map_rms"] <= 1e-11, err
    assert err["cross_round_trip"] <= 1e-11, err
    assert err["map_max"] <= 1e-10, err  # polar rings: module docstring


def test_single_harmonics_have_the_project_convention() -> None:
    """Y_1,1 = +√(3/4π) x (no Condon–Shortley phase), Y_1,−1 = +√(3/4π) y, Y_2,2 ∝ x² − y²,
    through ducc0: the sign and √2 conventions, one harmonic at a time."""
    lmax = 4
    grid = gl_grid(lmax)
    th, ph = np.meshgrid(grid.theta, grid.phi, indexing="ij")
    x, y = np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph)
    k = np.sqrt(3.0 / (4.0 * np.pi))
    cases = {(1, 1): k * x, (1, -1): k * y,
             (2, 2): 0.25 * np.sqrt(15.0 / np.pi) * (x * x - y * y)}
    for (l, m), expected in cases.items():
        c = np.zeros((lmax + 1) ** 2)
        c[l * l + l + m] = 1.0
        np.testing.assert_allclose(synthesis(c, grid=grid, backend="ducc0"), expected,
                                   atol=1e-14)
        np.testing.assert_allclose(analysis(expected, grid=grid, backend="ducc0"), c,
                                   atol=1e-14)


def test_module_setting_selects_the_backend(restore_defaults) -> None:
    assert transform_defaults().backend == "ducc0"
    assert transform_defaults().nthreads == 1
    # ducc0 needs no stored Legendre table; the reference gets it by default
    assert gl_grid(20).legendre is None
    old = set_transform_defaults(backend="reference", nthreads=2)
    assert old.backend == "ducc0" and old.nthreads == 1
    assert transform_defaults().backend == "reference"
    assert gl_grid(20).legendre is not None
    c = np.random.default_rng(2).standard_normal(21 * 21)
    grid = gl_grid(20)
    np.testing.assert_allclose(synthesis(c, grid=grid), synthesis(c, grid=grid,
                                                                  backend="ducc0"),
                               atol=1e-12)


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"backend": "libsharp"}, "backend"),
    ({"nthreads": -1}, "nthreads"),
    ({"nthreads": 1.5}, "nthreads"),
    ({"nthreads": True}, "nthreads"),
])
def test_bad_backend_settings_are_named(kwargs, name, restore_defaults) -> None:
    grid = gl_grid(2)
    with pytest.raises(SHInputError) as err:
        synthesis(np.zeros(9), grid=grid, **kwargs)
    assert err.value.argument == name
    with pytest.raises(SHInputError) as err:
        set_transform_defaults(**kwargs)
    assert err.value.argument == name
    assert transform_defaults().backend == "ducc0"


def _first_root(n: int, guess: float) -> float:
    """The GL node near ``guess`` (a colatitude) as a root of P_n(cos θ), in mpmath."""
    mp = pytest.importorskip("mpmath")
    with mp.workdps(40):
        return float(mp.findroot(lambda a: mp.legendre(n, mp.cos(a)), mp.mpf(guess)))


@pytest.mark.parametrize("n", [65, pytest.param(2049, marks=[pytest.mark.slow,
                                                              pytest.mark.timeout(900)])])
def test_grid_nodes_are_the_roots_to_rounding(n: int) -> None:
    """The grids' (ducc0's) polar nodes against mpmath roots of P_n; our own
    gauss_legendre agrees to its documented ε/θ."""
    from analysis.sh.legendre import gauss_legendre

    grid = gl_grid(n - 1)
    ours, w_ours = gauss_legendre(n)
    assert abs(grid.weights.sum() - 2.0) < 1e-14
    for j in (0, 2):
        root = _first_root(n, grid.theta[j])
        assert abs(grid.theta[j] - root) <= 4 * np.finfo(float).eps * root
        assert abs(ours[j] - root) <= 2 * np.finfo(float).eps / root
    np.testing.assert_allclose(w_ours, grid.weights, rtol=1e-10)
