"""Regularised solution of the per-point modal problem ``m_k = s_k x_k + noise_k``.

After the closed form (eq. 2-32/33: diffuse rank-one term removed, modes = Fourier orders,
gains s_k = S_pp) or an SVD of B̃ (modes = singular vectors, gains = singular values),
every scattering point r gives data ``m_rk`` with noise power ``σ_k² = E|noise_rk|²``.
The estimate is ``x̂_rk = φ_k m_rk / s_k`` with filter factors φ_k (Hansen,
*Discrete Inverse Problems*, SIAM 2010, ch. 4–5):

* ``"truncation"`` — keep modes with level ≤ p_max (level = |p| for Fourier modes); p_max is
  where the first difference of the MSE (Sasaki 2020, eq. 2-37 ff.)
  ``ΔMSE(L) = Σ_{k∈L} (σ_k²/|s_k|² − P_k)`` first turns positive, i.e. where a term's noise
  power overtakes its signal power;
* ``"wiener"`` — ``φ_k = P_k / (P_k + σ_k²/|s_k|²)``, the per-mode Wiener filter with the
  estimated signal spectrum P_k and noise PSD;
* ``"gcv"`` — Tikhonov ``φ_k = |s_k|²/(|s_k|² + λ)``, λ minimising the generalised
  cross-validation function (Golub, Heath & Wahba 1979);
* ``"discrepancy"`` — the largest λ with residual ≤ τ × expected noise power (Morozov);
* ``"none"`` — the naive inverse on observable modes.

The signal spectrum is pooled over all points (the unbiased plug-in estimate
``P_k = mean_r |m_rk/s_k|² − σ_k²/|s_k|²``, the UPRE idea; Hansen 2010), so one filter serves the
whole light field.  Modes with s_k = 0 are unobservable: φ = 0 there, never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

__all__ = [
    "Method",
    "RegularizationResult",
    "regularize",
    "truncation_level_mse",
]

Method = Literal["truncation", "wiener", "gcv", "discrepancy", "none"]


@dataclass(frozen=True)
class RegularizationResult:
    """What a regularised solve did and how well it fits.

    Attributes
    ----------
    method : str
    parameter_name : str — "p_max" (truncation), "lambda" (GCV, discrepancy), "noise_psd"
        (Wiener: the mean noise power σ_k² of the modal data it used) or "none"
    parameter : float — the chosen value (p_max as a float; NaN for "none")
    filter_factors : ndarray (R|1, K) — φ applied to each mode
    solution : ndarray (R, K) complex — x̂ = φ m/s
    effective_dof : float — mean over points of Σ_k φ_k
    residual_norm2 : float — Σ_rk |(1 − φ_k) m_rk|²
    noise_norm2 : float — Σ_rk σ_k², the residual pure noise would leave
    residual_ratio : float — residual_norm2 / noise_norm2
    signal_power : ndarray (K,) — pooled estimate P_k (clipped at 0)
    noise_power : ndarray (K,) — σ_k²/|s_k|² (inf where unobservable)
    recoverable : bool — any mode above level 0 kept (φ summed ≥ 0.5)
    message : str
    """

    method: str
    parameter_name: str
    parameter: float
    filter_factors: NDArray[np.float64]
    solution: NDArray[np.complex128]
    effective_dof: float
    residual_norm2: float
    noise_norm2: float
    residual_ratio: float
    signal_power: NDArray[np.float64]
    noise_power: NDArray[np.float64]
    recoverable: bool
    message: str


def truncation_level_mse(
    signal_power: ArrayLike, noise_power: ArrayLike, levels: ArrayLike
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Relative MSE of truncation at each level: ``Σ_{l≤L} Σ_{k∈l} (noise_k − signal_k)``.

    Returns (levels sorted, mse) with mse[0] the value when only level 0 is kept; the
    constant ‖x‖² is dropped.  Prepend 0 for "keep nothing".
    """
    sp = np.asarray(signal_power, dtype=float)
    npw = np.asarray(noise_power, dtype=float)
    lv = np.asarray(levels)
    uniq = np.unique(lv[lv >= 0])
    diff = np.array([np.sum(npw[lv == u] - sp[lv == u]) for u in uniq])
    return uniq, np.cumsum(diff)


def _tikhonov(s2: NDArray[Any], lam: float) -> NDArray[Any]:
    return s2 / (s2 + lam)


