"""Significance of located objects from the reconstruction's own noise model.

The localiser (:mod:`.localize`) fits point responses ``a_k K(θ − θ*_k(c))`` to the
reconstructed rays ``g(c, θ) = L cos θ`` of the solvable domain.  Their amplitudes are
linear in the data, so their noise follows from the noise of ``g``:

* Noise of the reconstruction (closed form, Sasaki 2020 eqs. 2-32/33 and ADR 0030): the
  Fourier coefficient of order p of a wall point's ``g`` carries the measured coefficient's
  noise divided by the gain and passed through the filter, variance ``v_p = φ_p² N_p`` with
  ``N_p = σ_p²/|S_pp|²`` (``RegularizationResult.noise_power``).  The noise is stationary
  in θ, so ``Cov(g_i, g_j) = Σ_p v_p e_p(θ_i) e_p*(θ_j)`` and a real weight ``m`` on the
  samples has ``mᵀ C m = n² Σ_p v_p |M_p|²`` with ``M_p`` its coefficients
  (:func:`.spectral.coefficients`, ``X_p = (1/n) Σ_j x_j e_p*(θ_j)``).  Different wall
  points are taken as independent.  They are not quite: the curves of neighbouring points
  interpolate overlapping camera samples (measured on the validation benchmark's 1 mm
  grids, the reconstruction noise's correlation between neighbouring rows is 0.16, −0.08
  and 0.04 at 1, 2 and 3 rows), and the spread of a point's significance over noise
  fields is 1.09–1.21 rather than 1 (``benchmarks/bench_lightfield_null.py``; the
  empirical false-alarm rate per scan is measured in
  ``benchmarks/bench_lightfield_validation.py``).
* Amplitudes of K responses at fixed positions, least squares on the rays with design
  ``X`` (n_rays, K): ``â = (XᵀX)⁻¹ Xᵀ g`` and ``Cov(â) = (XᵀX)⁻¹ XᵀCX (XᵀX)⁻¹``
  (generalised least squares' sandwich form for an unweighted fit).  Where the fit's
  residual exceeds what the noise explains (model mismatch: extended objects, light from
  outside the domain), the covariance is scaled by the ratio (the Birge ratio, the usual
  reduced-χ² scaling), so a mismatch artefact is judged against the mismatch, not the noise.
  The ratio is taken per amplitude, on its own rays: the residual power weighted by the
  squared response, ``Σ_i x_ik² r_i² / (v̄ Σ_i x_ik²)`` with ``v̄ = Σ_p v_p`` the variance
  of one ray — a weighted reduced χ².  A bright object that the point model fits badly
  (an object near the wall, larger than the blur, or seen partly from outside the solvable
  domain) leaves its residual on its own ray fan; a whole-field average dilutes it over
  the rays that do not see it, and the artefacts where its fan crosses other points' rays
  then cleared the threshold as phantoms (benchmarks/bench_lightfield_validation.py,
  scene "near").  The larger of the local and the whole-field ratio is used, so no
  candidate is judged against less misfit than the fit has as a whole.  With noise alone
  both are ≈ 1, so the false-alarm rate is unchanged.
* Significance ``s_k = â_k / sd(â_k)`` in standard deviations; one-sided (a radiance is
  not negative).  A scan searches a region of positions: the false-alarm probability
  *per scan* of a pure-noise peak above s is that of the maximum of the noise's
  significance field over the region, the expected Euler characteristic of its excursion
  set (:mod:`.excursion`; Worsley et al. 1996), and the threshold for a per-scan
  false-alarm rate α solves it for α.  :func:`snr_threshold` and
  :func:`false_alarm_probability` keep the count of independent cells (``N Q(s)``,
  Bonferroni) for a detection without a noise model and for the equivalent count the
  localiser reports.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr, ndtri

from .spectral import coefficients

__all__ = [
    "AmplitudeFit",
    "amplitude_fit",
    "depth_span",
    "false_alarm_probability",
    "likelihood_region",
    "snr_threshold",
    "with_leak",
]


@dataclass(frozen=True)
class AmplitudeFit:
    """Linear amplitudes of fixed point responses and their noise.

    Attributes
    ----------
    amplitudes : (K,) — least-squares amplitudes (radiance units)
    sigma : (K,) — their standard deviations (noise model × mismatch scaling)
    significance : (K,) — ``amplitudes / sigma`` in standard deviations
    mismatch : float — residual over its noise expectation (≥ 1; 1: noise explains it),
        over all the fitted rays (each ``sigma`` uses the ratio on its own rays)
    """

    amplitudes: NDArray[np.float64]
    sigma: NDArray[np.float64]
    significance: NDArray[np.float64]
    mismatch: float


def amplitude_fit(
    g_rays: NDArray[Any], responses: NDArray[Any], use: NDArray[np.bool_], phi: ArrayLike,
    noise_power: ArrayLike,
) -> AmplitudeFit:
    """Amplitudes of ``responses`` (K, R, n_use) in the data ``g_rays`` (R, n_use) with the
    noise of the reconstruction (module doc).

    ``use`` (N,) marks the rays of the solvable domain on the full angle grid, ``phi`` (N,)
    the filter factors and ``noise_power`` (N,) the ``σ_p²/|S_pp|²`` of the reconstruction
    (both in fftfreq order; infinite noise power where the filter passes nothing counts 0).
    """
    k = responses.shape[0]
    n = use.size
    x = responses.reshape(k, -1).T
    ginv, amp = _least_squares(x, g_rays.ravel())
    phi_ = np.asarray(phi, dtype=float)
    npw = np.asarray(noise_power, dtype=float)
    v = np.where((phi_ > 0) & np.isfinite(npw), phi_**2 * np.where(np.isfinite(npw), npw, 0.0),
                 0.0)
    full = np.zeros((*responses.shape[:2], n))
    full[..., use] = responses
    m = coefficients(full, axis=-1)  # (K, R, N)
    weighted = m * v
    xcx = (n * n) * np.einsum("krp,lrp->kl", weighted, m.conj()).real
    cov = ginv @ xcx @ ginv
    resid = g_rays.ravel() - x @ amp
    per_ray = float(v.sum())  # the noise variance of one ray (C's diagonal)
    expected = g_rays.size * per_ray  # trace of C over the fitted rays
    mismatch = max(1.0, float(resid @ resid) / expected) if expected > 0 else 1.0
    # each amplitude is judged on its own rays: the residual power over its noise
    # expectation, weighted by the response's square (where its information lies)
    w = x**2
    local = ((w.T @ resid**2) / np.maximum(w.sum(axis=0) * per_ray, 1e-300)
             if per_ray > 0 else np.ones(k))
    # never below the whole fit's ratio: clean rays of one candidate do not make the
    # model's misfit elsewhere irrelevant to it (on the brushed metal a far candidate at
    # the edge of the searched range cleared 4.6σ on its own rays alone)
    sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None) * np.maximum(local, mismatch))
    signif = np.where(sigma > 0, amp / np.where(sigma > 0, sigma, 1.0), np.inf)
    return AmplitudeFit(amp, sigma, signif, mismatch)


def _least_squares(
    x: NDArray[Any], y: NDArray[Any]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``((XᵀX)⁺, X⁺ y)`` from the SVD of ``X`` with unit-norm columns, not from ``XᵀX``.

    The normal equations square the condition number: two overlapping point responses
    (a pair one blur apart) made ``pinv(XᵀX)`` lose half the digits, and behind the brushed
    metal the located objects then depended on how many threads the BLAS used (its
    blocking changes the rounding).  Scaling the columns to unit norm (Golub & Van Loan,
    *Matrix Computations*, 4th ed., §5.3.5 and §3.5.2 on equilibration) and solving on
    ``X`` itself keeps the condition number of ``X``.  Singular values below
    ``max(n, K) ε s_max`` count as zero, as ``pinv`` does.
    """
    norms = np.sqrt(np.einsum("ik,ik->k", x, x))
    d = np.where(norms > 0, norms, 1.0)
    u, s, vt = np.linalg.svd(x / d, full_matrices=False)
    keep = s > max(x.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0)
    inv_s = np.where(keep, 1.0 / np.where(keep, s, 1.0), 0.0)
    v_scaled = vt.T * inv_s  # V S⁻¹
    amp = (v_scaled @ (u.T @ y)) / d
    ginv = (v_scaled @ v_scaled.T) / np.outer(d, d)
    return ginv, amp


