"""Errors shared by every point (common scale) or correlated between points.

They are propagated into the fitted parameters, not fitted as per-point noise.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.fit import FitResult
from analysis.brdf.geometry import flat_angles, make_geometry
from analysis.brdf.model import BRDFModel


def scale_sensitivity(
    model: BRDFModel,
    params: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
) -> NDArray[np.float64]:
    """∂p/∂s: how the weighted least-squares optimum moves when all data scale by (1 + s).

    Linearised at ``params``: δp = (JᵀWJ)⁺ JᵀW f, W = diag(1/σ²), J = ∂f/∂p (the
    Gauss–Newton step towards the rescaled data; Nocedal & Wright §10.3). For a model that is
    an amplitude times a shape (ρ/π, ks·D·V) it is exactly p_amp for the amplitudes and 0 for
    the shape parameters.

    Returns
    -------
    ndarray, shape (k,)
    """
    p = np.asarray(params, dtype=float)
    g = make_geometry(*flat_angles(theta_i, phi_i, theta_r, phi_r))
    jac = model.jacobian_geometry(p, g).reshape(-1, p.size)
    f = model.evaluate_geometry(p, g).reshape(-1)
    w = 1.0 / np.broadcast_to(np.asarray(sigma, dtype=float).reshape(-1), f.shape) ** 2
    a = jac.T @ (jac * w[:, None])
    return np.linalg.pinv(a, rcond=1e-12) @ (jac.T @ (w * f))


def with_scale_uncertainty(
    fit: FitResult,
    model: BRDFModel,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
    scale_rel: float,
) -> FitResult:
    """The fit with the run's common scale uncertainty added to its covariance.

    C' = C + u_s² δp δpᵀ with δp from :func:`scale_sensitivity` (GUM, JCGM 100:2008 §5.2:
    a fully correlated input contributes the outer product of its sensitivities). Standard
    errors and correlations are recomputed; everything else is unchanged.
    """
    if scale_rel == 0.0:
        return fit
    dp = scale_sensitivity(model, fit.params, theta_i, phi_i, theta_r, phi_r, sigma=sigma)
    cov = fit.covariance + scale_rel**2 * np.outer(dp, dp)
    with np.errstate(invalid="ignore"):
        se = np.sqrt(np.diag(cov))
        corr = cov / np.outer(se, se)
    return replace(fit, covariance=cov, stderr=se, correlation=corr)


def with_correlated_uncertainty(
    fit: FitResult,
    model: BRDFModel,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
    cov: ArrayLike,
) -> FitResult:
    """The fit with errors correlated between points (covariance ``cov``, shape (n, n))
    added to its parameter covariance.

    The weighted least-squares optimum responds linearly to a data error δy:
    δp = S δy, S = (JᵀWJ)⁺ JᵀW, W = diag(1/σ²) (the Gauss–Newton step, Nocedal & Wright
    §10.3), so C' = C + S cov Sᵀ (GUM, JCGM 100:2008 §5.2, correlated inputs). The common
    scale of :func:`with_scale_uncertainty` is the special case cov = u_s² f fᵀ.
    """
    c = np.asarray(cov, dtype=float)
    if not np.any(c):
        return fit
    p = np.asarray(fit.params, dtype=float)
    g = make_geometry(*flat_angles(theta_i, phi_i, theta_r, phi_r))
    jac = model.jacobian_geometry(p, g).reshape(-1, p.size)
    if c.shape != (jac.shape[0], jac.shape[0]):
        raise ValueError(f"cov must have shape ({jac.shape[0]}, {jac.shape[0]})")
    w = 1.0 / np.broadcast_to(np.asarray(sigma, dtype=float).reshape(-1), (jac.shape[0],)) ** 2
    sens = np.linalg.pinv(jac.T @ (jac * w[:, None]), rcond=1e-12) @ (jac.T * w[None, :])
    cov_p = fit.covariance + sens @ c @ sens.T
    with np.errstate(invalid="ignore"):
        se = np.sqrt(np.diag(cov_p))
        corr = cov_p / np.outer(se, se)
    return replace(fit, covariance=cov_p, stderr=se, correlation=corr)