def regularize(
    data: ArrayLike,
    gains: ArrayLike,
    noise_var: ArrayLike,
    *,
    method: Method = "wiener",
    levels: ArrayLike | None = None,
    tau: float = 1.0,
    signal_power: ArrayLike | None = None,
    p_max: int | None = None,
    pool: ArrayLike | None = None,
    significance: float = 3.0,
    gain_floor: float = 1e-10,
) -> RegularizationResult:
    """Solve ``m = s x + noise`` mode by mode with the chosen regularisation.

    Parameters
    ----------
    data : ndarray (R, K) — modal data m_rk
    gains : ndarray (R|1, K) or (K,) — s_k (complex allowed)
    noise_var : scalar or (K,) — σ_k², noise power of m_rk
    method : see module docstring
    levels : ndarray (K,) of int — truncation level of each mode (default: rank by |s|)
    tau : float — discrepancy safety factor (≈ 1–1.1)
    signal_power : optional (K,) — a known (oracle) signal spectrum E|x_k|² instead of
        the pooled estimate (for validation)
    p_max : optional int — fix the truncation level instead of choosing it
    pool : optional bool (R,) — the points whose data enter the pooled signal spectrum
        (e.g. excluding points flagged for model mismatch); default all
    significance : float — the pooled estimate P_k counts as signal only where it exceeds
        ``significance × σ_k²/|s_k|² / √R_pool`` (its own standard error for pure noise);
        otherwise P_k = 0, so pure-noise modes never pass the filter by chance
    gain_floor : float — modes with ``|s_k| < gain_floor · max|s|`` are unobservable
    """
    m = np.atleast_2d(np.asarray(data, dtype=complex))
    s = np.atleast_2d(np.asarray(gains, dtype=complex))
    n_r, n_k = m.shape
    sig2 = np.broadcast_to(np.asarray(noise_var, dtype=float), (n_k,))
    obs = np.abs(s) > gain_floor * (float(np.abs(s).max()) if s.size else 0.0)
    s2 = np.abs(s) ** 2
    safe_s = np.where(obs, s, 1.0)
    x_naive = np.where(obs, m / safe_s, 0.0)
    with np.errstate(divide="ignore"):
        npow_rk = np.where(obs, sig2 / np.where(obs, s2, 1.0), np.inf)
    npow = np.broadcast_to(npow_rk, (s.shape[0], n_k)).mean(axis=0)
    if signal_power is None:
        sel = np.ones(n_r, bool) if pool is None else np.asarray(pool, dtype=bool)
        if not np.any(sel):
            sel = np.ones(n_r, bool)
        finite = np.isfinite(npow)
        raw = np.mean(np.abs(x_naive[sel]) ** 2, axis=0)
        excess = raw - np.where(finite, npow, 0.0)
        threshold = significance * np.where(finite, npow, 0.0) / np.sqrt(np.count_nonzero(sel))
        sp = np.where(finite & (excess > threshold), excess, 0.0)
    else:
        sp = np.broadcast_to(np.asarray(signal_power, dtype=float), (n_k,)).copy()
    if levels is None:
        order = np.argsort(-np.abs(s).mean(axis=0), kind="stable")
        lv = np.empty(n_k, dtype=np.int64)
        lv[order] = np.arange(n_k)
    else:
        lv = np.asarray(levels, dtype=np.int64)
    if signal_power is None:
        # trust the pooled spectrum only up to the first level where it is
        # indistinguishable from noise: beyond it a chance excess at a mode whose noise
        # gain is astronomically large would otherwise leak into the estimate
        uniq = np.unique(lv)
        empty = [u for u in uniq if not np.any(sp[lv == u] > 0)]
        if empty:
            sp = np.where(lv < empty[0], sp, 0.0)
        # an object spectrum does not grow with order; excess power that does (growing
        # like 1/|s_k|²) is model mismatch amplified by the inverse, so cap each level at
        # the running minimum of the level means below it
        means = np.array([sp[lv == u].mean() for u in uniq])
        envelope = np.minimum.accumulate(means)
        sp = np.minimum(sp, envelope[np.searchsorted(uniq, lv)])
    name, param = "none", float("nan")

    if method == "none":
        phi = obs.astype(float)
    elif method == "truncation":
        uniq = np.unique(lv[lv >= 0])
        if p_max is None:
            diffs = np.array([np.sum(npow[lv == u] - sp[lv == u]) for u in uniq])
            rising = np.nonzero(diffs > 0)[0]
            chosen = int(uniq[rising[0]] - 1) if rising.size else int(uniq[-1])
        else:
            chosen = int(p_max)
        phi = np.broadcast_to((lv <= chosen)[None, :] & obs, s.shape).astype(float)
        name, param = "p_max", float(chosen)
    elif method == "wiener":
        with np.errstate(invalid="ignore", divide="ignore"):
            phi = np.where(obs, sp / (sp + npow_rk), 0.0)
        phi = np.nan_to_num(phi, nan=0.0, posinf=0.0)
        name, param = "noise_psd", float(np.mean(sig2))
    elif method in ("gcv", "discrepancy"):
        smax = float(s2.max()) if s2.size else 0.0
        if smax == 0:
            phi = np.zeros(s.shape)
        else:
            lo, hi = np.log(smax * 1e-12), np.log(smax * 1e4)
            sel = np.ones(n_r, bool) if pool is None else np.asarray(pool, dtype=bool)
            if not np.any(sel):
                sel = np.ones(n_r, bool)
            m_sel = m[sel]
            obs_sel = obs if obs.shape[0] == 1 else obs[sel]
            s2_sel = s2 if s2.shape[0] == 1 else s2[sel]
            n_tot = m_sel.size

            def resid(loglam: float) -> float:
                f = np.where(obs_sel, _tikhonov(s2_sel, np.exp(loglam)), 0.0)
                return float(np.sum(np.abs((1.0 - f) * m_sel) ** 2))

            if method == "gcv":
                def gcv(loglam: float) -> float:
                    f = np.where(obs_sel, _tikhonov(s2_sel, np.exp(loglam)), 0.0)
                    tr = float(np.sum(np.broadcast_to(1.0 - f, m_sel.shape)))
                    return n_tot * resid(loglam) / max(tr, 1e-300) ** 2

                grid = np.linspace(lo, hi, 161)
                vals = np.array([gcv(g) for g in grid])
                i = int(np.argmin(vals))
                a_, b_ = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
                opt = optimize.minimize_scalar(gcv, bounds=(a_, b_), method="bounded",
                                               options={"xatol": 1e-4})
                loglam = float(opt.x) if opt.fun <= vals[i] else float(grid[i])
            else:
                target = tau * m_sel.shape[0] * float(np.sum(sig2))
                if resid(hi) <= target:
                    loglam = hi
                elif resid(lo) >= target:
                    loglam = lo
                else:
                    loglam = optimize.brentq(lambda g: resid(g) - target, lo, hi, xtol=1e-6)
            lam = float(np.exp(loglam))
            phi = np.where(obs, _tikhonov(s2, lam), 0.0)
            name, param = "lambda", lam
    else:
        raise ValueError(f"unknown method {method!r}")

    phi = np.asarray(phi, dtype=float)
    x = phi * x_naive
    resid2 = float(np.sum(np.abs((1.0 - phi) * m) ** 2))
    noise2 = float(n_r * np.sum(sig2))
    dof = float(np.broadcast_to(phi, (max(n_r, phi.shape[0]), n_k)).sum(axis=1).mean())
    ac = np.broadcast_to(phi, (phi.shape[0], n_k))[:, lv > 0].sum(axis=1).mean()
    recoverable = bool(ac >= 0.5)
    chosen_text = "no filter" if name == "none" else f"{name}={param:.4g}"
    msg = (
        f"{method}: {chosen_text}, effective dof {dof:.2f}, residual/noise "
        f"{resid2 / noise2 if noise2 > 0 else float('inf'):.3g}"
    )
    if not recoverable:
        msg = (
            "no recoverable object information: no angular term above level 0 rises above "
            "the noise (" + msg + ")"
        )
    return RegularizationResult(
        method=method,
        parameter_name=name,
        parameter=param,
        filter_factors=phi,
        solution=x,  # type: ignore[arg-type]  # complex: φ (real) times the complex m/s
        effective_dof=dof,
        residual_norm2=resid2,
        noise_norm2=noise2,
        residual_ratio=resid2 / noise2 if noise2 > 0 else float("inf"),
        signal_power=np.asarray(sp, dtype=float),
        noise_power=np.asarray(npow, dtype=float),
        recoverable=recoverable,
        message=msg,
    )
