"""Reconstruction of the hidden object's light field, one scattering point at a time.

Procedure of Sasaki 2020 (ch. 2, eqs. 2-6 … 2-38), vectorised over points c_r:

1. sample the measured field along each point's curve ``y_m = c_r + d2,r tan θ_m``;
2. take Fourier coefficients ``M_p`` on the domain [a, b] (eq. 2-13);
3. solve ``M = B̃ Õ`` in the cosine-weighted basis (eq. 2-18), where
   ``G(θ_o) = cos(θ_o − Θ_r) O(θ_o) = Σ_q Õ_q φ_q(θ_o)`` so the obliquity cancels:

   * ``solver="closed_form"`` (separable diffuse + shift-invariant specular, flat window):
     ``α = Σ_p (D_p*/S_pp) M_p / (1 + Σ_p |D_p|²/S_pp)``, ``Õ_p = (M_p − α D_p)/S_pp``
     (eq. 2-32, eq. 2-33), then regularised mode by mode (:mod:`.regularize`);
   * ``solver="general"``: B̃ from the BRDF's 2-D Fourier coefficients
     (:func:`.spectral.brdf_fourier_matrix`, or ``S_pp W_{p−q} + D_p D_q*`` for a
     separable model with a window), an SVD, and the same regularisation on the
     singular modes (truncated SVD / Wiener / Tikhonov);

4. synthesise ``G`` and divide by the obliquity: ``O_r(θ_o)``, which is the object light
   field on the object-side curve, ``L_obj(c_r − d1,r tan θ_o, θ_o) = O_r(θ_o)``.

The result is stored as the incident light field at the wall (z = 0, rows c_r): refocusing
to any depth, including the object plane (−d1), is a shear of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .brdf import FlatlandBRDF, SpatiallyVaryingBRDF
from .diagnostics import (
    REL_FLOOR,
    Diagnostics,
    NoiseEstimate,
    diagnose,
    noise_psd_from_coefficients,
    tail_outliers,
)
from .field import LightField2D
from .propagate import propagate, sample_along_curves
from .regularize import Method, RegularizationResult, regularize
from .scatter import BRDFCallable
from .spectral import (
    SeparableSpectra,
    brdf_fourier_matrix,
    coefficients,
    fourier_orders,
    separable_spectra,
    synthesize,
)

__all__ = ["CurveSolution", "Reconstruction", "reconstruct", "solve_curves"]

Solver = Literal["auto", "closed_form", "general"]


@dataclass(frozen=True)
class Reconstruction:
    """Reconstructed object light field with everything needed to judge it.

    Attributes
    ----------
    incident_field : LightField2D (R, N) — O_r(θ) as the incident field at the wall
        (z = 0); all zeros when ``recoverable`` is False
    coefficients : ndarray (R, N) complex — Õ_p (weighted basis, fftfreq order)
    orders : ndarray (N,) — the Fourier orders p
    alpha : ndarray (R,) complex — diffuse projection of eq. 2-32 (0 for the general solver)
    regularization : RegularizationResult — method, parameter, filter factors, dof, residual
    diagnostics : Diagnostics — γ, SNR, SNR_eff, Δ_p, the noise PSD used
    solver : str — "closed_form" or "general"
    recoverable : bool
    message : str — human-readable verdict, including "no recoverable object information"
    valid_fraction : ndarray (R,) — fraction of each curve inside the measured y range
    solvable_domain_rad : (float, float) — the angle range clear of the domain edges by
        three specular widths, where the periodic model holds (for localisation)
    """

    incident_field: LightField2D
    coefficients: NDArray[np.complex128]
    orders: NDArray[np.int64]
    alpha: NDArray[np.complex128]
    regularization: RegularizationResult
    diagnostics: Diagnostics
    solver: str
    recoverable: bool
    message: str
    valid_fraction: NDArray[np.float64]
    solvable_domain_rad: tuple[float, float]

    def object_samples(
        self, d1_mm: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[Any]]:
        """The result placed on the object-side curves: ``(y_o, θ, L)``.

        ``y_o[r, j] = c_r − d1,r tan θ_j`` (mm, shape (R, N)), θ (N,), L (R, N).
        """
        f = self.incident_field
        d1 = np.broadcast_to(np.asarray(d1_mm, dtype=float), f.y_mm.shape)
        y_o = f.y_mm[:, None] - d1[:, None] * np.tan(f.theta_rad)[None, :]
        return y_o, f.theta_rad, f.radiance

    def object_field(self, d1_mm: float, *, method: str = "cubic") -> LightField2D:
        """The object-plane light field on the wall's y grid (a shear by −d1)."""
        # method: a str checked by propagate itself (ValueError), not narrowed to its Literal
        return propagate(self.incident_field, -float(d1_mm), method=method)  # type: ignore[arg-type]