def with_leak(fit: AmplitudeFit, responses: NDArray[Any], share: float) -> NDArray[np.float64]:
    """Significances of ``fit`` with a systematic share of what every other response leaks
    into each one: ``s_k = a_k / hypot(σ_k, share Σ_{j≠k} |a_j ⟨K_k, K_j⟩| / ⟨K_k, K_k⟩)``
    (the localiser's model-mismatch term, :data:`.localize.MODEL_MISMATCH`).
    ``responses`` (K, R, n_use) are those the amplitudes were fitted with."""
    x = responses.reshape(responses.shape[0], -1)
    gram = x @ x.T
    leak = np.abs(gram * fit.amplitudes[None, :]) / np.diag(gram)[:, None]
    np.fill_diagonal(leak, 0.0)
    sd = np.hypot(fit.sigma, share * leak.sum(axis=1))
    return fit.amplitudes / np.where(sd > 0, sd, np.inf)


def depth_span(
    profile: ArrayLike, i_ref: int, significance: float, threshold: float
) -> tuple[int, int]:
    """Indices bounding the depths an object's data do not exclude at the detection's own
    confidence: the contiguous run around ``i_ref`` where ``Δχ²(z) = s² − s(z)² < s*²``.

    ``profile`` (N_z,) is the data's normalised matched filter along the object's line of
    sight (profiled over y; the point-source likelihood statistic, whose square is the χ²
    a point there removes), ``significance`` s the object's, ``threshold`` s* the scan's.
    The significance at depth z is taken as ``s(z) = s · profile(z)/profile(i_ref)`` (the
    statistic in units of its noise, which is the same at every trial point for a
    unit-norm kernel).  The bound ``s*²`` is the profile-likelihood interval (Wilks 1938:
    Δχ² of the profiled parameter) at the confidence the detection claims: an object at
    the threshold has no depth the data exclude, while a bright one (s ≫ s*) keeps
    ``profile/profile(i_ref) ≥ √(1 − (s*/s)²)``, a fraction of a resolution cell.
    (Behind the glossy paper a dim disc at 4.8σ against 4.2σ was placed 1.4 depth cells from
    its true depth, where the data still gave 2.8σ: Δχ² = 15 < s*² = 17.6.)
    """
    v = np.asarray(profile, dtype=float)
    ref = float(v[i_ref])
    if not (ref > 0 and np.isfinite(significance) and np.isfinite(threshold)):
        return i_ref, i_ref
    floor = max(1.0 - (threshold / significance) ** 2, 0.0) if significance > 0 else 0.0
    ratio = v / ref
    inside = (ratio > 0) & (ratio * ratio >= floor)
    lo = hi = i_ref
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    while hi < v.size - 1 and inside[hi + 1]:
        hi += 1
    return lo, hi


