"""Noise and conditioning diagnostics of the per-point reconstruction (Sasaki 2020,
ch. 2, eqs. 2-37 and 2-38).

Normalisation: coefficients are ``X_p = ⟨x, φ_p⟩`` (:func:`spectral.coefficients`), so white
noise of variance σ² per angle sample has ``PSD_p = E|X_p|² = σ²/N`` (Parseval; the "divide
by √N" remark after eq. 2-38).  M_0 is the mean of the measured curve.

* Degree of specularity ``γ = 1 / (1 + Σ_p |D_p|²/S_pp)`` (eq. 2-37 text);
* ``SNR = M_0/√PSD`` and the effective ``SNR_eff = M_0 γ/√PSD``;
* relative noise error per term ``Δ_p = |S_00/S_pp| √PSD_p / (M_0 γ)`` (eq. 2-37, eq. 2-38).

The sums over p skip orders where ``|S_pp| < rel_floor·max|S|``: there the specular
response is numerically zero, and dividing a small D_p by it only measures round-off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from .spectral import coefficients, fourier_orders

__all__ = [
    "Diagnostics",
    "NoiseEstimate",
    "degree_of_specularity",
    "diagnose",
    "noise_psd_from_coefficients",
    "noise_psd_from_frames",
    "relative_noise_error",
    "tail_outliers",
]

REL_FLOOR = 1e-6


def _safe_ratio(num: NDArray[Any], s: NDArray[Any], rel_floor: float) -> NDArray[Any]:
    smax = np.max(np.abs(s), axis=-1, keepdims=True)
    ok = np.abs(s) >= rel_floor * np.where(smax > 0, smax, 1.0)
    ok &= smax > 0
    return np.where(ok, num / np.where(ok, s, 1.0), 0.0)


def degree_of_specularity(
    s: ArrayLike, d: ArrayLike, *, rel_floor: float = REL_FLOOR
) -> NDArray[np.float64]:
    """γ per point from S_pp and D_p (arrays (..., N)); 0 where S ≡ 0 (purely diffuse)."""
    s_ = np.asarray(s, dtype=complex)
    d_ = np.asarray(d, dtype=complex)
    if not np.any(np.abs(s_) > 0):
        return np.zeros(np.broadcast_shapes(s_.shape, d_.shape)[:-1])
    ratio = _safe_ratio(np.abs(d_) ** 2, s_, rel_floor).real.sum(axis=-1)
    gamma = 1.0 / (1.0 + ratio)
    smax = np.max(np.abs(s_), axis=-1)
    return np.where(np.broadcast_to(smax, gamma.shape) > 0, gamma, 0.0)


def relative_noise_error(
    s: ArrayLike, m0: ArrayLike, gamma: ArrayLike, psd: ArrayLike
) -> NDArray[np.float64]:
    """Δ_p = |S_00/S_pp| √PSD_p/(|M_0| γ) (eq. 2-37); ``inf`` where S_pp = 0 or γ M_0 = 0.

    ``s`` (..., N) in fftfreq order (S_00 at index 0), ``m0`` and ``gamma`` (...),
    ``psd`` scalar or (N,).
    """
    s_ = np.abs(np.asarray(s, dtype=complex))
    den = s_ * (np.abs(np.asarray(m0))[..., None] * np.asarray(gamma)[..., None])
    num = s_[..., :1] * np.sqrt(np.asarray(psd, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0, num / np.where(den > 0, den, 1.0), np.inf)
    return out


@dataclass(frozen=True)
class NoiseEstimate:
    """Estimated noise PSD in coefficient normalisation (E|X_p|² per order).

    Attributes
    ----------
    psd : ndarray (N,) — PSD_p (constant for the white estimate)
    sigma_per_sample : float — implied per-sample standard deviation √(N·mean PSD)
    method : str — "high-frequency tail" or "repeated frames"
    n_values : int — how many |X_p|² values the estimate averages
    """

    psd: NDArray[np.float64]
    sigma_per_sample: float
    method: str
    n_values: int


def _tail(n: int, tail_fraction: float) -> NDArray[np.bool_]:
    p = np.abs(fourier_orders(n))
    cut = np.quantile(p, 1.0 - tail_fraction)
    return p >= max(cut, 1)


def noise_psd_from_coefficients(
    m_coeffs: ArrayLike, *, tail_fraction: float = 0.25, valid_rows: ArrayLike | None = None
) -> NoiseEstimate:
    """White-noise PSD from the high-|p| tail of measured coefficients (eq. 2-38 remark).

    The specular lobe low-passes the object (``S_pp`` decays), so the top ``tail_fraction``
    of orders holds noise only.  Each point's mean tail power is Gamma(n, PSD/n)
    distributed for n tail orders; the estimate is the median over points divided by the
    Gamma median factor, so a few points with model mismatch (e.g. at a wall edge) do not
    bias it.  ``m_coeffs`` has shape (R, N).
    """
    m = np.atleast_2d(np.asarray(m_coeffs))
    if valid_rows is not None:
        m = m[np.asarray(valid_rows, dtype=bool)]
    n = m.shape[-1]
    tail = _tail(n, tail_fraction)
    per_row = (np.abs(m[:, tail]) ** 2).mean(axis=1)
    k = int(tail.sum())
    if per_row.size == 0 or k == 0:
        return NoiseEstimate(np.zeros(n), 0.0, "high-frequency tail", 0)
    psd = float(np.median(per_row)) / (stats.gamma.median(k) / k)
    return NoiseEstimate(np.full(n, psd), float(np.sqrt(psd * n)), "high-frequency tail",
                         int(per_row.size * k))


def tail_outliers(
    m_coeffs: ArrayLike, noise: NoiseEstimate, *, tail_fraction: float = 0.25,
    false_alarm: float = 1e-3,
) -> NDArray[np.bool_]:
    """Points whose high-|p| tail holds more power than noise explains (model mismatch).

    A point is flagged when its mean tail power exceeds the ``1 − false_alarm`` quantile
    of Gamma(n, PSD/n); such points (object light outside the angle domain, a wall edge
    crossing the sampled curve) are left out of pooled spectrum estimates.
    """
    m = np.atleast_2d(np.asarray(m_coeffs))
    n = m.shape[-1]
    tail = _tail(n, tail_fraction)
    k = int(tail.sum())
    per_row = (np.abs(m[:, tail]) ** 2).mean(axis=1)
    psd = float(np.mean(noise.psd[tail])) if k else 0.0
    if psd <= 0:
        return per_row > 0
    return per_row > psd * stats.gamma.ppf(1.0 - false_alarm, k) / k


def noise_psd_from_frames(frames: ArrayLike) -> NoiseEstimate:
    """PSD of one frame from repeated frames of the same curves, shape (F, R, N).

    Uses the unbiased variance across frames of each coefficient, pooled over points.
    The PSD of the frame average is this divided by F.
    """
    x = np.asarray(frames, dtype=float)
    if x.ndim == 2:
        x = x[:, None, :]
    if x.shape[0] < 2:
        raise ValueError("need at least two frames")
    c = coefficients(x, axis=-1)
    var = np.var(c, axis=0, ddof=1)  # complex var = E|X − E X|²
    psd = var.reshape(-1, x.shape[-1]).mean(axis=0).real
    return NoiseEstimate(psd, float(np.sqrt(psd.mean() * x.shape[-1])), "repeated frames",
                         int(c.size))


@dataclass(frozen=True)
class Diagnostics:
    """Per-point conditioning and noise figures of a reconstruction (eq. 2-37, eq. 2-38).

    Attributes
    ----------
    gamma : ndarray (R,) — degree of specularity
    m0 : ndarray (R,) — mean measured radiance along each curve (M_0)
    snr : ndarray (R,) — M_0/√PSD_0
    snr_eff : ndarray (R,) — M_0 γ/√PSD_0
    delta_p : ndarray (R, N) — relative noise error per order (fftfreq order)
    noise : NoiseEstimate — the PSD used
    """

    gamma: NDArray[np.float64]
    m0: NDArray[np.float64]
    snr: NDArray[np.float64]
    snr_eff: NDArray[np.float64]
    delta_p: NDArray[np.float64]
    noise: NoiseEstimate


def diagnose(
    m_coeffs: ArrayLike, s: ArrayLike, d: ArrayLike, noise: NoiseEstimate
) -> Diagnostics:
    """Compute :class:`Diagnostics` from coefficients (R, N), S (R|1, N), D (R|1, N)."""
    m = np.atleast_2d(np.asarray(m_coeffs))
    gamma = np.broadcast_to(degree_of_specularity(s, d), m.shape[:1]).copy()
    m0 = m[:, 0].real
    root = np.sqrt(max(float(noise.psd[0]), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = np.where(root > 0, np.abs(m0) / root, np.inf)
    snr_eff = snr * gamma
    delta = relative_noise_error(np.broadcast_to(s, m.shape), m0, gamma, noise.psd)
    return Diagnostics(gamma, m0, snr, snr_eff, delta, noise)