@dataclass(frozen=True)
class CurveSolution:
    """Result of :func:`solve_curves` for R sampled curves of N angles.

    Attributes
    ----------
    radiance : ndarray (R, N) — O_r(θ_j), object radiance on the curves (0 if unrecoverable)
    coefficients : ndarray (R, N) complex — Õ_p (weighted basis, fftfreq order)
    alpha : ndarray (R,) complex — diffuse projection of eq. 2-32 (0 for the general solver)
    regularization : RegularizationResult
    diagnostics : Diagnostics
    solver : str — "closed_form" or "general"
    recoverable : bool
    message : str
    """

    radiance: NDArray[np.float64]
    coefficients: NDArray[np.complex128]
    alpha: NDArray[np.complex128]
    regularization: RegularizationResult
    diagnostics: Diagnostics
    solver: str
    recoverable: bool
    message: str


def _is_separable(brdf: object) -> bool:
    return isinstance(brdf, FlatlandBRDF | SpatiallyVaryingBRDF)


def solve_curves(
    curves: ArrayLike,
    brdf: BRDFCallable,
    domain_rad: tuple[float, float],
    *,
    points_mm: ArrayLike | None = None,
    normal_angle_rad: ArrayLike = 0.0,
    method: Method = "wiener",
    solver: Solver = "auto",
    noise: NoiseEstimate | float | None = None,
    tau: float = 1.0,
    p_max: int | None = None,
    signal_power: ArrayLike | None = None,
    gamma_min: float = 1e-6,
    pool: ArrayLike | None = None,
) -> CurveSolution:
    """Solve the per-point problems for curves already sampled, shape (R, N).

    Returns a :class:`CurveSolution`; its radiance (R, N) lies on the cell-centred θ grid
    of ``domain_rad``.
    ``noise`` is a :class:`NoiseEstimate`, a white PSD (float, coefficient
    normalisation, σ²/N) or None to estimate it from the high-|p| tail.  ``pool`` (R,)
    marks the points allowed to shape the shared filter (default: all that pass the
    tail-outlier test).

    For a BRDF that is not a :class:`FlatlandBRDF`/:class:`SpatiallyVaryingBRDF` the
    diffuse part is not separated: its diagnostics take diag(B̃) as S_pp and D = 0 (so
    γ = 1); whether anything is recoverable is then decided by the regularisation alone
    (a rank-one, purely diffuse B̃ leaves only the level-0 singular mode).
    """
    mc = np.atleast_2d(np.asarray(curves, dtype=float))
    n_r, n = mc.shape
    a, b = domain_rad
    p = fourier_orders(n)
    m_coef = coefficients(mc, axis=-1)
    if noise is None:
        est = noise_psd_from_coefficients(m_coef)
    elif isinstance(noise, NoiseEstimate):
        est = noise
    else:
        psd = float(noise)
        est = NoiseEstimate(np.full(n, psd), float(np.sqrt(psd * n)), "given", 0)
    psd = np.broadcast_to(est.psd, (n,))
    # points whose curve is inconsistent with the model do not shape the shared filter
    pool_ok = ~tail_outliers(m_coef, est)
    if pool is not None:
        pool_ok &= np.asarray(pool, dtype=bool)
    pool = pool_ok
    tn = np.broadcast_to(np.asarray(normal_angle_rad, dtype=float), (n_r,))
    per_point_tilt = np.ndim(normal_angle_rad) > 0
    separable = _is_separable(brdf)
    if solver == "auto":
        solver = "closed_form" if separable and _flat_window(brdf) else "general"
    if solver == "closed_form" and not (separable and _flat_window(brdf)):
        raise ValueError("the closed form needs a separable BRDF with a flat window")
    pts = None if points_mm is None else np.broadcast_to(np.asarray(points_mm, float), (n_r,))

    if separable:
        # separable: brdf is a FlatlandBRDF or SpatiallyVaryingBRDF (the test above says so)
        spec = separable_spectra(brdf, domain_rad, n, points_mm=pts,  # type: ignore[arg-type]
                                 normal_angle_rad=tn if per_point_tilt else float(tn[0]))
        s_all, d_all = spec.s, spec.d
    else:
        spec = None
    alpha = np.zeros(n_r, dtype=complex)

    if solver == "closed_form":
        assert spec is not None
        s_b = np.broadcast_to(s_all, (n_r, n)) if s_all.shape[0] > 1 else s_all
        smax = np.max(np.abs(s_all), axis=-1, keepdims=True)
        use = (np.abs(s_all) >= REL_FLOOR * np.where(smax > 0, smax, 1)) & (smax > 0)
        safe = np.where(use, s_all, 1.0)
        num = np.sum(np.where(use, d_all.conj() * m_coef / safe, 0.0), axis=-1)
        den = 1.0 + np.sum(np.where(use, np.abs(d_all) ** 2 / safe, 0.0), axis=-1)
        alpha = num / den
        data = m_coef - alpha[:, None] * d_all
        reg = regularize(data, s_b, psd, method=method, levels=np.abs(p), tau=tau,
                         p_max=p_max, signal_power=signal_power, pool=pool)
        o_coef = reg.solution
        diag = diagnose(m_coef, s_all, d_all, est)
    else:
        if per_point_tilt or not getattr(brdf, "homogeneous", True):
            mats = [_b_matrix(brdf, spec, domain_rad, n, r, float(tn[r]),
                              None if pts is None else float(pts[r])) for r in range(n_r)]
            bt = np.stack(mats)
        else:
            bt = _b_matrix(brdf, spec, domain_rad, n, 0, float(tn[0]),
                           None if pts is None else float(pts[0]))[None]
        u, sv, vh = np.linalg.svd(bt)
        data = np.einsum("rpk,rp->rk", u.conj(), m_coef) if bt.shape[0] > 1 else (
            m_coef @ u[0].conj())
        noise_modes = np.einsum("rpk,p->rk", np.abs(u) ** 2, psd).mean(axis=0)
        lv = None if p_max is None else np.arange(n)
        reg = regularize(data, sv, noise_modes, method=method, levels=lv, tau=tau,
                         p_max=p_max, signal_power=signal_power, pool=pool)
        x = reg.solution
        o_coef = np.einsum("rk,rkq->rq", x, vh.conj()) if bt.shape[0] > 1 else x @ vh[0].conj()
        if spec is not None:
            diag = diagnose(m_coef, s_all, d_all, est)
        else:
            diag_s = np.stack([np.diag(bm) for bm in bt])
            diag = diagnose(m_coef, diag_s, np.zeros_like(diag_s), est)

    gamma_max = float(np.max(diag.gamma)) if diag.gamma.size else 0.0
    recoverable = reg.recoverable and gamma_max > gamma_min
    if gamma_max <= gamma_min:
        message = (
            f"no recoverable object information: the wall is (numerically) purely diffuse "
            f"(γ = {gamma_max:.2e}); the measurement holds only the diffuse total"
        )
    else:
        message = reg.message
    th = np.linspace(a, b, n, endpoint=False) + 0.5 * (b - a) / n
    if recoverable:
        g = synthesize(o_coef, axis=-1).real
        obliq = np.clip(np.cos(th[None, :] - tn[:, None]), 1e-6, None)
        obj = g / obliq
    else:
        o_coef = np.zeros_like(o_coef)
        obj = np.zeros((n_r, n))
    return CurveSolution(obj, o_coef, alpha, reg, diag, solver, recoverable, message)


