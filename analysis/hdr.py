"""High-dynamic-range merge of bracketed linear raw frames (12/16 bit), in numpy.

For a camera with a known *linear* response (EMVA 1288 R3.1 §2.1) each bracket i gives an
independent estimate of the signal rate

    x_i = (y_i − d_i) / (t_i · g_i)        [DN/µs at unit relative gain]

from the raw value y_i, its dark d_i, exposure t_i (µs) and relative gain g_i. The merge is
a weighted mean of the x_i over the brackets in which the pixel is neither near saturation
nor near the dark level. This is the merge of Debevec & Malik, "Recovering high dynamic
range radiance maps from photographs", SIGGRAPH 1997, Eq. (6), with the response curve g
known to be linear so nothing is fitted; their "hat" weighting is one option. The other
is inverse-variance weighting (Robertson, Borman & Stevenson, "Estimation-theoretic
approach to dynamic range enhancement using multiple exposures", J. Electron. Imaging
12(2), 2003; Granados et al., CVPR 2010) with the EMVA 1288 noise model (R3.1 §2.3)

    σ²_y,i = K_i · (y_i − d_i) + σ²_read           [DN²],    K_i = K · g_i

so that var(x_i) = σ²_y,i / (t_i g_i)². To avoid the bias of weights computed from the
noisy values themselves, the variances are evaluated at the signal *predicted* from a
first hat-weighted estimate.

OpenCV's Debevec/Robertson merges take 8-bit input only (a 256-entry response table;
OpenCV documentation of ``cv::MergeDebevec``) and are not used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["HdrResult", "merge_hdr"]


@dataclass(frozen=True)
class HdrResult:
    """The merged frame.

    Attributes
    ----------
    rate : ndarray, shape (H, W), float64
        Dark-subtracted signal rate in DN/µs at relative gain 1 (multiply by an exposure to
        get DN, or convert to radiance with :func:`analysis.radiometry.to_radiance`).
    variance : ndarray, shape (H, W), or None
        Variance of ``rate`` from the noise model ((DN/µs)²); ``None`` when no noise model
        (``system_gain_dn_per_e`` and ``read_noise_dn``) was given.
    n_used : ndarray of int, shape (H, W)
        How many brackets contributed; 0 where the fallback below was used.
    saturated : ndarray of bool, shape (H, W)
        Near saturation in every bracket: ``rate`` comes from the shortest exposure and is
        only a lower bound.
    underexposed : ndarray of bool, shape (H, W)
        Below the dark threshold in every unsaturated bracket: ``rate`` comes from the
        longest unsaturated exposure (unbiased, but with low signal-to-noise ratio).
    """

    rate: NDArray[np.float64]
    variance: NDArray[np.float64] | None
    n_used: NDArray[np.int64]
    saturated: NDArray[np.bool_]
    underexposed: NDArray[np.bool_]


def _per_frame(value: ArrayLike | None, n: int, default: float, what: str) -> NDArray[Any]:
    if value is None:
        return np.full(n, default, dtype=np.float64)
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{what} must be a scalar or have shape ({n},), got {arr.shape}")
    return arr


def merge_hdr(
    frames: ArrayLike,
    exposures_us: ArrayLike,
    *,
    darks: ArrayLike = 0.0,
    saturation_dn: ArrayLike,
    gains: ArrayLike | None = None,
    weighting: str = "hat",
    saturation_fraction: float = 0.95,
    min_signal_dn: float | None = None,
    system_gain_dn_per_e: float | None = None,
    read_noise_dn: ArrayLike | None = None,
) -> HdrResult:
    """Merge bracketed linear frames into one signal-rate image.

    Parameters
    ----------
    frames : array_like, shape (N, H, W)
        Raw frames in DN (any integer or float dtype), one per bracket.
    exposures_us : array_like, shape (N,)
        Actual exposure of each frame in µs.
    darks : array_like, shape (N, H, W), (H, W) or scalar
        Master dark of each bracket (same exposure and gain; dark current grows with
        exposure, so one dark for all brackets is right only when it is negligible).
    saturation_dn : array_like, scalar or shape (N,)
        Raw level at or above which a pixel is saturated (``Frame.saturation_dn``).
    gains : array_like, shape (N,), optional
        Relative linear gain of each bracket (1 = reference). Default all 1.
    weighting : {"hat", "inverse_variance"}
        "hat": w = min(s − s_low, s_high − s) on the dark-subtracted signal s
        (Debevec & Malik 1997, Eq. 6). "inverse_variance": w = 1/var(x_i) from the noise
        model; needs ``system_gain_dn_per_e`` and ``read_noise_dn``.
    saturation_fraction : float
        A raw value ≥ this fraction of ``saturation_dn`` counts as near-saturated.
    min_signal_dn : float, optional
        Dark-subtracted signals below this are near-dark and rejected. Default
        5 × ``read_noise_dn`` when given, else 0.2 % of the saturation level.
    system_gain_dn_per_e : float, optional
        K in DN/e⁻ at relative gain 1.
    read_noise_dn : array_like, scalar or shape (N,), optional
        Temporal dark noise σ_y.dark in DN, quantisation included.

    Returns
    -------
    HdrResult
    """
    stack = np.asarray(frames)
    if stack.ndim != 3 or stack.shape[0] < 1:
        raise ValueError(f"frames must have shape (N, H, W), got {stack.shape}")
    n = stack.shape[0]
    t = _per_frame(exposures_us, n, 1.0, "exposures_us")
    if np.any(~np.isfinite(t)) or np.any(t <= 0):
        raise ValueError("exposures must be finite and > 0")
    g = _per_frame(gains, n, 1.0, "gains")
    if np.any(g <= 0):
        raise ValueError("gains must be > 0")
    sat = _per_frame(saturation_dn, n, 0.0, "saturation_dn")
    if weighting not in ("hat", "inverse_variance"):
        raise ValueError(f"weighting must be 'hat' or 'inverse_variance', got {weighting!r}")
    if not 0.0 < saturation_fraction <= 1.0:
        raise ValueError("saturation_fraction must lie in (0, 1]")
    have_model = system_gain_dn_per_e is not None and read_noise_dn is not None
    if weighting == "inverse_variance" and not have_model:
        raise ValueError("inverse_variance weighting needs system_gain_dn_per_e and read_noise_dn")
    read = _per_frame(read_noise_dn, n, 0.0, "read_noise_dn")
    if min_signal_dn is None:
        min_signal_dn = (
            5.0 * float(read.max()) if read_noise_dn is not None else 0.002 * float(sat.min())
        )
    dark_arr = np.asarray(darks, dtype=np.float64)
    per_bracket_dark = dark_arr.ndim == 3
    if per_bracket_dark and dark_arr.shape[0] != n:
        raise ValueError("darks of shape (N, H, W) need one dark per frame")

    def signal(i: int) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
        d = dark_arr[i] if per_bracket_dark else dark_arr
        s = np.subtract(stack[i], d, dtype=np.float64)
        near_sat = stack[i] >= saturation_fraction * sat[i]
        usable = s >= min_signal_dn
        usable &= ~near_sat
        return s, near_sat, usable

    shape = stack.shape[1:]
    # Upper end of the usable dark-subtracted signal of each bracket (for the hat).
    mean_dark = [
        float(np.mean(dark_arr[i] if per_bracket_dark else dark_arr)) for i in range(n)
    ]
    s_high = saturation_fraction * sat - np.asarray(mean_dark)

    def hat(i: int, s: NDArray[np.float64], usable: NDArray[np.bool_]) -> NDArray[np.float64]:
        w = s - min_signal_dn
        np.minimum(w, s_high[i] - s, out=w)
        # A small floor keeps a usable bracket's weight positive right at the thresholds.
        np.maximum(w, 1e-3 * max(s_high[i], 1.0), out=w)
        w *= usable
        return w

    # Order by effective exposure so the fallbacks can pick the shortest/longest.
    order = np.argsort(t * g)

    # Pass 1: hat-weighted mean; also the fallbacks and the bookkeeping.
    num = np.zeros(shape)
    den = np.zeros(shape)
    n_used = np.zeros(shape, dtype=np.int64)
    any_unsat = np.zeros(shape, dtype=bool)
    fallback = np.zeros(shape)
    shortest_rate = np.zeros(shape)
    for rank, i in enumerate(order):
        s, near_sat, usable = signal(i)
        w = hat(i, s, usable)
        x = s
        x *= 1.0 / (t[i] * g[i])  # s is not needed any more: reuse its memory
        if rank == 0:
            shortest_rate = x
        num += w * x
        den += w
        n_used += usable
        # Longest unsaturated exposure seen so far (brackets are in increasing order).
        unsat = ~near_sat
        np.copyto(fallback, x, where=unsat)
        any_unsat |= unsat
    good = n_used > 0
    rate = np.divide(num, den, out=np.zeros(shape), where=good)
    saturated = ~any_unsat
    underexposed = ~good & any_unsat
    np.copyto(rate, fallback, where=underexposed)
    np.copyto(rate, shortest_rate, where=saturated)

    variance: NDArray[np.float64] | None = None
    if have_model:
        k = float(system_gain_dn_per_e)  # type: ignore[arg-type]  # not None: have_model says so
        predicted = np.maximum(rate, 0.0)
        wsum = np.zeros(shape)
        wacc = np.zeros(shape)
        fb_var = np.zeros(shape)
        if weighting == "inverse_variance":
            num = np.zeros(shape)
        for i in order:
            s, near_sat, usable = signal(i)
            scale = t[i] * g[i]
            # Noise model at the predicted (not the measured) signal: unbiased weights.
            # var(x_i) = (K g_i · x̂ · t_i g_i + σ²_read) / (t_i g_i)².
            var_i = predicted * (k * g[i] / scale)
            var_i += read[i] ** 2 / scale**2
            np.maximum(var_i, 1e-300, out=var_i)
            np.copyto(fb_var, var_i, where=~near_sat)
            if weighting == "inverse_variance":
                w = np.divide(usable, var_i)
                s *= 1.0 / scale
                num += w * s
                wsum += w
            else:
                w = hat(i, s, usable)
                wsum += w
                w *= w
                w *= var_i
                wacc += w
        if weighting == "inverse_variance":
            rate = np.where(good, np.divide(num, wsum, out=np.zeros(shape), where=good), rate)
            variance = np.divide(1.0, wsum, out=np.zeros(shape), where=good)
        else:
            variance = np.divide(wacc, wsum * wsum, out=np.zeros(shape), where=good)
        np.copyto(variance, fb_var, where=~good)
        if saturated.any():
            i0 = order[0]
            s0 = t[i0] * g[i0]
            v0 = (k * g[i0] * np.maximum(rate, 0.0) * s0 + read[i0] ** 2) / s0**2
            np.copyto(variance, v0, where=saturated)
    return HdrResult(
        rate=rate,
        variance=variance,
        n_used=np.where(good, n_used, 0),
        saturated=saturated,
        underexposed=underexposed,
    )