def likelihood_region(
    significance: ArrayLike, ref: tuple[int, ...], threshold: float
) -> NDArray[np.bool_]:
    """The trial positions an object's data do not exclude at the detection's own
    confidence: where ``Δχ² = s_best² − s² < s*²`` (and ``ref`` itself).

    ``significance`` is the object's significance s (σ) refitted at each trial position of
    a grid around it, jointly with the other objects (their amplitudes profiled out);
    ``s_best`` its maximum over the grid, ``threshold`` s* the scan's.  ``s²`` is the χ² a
    point there removes, so this is the profile-likelihood region of the position (Wilks
    1938) at the confidence the detection claims — :func:`depth_span` over both
    coordinates, on the joint fit rather than one matched-filter column.  A bright object
    keeps a fraction of its resolution cell; one near the threshold every position its
    light does not rule out, across as well as in depth.  The region is the whole level
    set, not only the part connected to ``ref``: beside a bright disc behind the glossy
    paper a dim one's data peaked twice, 6.1σ at (8, −176) mm and 5.5σ at its true
    (20, −228) mm, with a valley between (a point's response has side lobes, and the bright
    disc's leak is removed with the fit): Δχ² = 7 < s*² = 17.6, so both places are allowed.
    NaN counts as excluded.
    """
    v = np.nan_to_num(np.asarray(significance, dtype=float), nan=-np.inf)
    best = float(v.max())
    out = np.zeros(v.shape, dtype=bool)
    if np.isfinite(best) and best > 0 and np.isfinite(threshold):
        out = (v > 0) & (np.maximum(v, 0.0) ** 2 > best**2 - threshold**2)
    out[ref] = True
    return out


def snr_threshold(false_alarm_per_scan: float, n_cells: float) -> float:
    """The significance (σ) a pure-noise peak exceeds with probability
    ``false_alarm_per_scan`` somewhere among ``n_cells`` independent cells (one-sided)."""
    if not 0.0 < false_alarm_per_scan < 1.0:
        raise ValueError(f"false_alarm {false_alarm_per_scan:g} must be in (0, 1): a "
                         f"probability per scan")
    return float(-ndtri(false_alarm_per_scan / max(float(n_cells), 1.0)))


def false_alarm_probability(significance: ArrayLike, n_cells: float) -> NDArray[np.float64]:
    """Per-scan probability that noise alone gives a peak this significant:
    ``min(1, N_cells Q(s))``."""
    s = np.asarray(significance, dtype=float)
    return np.minimum(1.0, max(float(n_cells), 1.0) * ndtr(-s))
