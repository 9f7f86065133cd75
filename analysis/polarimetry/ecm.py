"""Eigenvalue calibration method (ECM) for a separable 4-state × 4-state polarimeter.

Compain, Poirier & Drévillon 1999 (Appl. Opt. 38, 3490). A polarimeter with four
generator states (the columns of the 4×4 PSG matrix W) and four analyser states (the
rows of the 4×4 PSA matrix A) measures the 4×4 intensity matrix ``B = A · M · W``
(eq. 2). With ``B₀ = A W`` measured on air, each reference sample gives

    C_i = B₀⁻¹ B_i = W⁻¹ M_i W        (eq. 5)

a matrix similar to ``M_i``: its eigenvalues are those of the sample, whatever W and A
are. A reference sample is a linear retarder–diattenuator

    M(τ, Ψ, Δ, θ) = R(−θ) · τ [[1, cos2Ψ, 0, 0], [cos2Ψ, 1, 0, 0],
                               [0, 0, sin2Ψ cosΔ, sin2Ψ sinΔ],
                               [0, 0, −sin2Ψ sinΔ, sin2Ψ cosΔ]] · R(θ)   (eq. 7)

whose eigenvalues ``2τcos²Ψ, 2τsin²Ψ, τ sin2Ψ e^{±iΔ}`` (eq. 8) give τ, Ψ, Δ (eqs. 9–11;
Ψ = 0 is a polariser along θ, Ψ = 45° a pure retarder). Only θ is left: W solves the
linear system ``M_i W − W C_i = 0`` for every sample, i.e. W spans the null space of
``K = Σ H_iᵀ H_i`` with ``H_i = M_i ⊗ 1 − 1 ⊗ C_iᵀ`` (row-major ``vec``, eqs. 13–16).
The orientations are those that make K's smallest eigenvalue vanish: they are found by
minimising ``μ₁/μ₂`` (eq. 17), with the first sample's orientation fixed as the
reference of the azimuths (a common rotation of everything is not observable).
The ratio ``μ₁/μ₂`` at the minimum (≈ 0 for noiseless data, ≈ noise² otherwise) and
``μ₂/μ₁₆`` (how well the null space is separated; small means a poorly conditioned
calibration) are the quality indicators.

Uncertainty. With the standard deviations of the measured intensities (``sigma_air``,
``sigma_samples``, independent readings) the calibration carries the covariance of
``(vec W, vec A)`` (row-major, 32×32). ``method="monte_carlo"`` (the default) recalibrates
``n_draws`` seeded draws of the intensities around the measured ones (JCGM 101:2008, the
GUM's Supplement 1, §7), each search started at the measured solution's orientations;
``method="linear"`` is first-order propagation ``J Σ Jᵀ`` (JCGM 100:2008, eq. 13) with
``J`` the Jacobian of the whole calibration map by central differences of one σ in each
intensity. The two agree within the Monte Carlo's sampling error where the references'
eigenvalues are well apart (partial polarisers and retarders; tested). The Monte Carlo is
the default: with ideal polarisers (Ψ = 0) the vanishing eigenvalue pair is noise, its
assignment in eqs. 9–11 is not differentiable there, and first order misstates σ by up to
a third (measured with polarisers at 0° and 90° and a retarder at 1e-3 noise).

The dual rotating retarder is not separable: its K settings change generator and analyser
together (one row ``vec(a_k g_kᵀ)`` per step), so no 4×4 ``B`` exists and ECM does not
apply directly; :mod:`analysis.polarimetry.calibration` fits the DRR's hidden parameters
by least squares on the same reference measurements instead (ADR 0102).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from analysis.polarimetry.elements import rotated
from analysis.polarimetry.validation import PolarimetryInputError, check_array

__all__ = ["EcmCalibration", "ReferenceSample", "ecm_calibrate", "retarder_diattenuator"]


def retarder_diattenuator(theta_rad: float, tau: float, psi_rad: float,
                          delta_rad: float) -> NDArray[np.float64]:
    """The reference-sample model of Compain et al. 1999, eq. 7 (shape (4, 4))."""
    c2, s2 = math.cos(2 * psi_rad), math.sin(2 * psi_rad)
    cd, sd = math.cos(delta_rad), math.sin(delta_rad)
    m0 = tau * np.array([[1.0, c2, 0, 0], [c2, 1.0, 0, 0],
                         [0, 0, s2 * cd, s2 * sd], [0, 0, -s2 * sd, s2 * cd]])
    return rotated(m0, theta_rad)


@dataclass(frozen=True)
class ReferenceSample:
    """One reference sample as ECM recovers it (Compain et al. 1999, eqs. 7–11).

    Attributes
    ----------
    tau : float
        Mean transmittance τ.
    psi_deg : float
        Ψ in degrees (0: a polariser along θ; 45: a pure retarder).
    retardance : float
        Δ in radians, in [0, π].
    theta_deg : float
        Orientation, degrees, relative to the first reference sample.
    """

    tau: float
    psi_deg: float
    retardance: float
    theta_deg: float

    def mueller(self) -> NDArray[np.float64]:
        """The sample's Mueller matrix."""
        return retarder_diattenuator(math.radians(self.theta_deg), self.tau,
                                     math.radians(self.psi_deg), self.retardance)


