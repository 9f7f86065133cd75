"""Directional–hemispherical reflectance ρ(θi) = ∫ f(ωi, ωr) cos θr dωr by quadrature
(Nicodemus et al. 1977, NBS Monograph 160).

Two quadratures, both deterministic and vectorised over θi:

* ``method="hemisphere"``: Gauss–Legendre in μr = cos θr ∈ [0, 1] times the periodic
  trapezoid rule in φr (spectrally accurate for smooth integrands; exact for a Lambertian).
* ``method="mirror"``: spherical coordinates (ψ, χ) about the mirror direction, with
  Gauss–Legendre panels in ψ graded geometrically from ``lobe_width`` outwards, for sharp
  specular lobes the hemisphere grid would miss. Directions below the horizon contribute 0.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.fit import FitResult
from analysis.brdf.geometry import geometry_from_vectors
from analysis.brdf.model import BRDFModel


@dataclass(frozen=True)
class Quadrature:
    """Directions and weights for ∫ g(ωr) cos θr dωr ≈ Σ w_j g(ω_j).

    Attributes
    ----------
    omega_r : ndarray, shape (M, 3)
        Unit directions in the upper hemisphere.
    weights : ndarray, shape (M,)
        Weights including cos θr and the solid-angle element.
    """

    omega_r: NDArray[np.float64]
    weights: NDArray[np.float64]


@lru_cache(maxsize=8)
def hemisphere_quadrature(n_mu: int = 96, n_phi: int = 192) -> Quadrature:
    """Gauss–Legendre in μ ∈ [0, 1] × trapezoid in φ: dω cos θ = μ dμ dφ (cached: the
    same nodes serve every θi and model; callers must not modify the arrays)."""
    t, w = np.polynomial.legendre.leggauss(n_mu)
    mu = 0.5 * (t + 1.0)
    wmu = 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    st = np.sqrt(1.0 - mu * mu)
    om = np.stack(
        np.broadcast_arrays(
            st[:, None] * np.cos(phi)[None, :],
            st[:, None] * np.sin(phi)[None, :],
            mu[:, None],
        ),
        axis=-1,
    ).reshape(-1, 3)
    wt = (wmu * mu)[:, None] * np.full(n_phi, 2.0 * np.pi / n_phi)[None, :]
    return Quadrature(om, wt.reshape(-1))


def _mirror_quadrature(
    mirror: NDArray[np.float64], lobe_width: float, n_per_panel: int, n_chi: int
) -> Quadrature:
    m = mirror / np.linalg.norm(mirror)
    # orthonormal frame (e1, e2, m)
    helper = np.array([1.0, 0.0, 0.0]) if abs(m[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(m, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(m, e1)
    edges = [0.0]
    w = lobe_width
    while edges[-1] < np.pi:
        edges.append(min(np.pi, max(w, edges[-1] + 1e-12)))
        w *= 2.0
    t, wt = np.polynomial.legendre.leggauss(n_per_panel)
    psi_l, wpsi_l = [], []
    for a, b in itertools.pairwise(edges):
        psi_l.append(0.5 * (b - a) * t + 0.5 * (a + b))
        wpsi_l.append(0.5 * (b - a) * wt)
    psi = np.concatenate(psi_l)
    wpsi = np.concatenate(wpsi_l) * np.sin(psi)
    chi = (np.arange(n_chi) + 0.5) * (2.0 * np.pi / n_chi)
    dirs = (
        np.cos(psi)[:, None, None] * m
        + np.sin(psi)[:, None, None]
        * (np.cos(chi)[None, :, None] * e1 + np.sin(chi)[None, :, None] * e2)
    ).reshape(-1, 3)
    wts = (wpsi[:, None] * np.full(n_chi, 2.0 * np.pi / n_chi)[None, :]).reshape(-1)
    mu = dirs[:, 2]
    keep = mu > 0
    return Quadrature(dirs[keep], wts[keep] * mu[keep])


def dhr(
    model: BRDFModel,
    params: ArrayLike,
    theta_i: ArrayLike,
    *,
    phi_i: float = 0.0,
    method: str = "hemisphere",
    n_mu: int = 96,
    n_phi: int = 192,
    lobe_width: float = 0.01,
    n_per_panel: int = 24,
    n_chi: int = 96,
) -> NDArray[np.float64]:
    """Directional–hemispherical reflectance of ``model`` for each θi (radians).

    Parameters
    ----------
    model : BRDFModel
    params : array_like, shape (k,)
    theta_i : array_like, shape (N,) or scalar
        Incidence polar angles in [0, π/2].
    phi_i : float
        Incidence azimuth (matters only for anisotropic models).
    method : {"hemisphere", "mirror"}
        See the module docstring; use "mirror" with ``lobe_width`` ≈ the lobe's angular
        width for sharp lobes.

    Returns
    -------
    ndarray, shape of ``theta_i``
        ρ(θi) (dimensionless). For flatland models (unit 1/rad) this is meaningless; use
        :func:`flatland_reflectance`.
    """
    ti = np.atleast_1d(np.asarray(theta_i, dtype=float))
    out = np.empty(ti.shape)
    for idx, t in np.ndenumerate(ti):
        wi = np.array([np.sin(t) * np.cos(phi_i), np.sin(t) * np.sin(phi_i), np.cos(t)])
        if method == "hemisphere":
            q = hemisphere_quadrature(n_mu, n_phi)
        elif method == "mirror":
            mirror = np.array([-wi[0], -wi[1], wi[2]])
            q = _mirror_quadrature(mirror, lobe_width, n_per_panel, n_chi)
        else:
            raise ValueError("method must be 'hemisphere' or 'mirror'")
        g = geometry_from_vectors(wi[None, :], q.omega_r)
        out[idx] = float(np.sum(model.evaluate_geometry(params, g) * q.weights))
    return out.reshape(np.shape(theta_i)) if np.ndim(theta_i) else out[0]


def flatland_reflectance(
    model: BRDFModel, params: ArrayLike, theta_in: ArrayLike, *, n_theta: int = 2001
) -> NDArray[np.float64]:
    """∫_{−π/2}^{π/2} f(θo, θm) cos θm dθm for a flatland (1/rad) model in the plane φ = 0,
    θo the signed incoming angle (Sasaki 2020, ch. 2); trapezoid rule on ``n_theta`` points."""
    tin = np.atleast_1d(np.asarray(theta_in, dtype=float))
    tm = np.linspace(-np.pi / 2, np.pi / 2, n_theta)
    # signed flatland angle s_i = atan2(−x_i, z_i): incidence from φi = π for s_i > 0.
    theta_i = np.abs(tin)[:, None]
    phi_i = np.where(tin >= 0, np.pi, 0.0)[:, None]
    theta_r = np.abs(tm)[None, :]
    phi_r = np.where(tm >= 0, 0.0, np.pi)[None, :]
    f = model.evaluate(params, theta_i, phi_i, theta_r, phi_r)
    res = np.trapezoid(f * np.cos(tm)[None, :], tm, axis=1)
    # np.trapezoid's stubs allow a scalar; along axis 1 of a 2-D array it is an array
    return res.reshape(np.shape(theta_in)) if np.ndim(theta_in) else res[0]  # type: ignore[index, return-value]


@dataclass(frozen=True)
class DHRResult:
    """Directional–hemispherical reflectance of a fitted model with its uncertainty.

    Attributes
    ----------
    theta_i : ndarray, shape (N,)
        Incidence angles, radians.
    value, stderr : ndarray, shape (N,)
        ρ(θi) and its 1σ uncertainty (delta method through the fit covariance).
    exceeds_one : ndarray of bool, shape (N,)
        ρ − 2σ > 1: the fitted model violates energy conservation significantly there
        (a physical check for reports; expected for the original Oren–Nayar near grazing).
    """

    theta_i: NDArray[np.float64]
    value: NDArray[np.float64]
    stderr: NDArray[np.float64]
    exceeds_one: NDArray[np.bool_]


def fitted_dhr(
    model: BRDFModel,
    fit: FitResult,
    theta_i: ArrayLike,
    *,
    rel_step: float = 1e-4,
    **quadrature: Any,
) -> DHRResult:
    """DHR of a fitted model at each θi with σ from ∇_p ρ (central differences of the
    quadrature, which is linear in f) and the fit covariance. ``quadrature`` is passed to
    :func:`dhr` (e.g. ``method="mirror", lobe_width=0.02`` for sharp lobes)."""
    if fit.param_names != model.param_names:
        raise ValueError(f"fit is of {fit.model_name!r}, not of {model.name!r}")
    ti = np.atleast_1d(np.asarray(theta_i, dtype=float)).reshape(-1)
    p = np.asarray(fit.params, dtype=float)
    val = np.asarray(dhr(model, p, ti, **quadrature), dtype=float).reshape(-1)
    grad = np.empty((ti.size, p.size))
    for j in range(p.size):
        h = rel_step * max(abs(p[j]), 1e-3)
        up, dn = p.copy(), p.copy()
        up[j] += h
        dn[j] = max(dn[j] - h, model.lower[j])
        fu = np.asarray(dhr(model, up, ti, **quadrature), dtype=float).reshape(-1)
        fd = np.asarray(dhr(model, dn, ti, **quadrature), dtype=float).reshape(-1)
        grad[:, j] = (fu - fd) / (up[j] - dn[j])
    var = np.einsum("ni,ij,nj->n", grad, fit.covariance, grad)
    se = np.sqrt(np.maximum(var, 0.0))
    return DHRResult(ti, val, se, val - 2.0 * se > 1.0)
