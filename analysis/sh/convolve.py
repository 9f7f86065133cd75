"""Spherical convolution B_lm = A_l L_lm and Wiener deconvolution of lighting.

Mahajan, Ramamoorthi & Curless (ECCV 2006), eqs. 4, 5 and 7 (tagged M4, M5, M7 below);
Ramamoorthi & Hanrahan (SIGGRAPH 2001). The Wiener filter
A*_l = A_l / (A_l² + K_l) never divides by zero: bands with A_l = 0 exactly (odd l > 1 for a
Lambertian kernel) are unobservable and are returned as zero with a flag, and K_l > 0 is
chosen per band from the noise level as K_l = σ² / P_L(l) (the per-band Wiener choice), σ² the
noise variance of one coefficient and P_L(l) a power law, both fitted to the band powers of
the image, P_B(l) = A_l² P_L(l) + σ². The effective number of recovered degrees of freedom
Σ_l (2l+1) A_l²/(A_l² + K_l) and the K_l actually used are reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.sh.convention import band_slice, degrees_orders
from analysis.sh.validation import (
    SHInputError,
    check_coefficients,
    check_degree,
    check_finite,
    check_scalar,
)

__all__ = [
    "NoiseEstimate",
    "WienerResult",
    "band_power",
    "convolve",
    "estimate_coefficient_noise",
    "per_coefficient",
    "wiener_deconvolve",
]


def per_coefficient(per_band: np.ndarray, lmax: int) -> np.ndarray:
    """Expand a per-degree array (≥ lmax+1 entries) to the flat (L+1)² layout."""
    lmax = check_degree("lmax", lmax)
    v = check_finite("per_band", per_band)
    if v.ndim == 0 or v.shape[0] < lmax + 1:
        raise SHInputError("per_band", f"must hold ≥ {lmax + 1} per-band values, got shape "
                           f"{v.shape}")
    l, _ = degrees_orders(lmax)
    return v[l]


def convolve(lighting: np.ndarray, filt: np.ndarray) -> np.ndarray:
    """B_lm = A_l L_lm (M4/M5).

    Parameters
    ----------
    lighting : ndarray of shape ((L+1)², ...)
    filt : ndarray of shape (≥ L+1,)
        A_l.

    Returns
    -------
    ndarray of the shape of ``lighting``
    """
    c, lmax = check_coefficients("lighting", lighting)
    a = per_coefficient(_filter(filt, lmax, nonzero=False), lmax)
    return c * a.reshape((-1,) + (1,) * (c.ndim - 1))


def band_power(coeffs: np.ndarray) -> np.ndarray:
    """Mean power per degree, P(l) = (1/(2l+1)) Σ_m c_lm², shape (L+1,)."""
    c, lmax = check_coefficients("coeffs", coeffs)
    return np.array([np.mean(c[band_slice(l)] ** 2) for l in range(lmax + 1)])


def _filter(filt: np.ndarray, lmax: int, *, nonzero: bool = True) -> np.ndarray:
    """The first L+1 values of a finite filter A_l (SHInputError naming ``filt``); with
    ``nonzero``, one that passes some band (a deconvolution needs one)."""
    a = check_finite("filt", filt, ndim=1)
    if a.size < lmax + 1:
        raise SHInputError("filt", f"must hold A_l for l = 0 … {lmax} ({lmax + 1} values), "
                           f"got {a.size}")
    if nonzero and not np.any(a[: lmax + 1] != 0):
        raise SHInputError("filt", "is zero in every band: nothing is observable")
    return a[: lmax + 1]


def _unobservable(filt: np.ndarray, tol: float) -> np.ndarray:
    a = np.abs(filt)
    return a <= tol * a.max()


@dataclass(frozen=True)
class NoiseEstimate:
    """Noise σ of one coefficient and the number of coefficients it rests on."""

    sigma: float
    n_used: int


def estimate_coefficient_noise(
    coeffs: np.ndarray,
    filt: np.ndarray,
    *,
    null_tol: float = 1e-12,
    negligible: float = 1e-3,
) -> NoiseEstimate:
    """Noise σ of one coefficient, estimated from bands that hold no signal.

    Bands with A_l = 0 (exact null space, e.g. odd l > 1 for Lambert) contain only noise;
    when there are none, bands with |A_l| < ``negligible``·max|A| are used. Robust scale:
    1.4826 · median |c| of those coefficients (the MAD of zero-mean Gaussian noise).

    Returns
    -------
    NoiseEstimate

    Raises
    ------
    ValueError
        When no band is signal-free: pass the noise level explicitly then.
    """
    c, lmax = check_coefficients("coeffs", coeffs)
    a = _filter(filt, lmax)
    null_tol = check_scalar("null_tol", null_tol, low=0.0, high=1.0, high_open=True)
    negligible = check_scalar("negligible", negligible, low=0.0, high=1.0, high_open=True)
    null = _unobservable(a, null_tol)
    if not null.any():
        null = np.abs(a) < negligible * np.abs(a).max()
    if not null.any():
        raise SHInputError("filt", "leaves no signal-free band to estimate the noise from; "
                           "pass noise_sigma")
    vals = np.concatenate([c[band_slice(l)] for l in np.nonzero(null)[0]])
    return NoiseEstimate(float(1.4826 * np.median(np.abs(vals))), int(vals.size))


@dataclass(frozen=True)
class WienerResult:
    """Result of :func:`wiener_deconvolve`.

    Attributes
    ----------
    coeffs : ndarray of shape ((L+1)²,)
        Estimated lighting L̂_lm; exactly 0 in unobservable bands.
    gain : ndarray of shape (L+1,)
        A*_l = A_l/(A_l² + K_l) actually applied (0 where unobservable).
    k : ndarray of shape (L+1,)
        K_l used (nan where unobservable, where no K applies).
    unobservable : ndarray of bool, shape (L+1,)
        Bands with A_l = 0: no information, returned as zero.
    dof : float
        Effective recovered degrees of freedom Σ (2l+1) A_l²/(A_l² + K_l).
    noise_sigma : float
        Noise σ used to choose K: the given one as it is, else the larger of the estimated
        level and the floor fitted to the band powers (nan when K was given).
    spectrum_slope : float
        Exponent p of the fitted lighting spectrum P_L(l) ∝ (l+1)^−p (nan when K was given).
    """

    coeffs: np.ndarray
    gain: np.ndarray
    k: np.ndarray
    unobservable: np.ndarray
    dof: float
    noise_sigma: float
    spectrum_slope: float


def _fit_lighting_spectrum(
    b: np.ndarray, a: np.ndarray, sigma_min: float, observable: np.ndarray,
    *, fixed_floor: bool = False,
) -> tuple[np.ndarray, float, float]:
    """Fit P_B(l) = A_l² c (l+1)^−p + n² to the band powers of the image.

    The noise floor n² is fitted too (bounded below by ``sigma_min``²): what stops the
    inverse filter in practice is every error that does not follow the convolution model
    (noise, and in a real image the departures of the sphere from the ideal kernel), and
    the band powers show it as the floor they level off to where A_l² P_L is small. With
    ``fixed_floor`` (a noise level the caller knows) n = ``sigma_min`` exactly and only c
    and p are fitted: with a few bands a free floor can absorb all the power and call the
    whole image noise. The slope is bounded to 0 ≤ p ≤ 8 (lighting power does not grow
    with l). Least squares on log P_B with weights 2l+1, the number of coefficients per
    band.

    Returns
    -------
    p_l : ndarray of shape (L+1,)
        Fitted lighting power per band.
    slope : float
    floor_sigma : float
        √n², the noise level used for K.
    """
    from scipy.optimize import least_squares

    lmax = a.size - 1
    pb = band_power(b)
    l = np.arange(lmax + 1)
    use = observable & (pb > 0)
    tiny = np.finfo(float).tiny
    if use.sum() < 3:
        # Too few bands for a spectrum: a flat lighting power, the band power above the
        # noise (the known noise when given).
        pool = pb[use] if use.any() else pb
        if fixed_floor:
            a2 = a[use] ** 2 if use.any() else np.ones(1)
            level = max(float(np.mean(np.maximum(pool - sigma_min**2, 0.0) / a2)), tiny)
            return np.full(lmax + 1, level), 0.0, sigma_min
        level = max(float(np.mean(pool)), tiny)
        return np.full(lmax + 1, level), 0.0, max(sigma_min, np.sqrt(tiny))
    a2 = a[use] ** 2
    x = np.log(l[use] + 1.0)
    y = np.log(pb[use])
    w = np.sqrt(2.0 * l[use] + 1.0)
    floor_min = max(sigma_min**2, tiny)
    log_fixed = np.log(sigma_min**2) if fixed_floor and sigma_min > 0 else -np.inf

    def model(q: np.ndarray) -> np.ndarray:
        log_c, slope, log_n2 = (*q, log_fixed) if fixed_floor else q
        return np.logaddexp(np.log(a2) + log_c - slope * x, log_n2)

    start = np.array([
        float(np.log(max(pb[use][0] / a2[0], tiny))),
        2.0,
        float(np.log(max(np.min(pb[use]), floor_min))),
    ])
    lo = [-np.inf, 0.0, np.log(floor_min)]
    hi = [np.inf, 8.0, np.inf]
    n_free = 2 if fixed_floor else 3
    lo, hi, start = lo[:n_free], hi[:n_free], start[:n_free]
    start = np.clip(start, np.array(lo) + 1e-9, np.array(hi) - 1e-9)
    sol = least_squares(lambda q: w * (model(q) - y), start, bounds=(lo, hi))
    log_c, slope = sol.x[:2]
    p_l = np.exp(log_c - slope * np.log(l + 1.0))
    floor = sigma_min if fixed_floor else float(np.sqrt(np.exp(sol.x[2])))
    return p_l, float(slope), floor


def wiener_deconvolve(
    image_coeffs: np.ndarray,
    filt: np.ndarray,
    *,
    noise_sigma: float | None = None,
    k: float | np.ndarray | None = None,
    null_tol: float = 1e-12,
) -> WienerResult:
    """Lighting from the SH coefficients of an image of known BRDF (M7).

    L̂_lm = A*_l B_lm, A*_l = A_l / (A_l² + K_l).

    Parameters
    ----------
    image_coeffs : ndarray of shape ((L+1)²,)
        B_lm.
    filt : ndarray of shape (≥ L+1,)
        A_l of the BRDF (:mod:`analysis.sh.filters`).
    noise_sigma : float, optional
        Noise σ ≥ 0 of one coefficient of B, when known: used as it is for K_l = σ²/P_L(l)
        (only the lighting spectrum is fitted). When not given it is estimated from
        signal-free bands with :func:`estimate_coefficient_noise` and serves as a lower
        bound for a noise floor fitted to the band powers (see ``_fit_lighting_spectrum``).
    k : float or ndarray of shape (L+1,), optional
        Explicit regularisation (scalar or per band), finite and > 0 in observable bands.
        Overrides the automatic choice.
    null_tol : float
        |A_l| ≤ null_tol·max|A| counts as an exact zero (unobservable band).

    Returns
    -------
    WienerResult
    """
    b, lmax = check_coefficients("image_coeffs", image_coeffs)
    if b.ndim != 1:
        raise SHInputError("image_coeffs", f"must be one vector of (L+1)² coefficients, got "
                           f"shape {b.shape}")
    a = _filter(filt, lmax)
    null_tol = check_scalar("null_tol", null_tol, low=0.0, high=1.0, high_open=True)
    if noise_sigma is not None:
        noise_sigma = check_scalar("noise_sigma", noise_sigma, low=0.0)
    unobs = _unobservable(a, null_tol)
    observable = ~unobs
    slope = float("nan")
    sigma_used = float("nan")
    if k is not None:
        k_in = check_finite("k", k)
        if k_in.ndim > 1 or (k_in.ndim == 1 and k_in.size != lmax + 1):
            raise SHInputError("k", f"must be a scalar or {lmax + 1} per-band values, got "
                               f"shape {k_in.shape}")
        k_arr = np.broadcast_to(k_in, (lmax + 1,)).copy()
        if np.any(k_arr[observable] <= 0):
            raise SHInputError("k", "must be > 0 (K = 0 is the unstable inverse filter)")
    else:
        known = noise_sigma is not None
        if not known:
            try:
                noise_sigma = estimate_coefficient_noise(b, a, null_tol=null_tol).sigma
            except SHInputError:
                noise_sigma = 0.0  # the fitted floor alone sets the level
        assert noise_sigma is not None  # given, or estimated just above
        p_l, slope, sigma_used = _fit_lighting_spectrum(b, a, float(noise_sigma), observable,
                                                        fixed_floor=known)
        k_arr = sigma_used**2 / p_l
    gain = np.zeros(lmax + 1)
    gain[observable] = a[observable] / (a[observable] ** 2 + k_arr[observable])
    k_out = np.where(observable, k_arr, np.nan)
    coeffs = b * per_coefficient(gain, lmax)
    l = np.arange(lmax + 1)
    frac = np.zeros(lmax + 1)
    frac[observable] = a[observable] ** 2 / (a[observable] ** 2 + k_arr[observable])
    dof = float(np.sum((2 * l + 1) * frac))
    return WienerResult(coeffs, gain, k_out, unobs, dof, sigma_used, slope)
