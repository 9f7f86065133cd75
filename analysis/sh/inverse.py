"""Inverse rendering of a diffuse + Phong BRDF (K_d, K_s, s) under known lighting.

The image of a sphere in the reflected parameterisation is (Ramamoorthi & Hanrahan,
"A signal-processing framework for inverse rendering", SIGGRAPH 2001, §5; Mahajan et al.
2008 eq. M12 with the diffuse term):

    B(pixel) = K_d/π · E(n) + K_s · Σ_l A_l(s) Σ_m L_lm Y_lm(R),

E(n) = Σ Â_l L_lm Y_lm(n) the Lambertian irradiance, A_l(s) the exact Phong filter
(:func:`analysis.sh.filters.phong_filter`). K_d and K_s enter linearly, s does not: the fit
is a nonlinear least-squares in (K_d, K_s, log s) with the standard errors from the Jacobian
at the optimum and the residual noise estimate, σ̂²(JᵀJ)⁻¹.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from analysis.sh.convention import band_slice
from analysis.sh.filters import PHONG_EXACT_MAX, lambertian_filter, phong_filter
from analysis.sh.transform import real_sh_matrix
from analysis.sh.validation import SHInputError, check_coefficients, check_finite, check_scalar

__all__ = ["PhongFit", "fit_diffuse_phong"]


@dataclass(frozen=True)
class PhongFit:
    """Result of :func:`fit_diffuse_phong`.

    Attributes
    ----------
    kd, ks, s : float
        Diffuse albedo, specular weight and Phong exponent.
    kd_std, ks_std, s_std : float
        Their standard errors (1σ).
    roughness : float
        The equivalent Torrance–Sparrow slope σ = 1/√(2s) (same l(l+1) decay of the filter).
    residual_rms : float
    noise_sigma : float
        σ̂ = √(Σ r² / (N − 3)).
    success : bool
    """

    kd: float
    ks: float
    s: float
    kd_std: float
    ks_std: float
    s_std: float
    roughness: float
    residual_rms: float
    noise_sigma: float
    success: bool


def fit_diffuse_phong(
    values: np.ndarray,
    normal_dirs: tuple[np.ndarray, np.ndarray],
    reflected_dirs: tuple[np.ndarray, np.ndarray],
    lighting: np.ndarray,
    *,
    s0: float = 20.0,
    s_bounds: tuple[float, float] = (1.0, 5000.0),
) -> PhongFit:
    """Fit (K_d, K_s, s) to sphere-image samples under known lighting.

    Parameters
    ----------
    values : ndarray of shape (N,)
        Radiance samples (e.g. interior pixels of a sphere image).
    normal_dirs : (theta, phi), each of shape (N,)
        Normal directions of the samples.
    reflected_dirs : (theta, phi), each of shape (N,)
        Reflected view directions of the samples.
    lighting : ndarray of shape ((L+1)²,)
        Known lighting; L should exceed the Phong band limit ≈ 3√s.
    s0 : float
        Starting exponent.
    s_bounds : (float, float)

    Returns
    -------
    PhongFit
    """
    v = check_finite("values", values, ndim=1)
    lig, lmax = check_coefficients("lighting", lighting)
    dirs = {}
    for name, pair in (("normal_dirs", normal_dirs), ("reflected_dirs", reflected_dirs)):
        try:
            th, ph = pair
        except (TypeError, ValueError):
            raise SHInputError(name, "must be a pair (theta, phi)") from None
        th, ph = check_finite(name, th, ndim=1), check_finite(name, ph, ndim=1)
        if not th.size == ph.size == v.size:
            raise SHInputError(name, f"must hold one direction per value ({v.size}), got "
                               f"{th.size} theta and {ph.size} phi")
        dirs[name] = (th, ph)
    s_lo = check_scalar("s_bounds", s_bounds[0], low=0.0, low_open=True)
    s_hi = check_scalar("s_bounds", s_bounds[1], low=s_lo, high=PHONG_EXACT_MAX,
                        low_open=True)
    s0 = check_scalar("s0", s0, low=s_lo, high=s_hi)
    yn = real_sh_matrix(lmax, *dirs["normal_dirs"])
    yr = real_sh_matrix(lmax, *dirs["reflected_dirs"])
    ahat = lambertian_filter(lmax).values
    l_idx = np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)
    diffuse = yn @ (ahat[l_idx] * lig) / np.pi
    bands = np.stack([yr[:, band_slice(l)] @ lig[band_slice(l)] for l in range(lmax + 1)], 1)

    def design(log_s: float) -> np.ndarray:
        spec = bands @ phong_filter(lmax, float(np.exp(log_s))).values
        return np.stack([diffuse, spec], axis=1)

    def linear(log_s: float) -> np.ndarray:
        coef, *_ = np.linalg.lstsq(design(log_s), v, rcond=None)
        return coef

    def resid(p: np.ndarray) -> np.ndarray:
        return design(p[2]) @ p[:2] - v

    kd0, ks0 = linear(np.log(s0))
    lo, hi = np.log(s_lo), np.log(s_hi)
    # Variable projection start: scan log s for the best linear fit, then polish jointly.
    grid = np.linspace(lo, hi, 25)
    costs = [np.sum((design(g) @ linear(g) - v) ** 2) for g in grid]
    g0 = float(grid[int(np.argmin(costs))])
    kd0, ks0 = linear(g0)
    sol = least_squares(resid, np.array([kd0, ks0, g0]), x_scale="jac",
                        bounds=([-np.inf, -np.inf, lo], [np.inf, np.inf, hi]))
    r = sol.fun
    n = v.size
    sigma = float(np.sqrt(r @ r / max(n - 3, 1)))
    jac = sol.jac
    cov = sigma**2 * np.linalg.pinv(jac.T @ jac)
    kd, ks, log_s = sol.x
    s = float(np.exp(log_s))
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return PhongFit(
        kd=float(kd),
        ks=float(ks),
        s=s,
        kd_std=float(std[0]),
        ks_std=float(std[1]),
        s_std=float(s * std[2]),
        roughness=float(1.0 / np.sqrt(2.0 * s)),
        residual_rms=float(np.sqrt(np.mean(r**2))),
        noise_sigma=sigma,
        success=bool(sol.success),
    )
