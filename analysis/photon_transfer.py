"""Photon-transfer analysis of an exposure sweep (EMVA 1288 linear camera model).

The EMVA 1288 standard (Release 3.1, 2016, and its successor Release 4.0 Linear, 2021)
describes a linear camera by (R3.1 §2.1 and §2.3):

    μ_y − μ_y.dark = K · μ_e                                   (linear signal model)
    σ²_y = K² σ²_d + σ²_q + K (μ_y − μ_y.dark)                  (photon transfer)

with K the system gain (DN/e⁻), σ_d the temporal dark noise (e⁻), σ²_q = 1/12 DN² the
quantisation noise and μ_e the mean number of photo-electrons, whose Poisson statistics give
the last term. The evaluation follows R3.1 §6.6 ("Evaluation of the measurements according
to the photon transfer method") and §6.7 ("Evaluation of linearity"):

* From each pair of frames A, B at one exposure: μ_y = ⟨y_A + y_B⟩/2 and the temporal
  variance σ²_y = ⟨((y_A − μ_A) − (y_B − μ_B))²⟩/2, which removes the fixed pattern.
  The same from a pair of dark frames at that exposure.
* The saturation point μ_y.sat is the mean at which σ²_y is largest (R3.1 §6.6).
* K is the slope of σ²_y − σ²_y.dark against μ_y − μ_y.dark, fitted through the origin over
  the points up to 70 % of the saturation signal (R3.1 §6.6).
* σ_d = √(σ²_y.dark − σ²_q) / K, σ²_y.dark extrapolated to zero exposure from the dark
  pairs (the shortest exposure's alone when one dark pair is given).
* Linearity: a straight line μ_y − μ_y.dark = a₀ + a₁·H fitted to the points between 5 % and
  95 % of the saturation signal (H ∝ exposure at constant irradiance); the relative
  deviations δ = (y − fit)/fit give LE = (max δ − min δ)/2 in per cent (R3.1 §6.7).

The evaluation itself is :func:`analysis.emva1288.evaluate_means`, shared with the full
characterization with uncertainties (:func:`analysis.emva1288.characterize`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.emva1288 import QUANTISATION_VARIANCE_DN2, evaluate_means

__all__ = ["PhotonTransferResult", "pair_statistics", "photon_transfer"]



def pair_statistics(pair: ArrayLike) -> tuple[float, float]:
    """Mean and temporal variance of a pair of frames (EMVA 1288 R3.1 §6.6).

    Parameters
    ----------
    pair : array_like, shape (2, H, W)

    Returns
    -------
    (mean_dn, variance_dn2) : tuple of float
        ``⟨y_A + y_B⟩/2`` and ``⟨((y_A − μ_A) − (y_B − μ_B))²⟩ / 2``.
    """
    arr = np.asarray(pair, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[0] != 2:
        raise ValueError(f"a pair must have shape (2, H, W), got {arr.shape}")
    a, b = arr[0], arr[1]
    mean = 0.5 * (a.mean() + b.mean())
    diff = (a - a.mean()) - (b - b.mean())
    return float(mean), float(0.5 * np.mean(diff * diff))


@dataclass(frozen=True)
class PhotonTransferResult:
    """Camera parameters from a photon-transfer sweep.

    Attributes
    ----------
    system_gain_dn_per_e : float
        K (DN/e⁻).
    system_gain_stderr : float
        Standard error of K from the regression residuals.
    read_noise_dn, read_noise_e : float
        Temporal dark noise σ_y.dark without quantisation, in DN and in e⁻ (σ_d).
    saturation_dn : float
        μ_y.sat: mean raw value at the variance maximum.
    saturation_capacity_e : float
        (μ_y.sat − μ_y.dark) / K.
    linearity_error_percent : float
        LE of R3.1 §6.7.
    mean_dn, mean_dark_dn, variance_dn2, variance_dark_dn2 : ndarray, shape (M,)
        Per-exposure pair statistics.
    gain_fit_mask, linearity_fit_mask : ndarray of bool, shape (M,)
        Points used by the two fits.
    linearity_deviation_percent : ndarray, shape (M,)
        δ for every point (NaN-free; 0 where the fit is 0).
    """

    system_gain_dn_per_e: float
    system_gain_stderr: float
    read_noise_dn: float
    read_noise_e: float
    saturation_dn: float
    saturation_capacity_e: float
    linearity_error_percent: float
    mean_dn: NDArray[np.float64]
    mean_dark_dn: NDArray[np.float64]
    variance_dn2: NDArray[np.float64]
    variance_dark_dn2: NDArray[np.float64]
    gain_fit_mask: NDArray[np.bool_]
    linearity_fit_mask: NDArray[np.bool_]
    linearity_deviation_percent: NDArray[np.float64]


def photon_transfer(
    flat_pairs: ArrayLike,
    dark_pairs: ArrayLike,
    exposures_us: ArrayLike,
    *,
    gain_fit_fraction: float = 0.7,
    linearity_range: tuple[float, float] = (0.05, 0.95),
) -> PhotonTransferResult:
    """Photon-transfer analysis of an exposure sweep at constant irradiance.

    Parameters
    ----------
    flat_pairs : array_like, shape (M, 2, H, W)
        Two frames of a uniform irradiance at each of M exposures, in DN. Include
        exposures past saturation so that the variance maximum is found.
    dark_pairs : array_like, shape (M, 2, H, W) or (2, H, W)
        Dark pairs at the same exposures (or one pair, when the dark current is
        negligible over the sweep).
    exposures_us : array_like, shape (M,)
        Exposure times (proportional to the photons per pixel at constant irradiance).
    gain_fit_fraction : float
        Upper end of the K fit as a fraction of the saturation signal (R3.1: 0.7).
    linearity_range : (low, high)
        Fractions of the saturation signal fitted for linearity (R3.1: 5 % to 95 %).

    Returns
    -------
    PhotonTransferResult

    Raises
    ------
    ValueError
        Shapes do not match, or fewer than two points fall into a fit range.
    """
    flats = np.asarray(flat_pairs)
    darks = np.asarray(dark_pairs)
    t = np.asarray(exposures_us, dtype=np.float64).reshape(-1)
    if flats.ndim != 4 or flats.shape[1] != 2:
        raise ValueError(f"flat_pairs must have shape (M, 2, H, W), got {flats.shape}")
    m = flats.shape[0]
    if t.shape != (m,):
        raise ValueError(f"exposures_us must have shape ({m},), got {t.shape}")
    if darks.ndim == 3:
        darks = darks[np.newaxis]
    if darks.ndim != 4 or darks.shape[0] not in (1, m) or darks.shape[1] != 2:
        raise ValueError(f"dark_pairs must have shape ({m}, 2, H, W) or (2, H, W)")

    stats = np.array([pair_statistics(p) for p in flats])
    dstats = np.array([pair_statistics(p) for p in darks])
    if dstats.shape[0] == 1:
        dstats = np.repeat(dstats, m, axis=0)
    mu, var = stats[:, 0], stats[:, 1]
    mu_d, var_d = dstats[:, 0], dstats[:, 1]
    ev = evaluate_means(t, mu, var, mu_d, var_d, gain_fit_fraction, linearity_range)
    k = ev.k
    read_noise_dn = float(np.sqrt(max(ev.dark_var_dn2 - QUANTISATION_VARIANCE_DN2, 0.0)))

    return PhotonTransferResult(
        system_gain_dn_per_e=k,
        system_gain_stderr=ev.k_residual_se,
        read_noise_dn=read_noise_dn,
        read_noise_e=read_noise_dn / k,
        saturation_dn=ev.sat_dn,
        saturation_capacity_e=ev.sat_signal_dn / k,
        linearity_error_percent=ev.le,
        mean_dn=mu,
        mean_dark_dn=mu_d,
        variance_dn2=var,
        variance_dark_dn2=var_d,
        gain_fit_mask=ev.gain_mask,
        linearity_fit_mask=ev.lin_mask,
        linearity_deviation_percent=ev.deviation,
    )