@dataclass(frozen=True)
class EcmCalibration:
    """The result of :func:`ecm_calibrate`.

    Attributes
    ----------
    w : ndarray of shape (4, 4)
        PSG matrix (columns: the generated Stokes vectors), up to a common scale.
    a : ndarray of shape (4, 4)
        PSA matrix (rows: the analyser vectors), ``B₀ W⁻¹``.
    samples : tuple of ReferenceSample
        The reference samples' recovered parameters, in the order given.
    eigenvalue_ratio : float
        ``μ₁/μ₂`` of K at the solution (≈ 0 when the model fits).
    separation : float
        ``μ₂/μ₁₆``: how well the null space is separated from the rest.
    cov : ndarray of shape (32, 32) or None
        Covariance of ``concatenate([vec W, vec A])`` (row-major), None when no σ of the
        intensities was given (module docstring).
    cov_method : str
        How ``cov`` was found (``""`` without it).
    """

    w: NDArray[np.float64]
    a: NDArray[np.float64]
    samples: tuple[ReferenceSample, ...]
    eigenvalue_ratio: float
    separation: float
    cov: NDArray[np.float64] | None = None
    cov_method: str = ""

    @property
    def cov_w(self) -> NDArray[np.float64] | None:
        """Covariance of ``vec W`` (16×16), or None."""
        return None if self.cov is None else self.cov[:16, :16]

    @property
    def cov_a(self) -> NDArray[np.float64] | None:
        """Covariance of ``vec A`` (16×16), or None."""
        return None if self.cov is None else self.cov[16:, 16:]

    def instrument_matrix(self) -> NDArray[np.float64]:
        """The 16×16 instrument matrix ``A ⊗ Wᵀ``: ``vec(B) = (A ⊗ Wᵀ) vec(M)`` (row-major).

        Pass it with ``vec(B)`` and its σ to :func:`analysis.polarimetry.drr.reduce`.
        """
        return np.asarray(np.kron(self.a, self.w.T), dtype=np.float64)

    def mueller(self, b: ArrayLike) -> NDArray[np.float64]:
        """``M = A⁻¹ B W⁻¹`` for a measured 4×4 intensity matrix (no covariance)."""
        bm = check_array("b", b, shape=(4, 4))
        return np.asarray(np.linalg.solve(self.a, bm) @ np.linalg.inv(self.w), dtype=np.float64)


def _sample_from_eigenvalues(c: NDArray[np.float64], name: str) -> tuple[float, float, float]:
    """(τ, Ψ, Δ) from the eigenvalues of ``C_i`` (Compain et al. 1999, eqs. 9–11)."""
    lam = np.linalg.eigvals(c)
    scale = float(np.max(np.abs(lam)))
    if scale <= 0:
        raise PolarimetryInputError(name, "transmits nothing: its eigenvalues are all zero")
    order = np.argsort(-np.abs(lam.imag))
    if abs(lam[order[0]].imag) > 1e-9 * scale:
        comp = lam[order[:2]]
        real = np.sort(lam[order[2:]].real)[::-1]
    else:  # Δ = 0 or π: the "complex" pair is real, the middle two of four
        srt = np.sort(lam.real)[::-1]
        real = np.array([srt[0], srt[3]])
        comp = srt[1:3].astype(complex)
    r1, r2 = (max(float(v), 0.0) for v in real)
    tau = 0.5 * (r1 + r2)
    psi = math.atan(math.sqrt(r2 / r1)) if r1 > 0 else math.pi / 4
    c1 = comp[0] if comp[0].imag >= 0 else comp[1]
    delta = abs(math.atan2(float(c1.imag), float(c1.real)))
    return tau, psi, delta