def _flat_window(brdf: object) -> bool:
    base = brdf.base if isinstance(brdf, SpatiallyVaryingBRDF) else brdf
    return bool(getattr(base, "window_exponent", 1.0) == 0)


def _b_matrix(
    brdf: BRDFCallable,
    spec: SeparableSpectra | None,
    domain: tuple[float, float],
    n: int,
    r: int,
    tilt: float,
    y: float | None,
) -> NDArray[np.complex128]:
    """B̃ of point r: from the separable spectra when known, else by 2-D quadrature."""
    if spec is not None:
        return spec.matrix(r)
    return brdf_fourier_matrix(brdf, domain, n, weighted=True, normal_angle_rad=tilt,
                               y_mm=None if getattr(brdf, "homogeneous", True) else y)


def reconstruct(
    lf_meas: LightField2D,
    brdf: BRDFCallable,
    *,
    d2_mm: ArrayLike,
    points_mm: ArrayLike | None = None,
    normal_angle_rad: ArrayLike = 0.0,
    method: Method = "wiener",
    solver: Solver = "auto",
    interpolation: Literal["linear", "cubic"] = "cubic",
    noise: NoiseEstimate | float | None = None,
    tau: float = 1.0,
    p_max: int | None = None,
    gamma_min: float = 1e-6,
) -> Reconstruction:
    """Reconstruct the object light field from a measured one (eq. 2-6, eq. 2-13 … eq. 2-38).

    Parameters
    ----------
    lf_meas : LightField2D (N_m, N)
        Measured field at the measurement plane; its angle domain is [a, b].
    brdf : callable
        The wall BRDF in the unfolded frame (a :class:`FlatlandBRDF` enables the closed
        form; any ``f(θ_in, θ_out)`` works with ``solver="general"``).
    d2_mm : float or (R,)
        Wall → measurement plane distance per point (mm).
    points_mm : (R,) uniform, optional
        Scattering points c_r (default: the measurement y grid).
    normal_angle_rad : float or (R,)
        Local wall normal angle Θ_r (rad).
    method, tau, p_max : regularisation (see :func:`.regularize.regularize`).
    noise : NoiseEstimate, float or None
        Noise PSD in coefficient normalisation; None estimates it from the data.

    Returns
    -------
    Reconstruction
    """
    c = lf_meas.y_mm if points_mm is None else np.asarray(points_mm, dtype=float)
    curves, valid = sample_along_curves(lf_meas, c, d2_mm, method=interpolation)
    sol = solve_curves(
        curves, brdf, lf_meas.domain_rad, points_mm=c, normal_angle_rad=normal_angle_rad,
        method=method, solver=solver, noise=noise, tau=tau, p_max=p_max, gamma_min=gamma_min,
        pool=valid.all(axis=1),
    )
    a, b = lf_meas.domain_rad
    width = getattr(getattr(brdf, "base", brdf), "specular_width_rad", 0.0)
    margin = min(3.0 * float(width), 0.25 * (b - a))
    field = LightField2D(sol.radiance, c, lf_meas.theta_rad, lf_meas.domain_rad, 0.0)
    return Reconstruction(
        incident_field=field,
        coefficients=sol.coefficients,
        orders=fourier_orders(lf_meas.theta_rad.size),
        alpha=sol.alpha,
        regularization=sol.regularization,
        diagnostics=sol.diagnostics,
        solver=sol.solver,
        recoverable=sol.recoverable,
        message=sol.message,
        valid_fraction=valid.mean(axis=1),
        solvable_domain_rad=(a + margin, b - margin),
    )