def _k_matrix(models: Sequence[NDArray[np.float64]],
              cs: Sequence[NDArray[np.float64]]) -> NDArray[np.float64]:
    eye = np.eye(4)
    k = np.zeros((16, 16))
    for m, c in zip(models, cs, strict=True):
        h = np.kron(m, eye) - np.kron(eye, c.T)
        k += h.T @ h
    return k


def _solve(b0: NDArray[np.float64], bs: Sequence[NDArray[np.float64]],
           th0: NDArray[np.float64], *, search: bool) -> EcmCalibration:
    """One calibration; ``search`` runs the coarse azimuth grid before the local search
    (off for the draws of the uncertainty, which start at the measured solution)."""
    cs = [np.asarray(np.linalg.solve(b0, b), dtype=np.float64) for b in bs]
    params = [_sample_from_eigenvalues(c, f"b_samples[{i}]") for i, c in enumerate(cs)]

    def models(free: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        thetas = np.concatenate([[th0[0]], free])
        return [retarder_diattenuator(math.radians(t), *p) for t, p in zip(thetas, params,
                                                                           strict=True)]

    def ratio(free: NDArray[np.float64]) -> float:
        mu = np.linalg.eigvalsh(_k_matrix(models(free), cs))
        return float(mu[0] / mu[1]) if mu[1] > 0 else 0.0

    free0 = th0[1:].copy()
    if search:
        # a coarse grid (±10° around the nominal) before a local search: the ratio has
        # local minima 90° apart for polarisers, so the start must be near the true azimuths
        grid = np.arange(-10.0, 10.01, 2.0)
        for i in range(free0.size):
            trial = [free0.copy() for _ in grid]
            for t, g in zip(trial, grid, strict=True):
                t[i] += g
            free0 = trial[int(np.argmin([ratio(t) for t in trial]))]
    options: dict[str, object] = {"xatol": 1e-7, "fatol": 1e-16, "maxiter": 4000}
    if not search:
        # a draw's azimuths lie within a few σ (≪ 0.1°) of the start: a small simplex,
        # and 1e-5° is far below any σ of them
        options.update(xatol=1e-5, fatol=1e-14, initial_simplex=free0 + np.vstack(
            [np.zeros(free0.size), 0.02 * np.eye(free0.size)]))
    res = optimize.minimize(ratio, free0, method="Nelder-Mead", options=options)
    mods = models(np.asarray(res.x))
    mu, vecs = np.linalg.eigh(_k_matrix(mods, cs))
    w = vecs[:, 0].reshape(4, 4)
    w = w * (np.sign(w[0, 0]) or 1.0) / np.linalg.norm(w) * 2.0
    a = b0 @ np.linalg.inv(w)
    thetas = np.concatenate([[th0[0]], res.x])
    samples = tuple(ReferenceSample(tau=p[0], psi_deg=math.degrees(p[1]), retardance=p[2],
                                    theta_deg=float(t)) for p, t in zip(params, thetas,
                                                                       strict=True))
    return EcmCalibration(w=w, a=a, samples=samples,
                          eigenvalue_ratio=float(mu[0] / mu[1]),
                          separation=float(mu[1] / mu[-1]))


def _vec(cal: EcmCalibration) -> NDArray[np.float64]:
    return np.concatenate([cal.w.ravel(), cal.a.ravel()])


_METHODS = ("monte_carlo", "linear")


def ecm_calibrate(b_air: ArrayLike, b_samples: Sequence[ArrayLike],
                  theta0_deg: Sequence[float], *, sigma_air: ArrayLike | None = None,
                  sigma_samples: Sequence[ArrayLike] | None = None,
                  method: str = "monte_carlo", n_draws: int = 200,
                  seed: int = 0) -> EcmCalibration:
    """Calibrate a separable polarimeter by the eigenvalue calibration method.

    Parameters
    ----------
    b_air : array_like of shape (4, 4)
        Intensity matrix ``B₀ = A W`` measured without a sample.
    b_samples : sequence of array_like of shape (4, 4)
        Intensity matrices of ≥ 2 reference samples (e.g. a polariser at 0°, the same
        at 90°, a retarder near 30°; Compain et al. use this set).
    theta0_deg : sequence of float
        Nominal orientations of the samples, degrees; the first one is held fixed (it
        defines the azimuth reference), the others start the search.
    sigma_air, sigma_samples : array_like of shape (4, 4), optional
        Standard deviations of the intensities (independent); with both, the result
        carries the covariance of ``(vec W, vec A)`` (module docstring).
    method : {"monte_carlo", "linear"}
        How that covariance is found.
    n_draws, seed : int
        Draws and seed of the Monte Carlo.

    Raises
    ------
    PolarimetryInputError
        Mis-shaped or non-finite input, fewer than 2 samples, a singular ``B₀``, σ for
        some intensities only, negative σ, an unknown method or fewer than 10 draws.
    """
    b0 = check_array("b_air", b_air, shape=(4, 4))
    bs = [check_array(f"b_samples[{i}]", b, shape=(4, 4)) for i, b in enumerate(b_samples)]
    if len(bs) < 2:
        raise PolarimetryInputError("b_samples", f"needs ≥ 2 reference samples, got {len(bs)}")
    th0 = check_array("theta0_deg", theta0_deg, shape=(len(bs),))
    if np.linalg.cond(b0) > 1e12:
        raise PolarimetryInputError("b_air", "is singular: the four generator or analyser "
                                    "states are not independent")
    if sigma_air is None and sigma_samples is None:
        return _solve(b0, bs, th0, search=True)
    if sigma_air is None or sigma_samples is None:
        raise PolarimetryInputError("sigma_air" if sigma_air is None else "sigma_samples",
                                    "give the σ of the air and of every sample's "
                                    "intensities, or neither")
    s0 = check_array("sigma_air", sigma_air, shape=(4, 4))
    ss = [check_array(f"sigma_samples[{i}]", s, shape=(4, 4))
          for i, s in enumerate(sigma_samples)]
    if len(ss) != len(bs):
        raise PolarimetryInputError("sigma_samples", f"needs {len(bs)} matrices, one per "
                                    f"sample, got {len(ss)}")
    if np.any(s0 < 0) or any(np.any(s < 0) for s in ss):
        raise PolarimetryInputError("sigma_air", "standard deviations must be ≥ 0")
    if method not in _METHODS:
        raise PolarimetryInputError("method", f"must be one of {_METHODS}, got {method!r}")
    if method == "monte_carlo" and n_draws < 10:
        raise PolarimetryInputError("n_draws", f"must be ≥ 10, got {n_draws}")
    cal = _solve(b0, bs, th0, search=True)
    start = np.array([smp.theta_deg for smp in cal.samples])
    x0 = np.concatenate([b0.ravel(), *(b.ravel() for b in bs)])
    sig = np.concatenate([s0.ravel(), *(s.ravel() for s in ss)])

    def at(x: NDArray[np.float64]) -> NDArray[np.float64]:
        parts = x.reshape(-1, 4, 4)
        return _vec(_solve(parts[0], list(parts[1:]), start, search=False))

    if method == "monte_carlo":
        rng = np.random.default_rng(seed)
        draws = np.array([at(x0 + sig * rng.standard_normal(x0.size))
                          for _ in range(n_draws)])
        cov = np.cov(draws, rowvar=False)
        how = f"Monte Carlo, {n_draws} draws, seed {seed} (JCGM 101:2008)"
    else:
        jac = np.zeros((32, x0.size))
        for i in np.flatnonzero(sig > 0):
            step = np.zeros_like(x0)
            step[i] = sig[i]
            jac[:, i] = (at(x0 + step) - at(x0 - step)) / (2.0 * sig[i])
        cov = (jac * sig**2) @ jac.T
        how = "first order, Jacobian by central differences of one σ (JCGM 100:2008)"
    return replace(cal, cov=0.5 * (cov + cov.T), cov_method=how)
