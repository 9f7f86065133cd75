"""Camera characterization after EMVA 1288 Release 4.0 Linear, with uncertainties.

The standard (EMVA 1288 "Standard for Characterization of Image Sensors and Cameras",
Release 4.0 Linear, 2021; R4.0 below) describes a linear camera by (R4.0 §2, the
mathematical model; same as R3.1 §2.1–2.3)

    μ_y − μ_y.dark = K η μ_p                                       (signal)
    σ²_y = K² σ²_d + σ²_q + K (μ_y − μ_y.dark)                      (photon transfer)

with K the system gain (DN/e⁻), η the quantum efficiency, μ_p the mean number of photons
per pixel, σ_d the temporal dark noise (e⁻) and σ²_q = 1/12 DN² the quantisation noise.
This module evaluates an exposure sweep at constant irradiance (R4.0 §6, "Methods for
Sensitivity, Linearity, and Noise": the photon count may be varied by the exposure time at a
constant irradiance; H ∝ exposure time) taken as pairs of frames at every exposure and
dark pairs at the same exposures:

* mean and temporal variance of every pair
  (:func:`analysis.photon_transfer.pair_statistics`: the difference of the two frames
  removes the fixed pattern);
* saturation: the point of the sweep where the temporal variance σ²_y is largest
  (R4.0 §6, photon-transfer evaluation); μ_e.sat = (μ_y.sat − μ_y.dark)/K is the
  saturation capacity;
* K: the slope of σ²_y − σ²_y.dark against μ_y − μ_y.dark, fitted through the origin over
  the points between 0 and 70 % of the saturation signal (R4.0 §6, photon-transfer
  method; R3.1 §6.6);
* σ_d = √(σ²_y.dark − σ²_q)/K with σ²_y.dark at zero exposure: the intercept of a
  straight line through the dark pairs' variances against the exposure time, which the
  dark current's shot noise raises as K² μ_I t (R4.0 §7, the dark-current model; the
  shortest exposure's dark pair alone, R4.0 §6, gives the same value with a larger
  error); σ²_q = 1/12 holds only for offsets spread over the quantisation step, so its
  possible error (:func:`quantisation_deviation_dn2`) enters u(σ_d); below σ²_y.dark ≈
  0.24 DN² the quantisation dominates and σ_d is only an upper bound (a warning);
* linearity: a straight line μ_y − μ_y.dark = a₀ + a₁ H fitted between 5 % and 95 % of
  the saturation signal; δ = (y − fit)/fit and LE = (max δ − min δ)/2 in per cent
  (R4.0 §6, linearity; R3.1 §6.7);
* dark current: the slope of μ_y.dark against the exposure time, divided by K
  (R4.0 §7, "Methods for Dark Current", the mean-value method);
* quantum efficiency, only when the photon count per pixel is known (a calibrated
  photodiode in the sensor plane): η = a₁/(K · photons per pixel per second)
  (R4.0 §6, responsivity R = K η);
* spatial non-uniformity from L frames averaged at the exposure nearest 50 % of the
  saturation signal and the L_d dark frames at that exposure (R4.0 §8, "Methods for
  Spatial Nonuniformity"): the spatial variance of the averaged frame, corrected for the
  temporal noise left in it, s²_y = s²_y.measured − σ²_y/L; DSNU = s_y.dark/K (e⁻) and
  PRNU = √(s²_y − s²_y.dark)/(μ_y − μ_y.dark) (relative).

Uncertainties (standard, k = 1). Every pair statistic has a known sampling error: over N
pixels the pair mean's is σ_y/√(2N) (the fixed pattern is the same in every frame and does
not scatter) and the pair variance's is σ²_y √(2/N) (a Gaussian sample variance). K, σ_d,
μ_sat, LE, the dark current and η take their uncertainties from a parametric bootstrap that
redraws every pair statistic with these errors and repeats the whole evaluation (Efron &
Tibshirani 1993, "An Introduction to the Bootstrap", ch. 6); K's is at least the standard
error of its regression residuals (scatter beyond the model, e.g. a drifting source).
The saturation point can be resolved no better than the sweep's step there: half a step
is added as a rectangular uncertainty (GUM 4.3.7). LE is a range statistic, biased upward
by noise even for an ideal camera: its noise floor, the mean LE of a perfectly linear
camera with the sweep's noise (the fitted line plus each mean's sampling error, evaluated
in the same way), is subtracted for the noise-corrected value reported beside the EMVA
value (its expectation is 0 for a linear camera). The non-uniformities' uncertainties
come from the spread of the per-pixel squared deviations, var(d²)/N, which includes the
sampling of the pixel population, and from K's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["QUANTISATION_VARIANCE_DN2", "CameraCharacterization", "MeansEvaluation",
           "SweepStatistics", "Uniformity", "characterize", "evaluate_means",
           "quantisation_deviation_dn2", "spatial_variance", "uniformity_exposure_index"]

#: σ²_q of an ideal quantiser with a step of 1 DN (R4.0 §2).
QUANTISATION_VARIANCE_DN2 = 1.0 / 12.0
#: Below this dark variance (DN²) the quantisation dominates the dark noise (R4.0 §6).
QUANTISATION_LIMIT_DN2 = 0.24


@dataclass(frozen=True)
class SweepStatistics:
    """Pair statistics of an exposure sweep.

    Attributes
    ----------
    exposures_us : ndarray, shape (M,)
        Increasing exposure times.
    mean_dn, var_dn2 : ndarray, shape (M, P)
        Mean and temporal variance of each of the P light pairs at each exposure.
    dark_mean_dn, dark_var_dn2 : ndarray, shape (M, Q)
        The same for the Q dark pairs at each exposure.
    n_pixels : int
        Pixels per frame.
    """

    exposures_us: NDArray[np.float64]
    mean_dn: NDArray[np.float64]
    var_dn2: NDArray[np.float64]
    dark_mean_dn: NDArray[np.float64]
    dark_var_dn2: NDArray[np.float64]
    n_pixels: int

    def __post_init__(self) -> None:
        m = self.exposures_us.shape[0]
        for name in ("mean_dn", "var_dn2", "dark_mean_dn", "dark_var_dn2"):
            a = getattr(self, name)
            if a.ndim != 2 or a.shape[0] != m or a.shape[1] < 1:
                raise ValueError(f"{name} must have shape ({m}, pairs ≥ 1), got {a.shape}")
        if m < 3:
            raise ValueError(f"a sweep needs at least 3 exposures, got {m}")
        if np.any(np.diff(self.exposures_us) <= 0):
            raise ValueError("exposures_us must increase")
        if self.n_pixels < 2:
            raise ValueError("a frame needs at least 2 pixels")


@dataclass(frozen=True)
class Uniformity:
    """Frames averaged for the spatial non-uniformity at one exposure (R4.0 §8).

    Attributes
    ----------
    light_mean_dn, dark_mean_dn : ndarray, shape (H, W)
        Averages of ``n_light`` light frames and ``n_dark`` dark frames.
    n_light, n_dark : int
    exposure_us : float
    """

    light_mean_dn: NDArray[np.float64]
    dark_mean_dn: NDArray[np.float64]
    n_light: int
    n_dark: int
    exposure_us: float


@dataclass(frozen=True)
class CameraCharacterization:
    """EMVA 1288 parameters of a camera with their standard uncertainties (``u_*``).

    Values: ``system_gain_dn_per_e`` (K), ``dark_noise_e`` (σ_d) and ``dark_noise_dn``
    (σ_y.dark without quantisation), ``saturation_dn`` (μ_y.sat, raw),
    ``saturation_capacity_e`` (μ_e.sat), ``linearity_error_percent`` (LE) and
    ``linearity_error_unbiased_percent`` (LE less its noise floor), ``dark_current_e_per_s``,
    ``dsnu_e``, ``prnu_rel``, ``quantum_efficiency`` (None without the photon count).
    Arrays per exposure for the report: ``exposures_us``, ``mean_dn``, ``mean_dark_dn``,
    ``var_dn2``, ``var_dark_dn2``, ``gain_fit_mask``, ``linearity_fit_mask``,
    ``linearity_fit_dn`` (the fitted line), ``linearity_deviation_percent``.
    """

    system_gain_dn_per_e: float
    u_system_gain_dn_per_e: float
    dark_noise_e: float
    u_dark_noise_e: float
    dark_noise_dn: float
    saturation_dn: float
    u_saturation_dn: float
    saturation_capacity_e: float
    u_saturation_capacity_e: float
    linearity_error_percent: float
    linearity_error_unbiased_percent: float
    u_linearity_error_percent: float
    dark_current_e_per_s: float
    u_dark_current_e_per_s: float
    dsnu_e: float
    u_dsnu_e: float
    prnu_rel: float
    u_prnu_rel: float
    quantum_efficiency: float | None
    u_quantum_efficiency: float | None
    responsivity_dn_per_photon: float | None
    n_pixels: int
    uniformity_exposure_us: float
    warnings: tuple[str, ...]
    exposures_us: NDArray[np.float64]
    mean_dn: NDArray[np.float64]
    mean_dark_dn: NDArray[np.float64]
    var_dn2: NDArray[np.float64]
    var_dark_dn2: NDArray[np.float64]
    gain_fit_mask: NDArray[np.bool_]
    linearity_fit_mask: NDArray[np.bool_]
    linearity_fit_dn: NDArray[np.float64]
    linearity_deviation_percent: NDArray[np.float64]


@dataclass(frozen=True)
class MeansEvaluation:
    """One evaluation of a sweep's per-exposure statistics (the bootstrap repeats it):
    K and its residual standard error, σ²_y.dark at zero exposure, the saturation point,
    LE, the linearity slope (DN/s), the dark mean's slope (DN/s), the fit masks, the
    fitted line and the deviations δ (%)."""

    k: float
    k_residual_se: float
    dark_var_dn2: float
    i_sat: int
    sat_dn: float
    sat_signal_dn: float
    le: float
    slope_dn_per_s: float
    dark_slope_dn_per_s: float
    gain_mask: NDArray[np.bool_]
    lin_mask: NDArray[np.bool_]
    lin_fit: NDArray[np.float64]
    deviation: NDArray[np.float64]


def evaluate_means(t_us: NDArray[np.float64], mu: NDArray[np.float64], var: NDArray[np.float64],
                   mu_d: NDArray[np.float64], var_d: NDArray[np.float64],
                   gain_fit_fraction: float = 0.7,
                   linearity_range: tuple[float, float] = (0.05, 0.95)) -> MeansEvaluation:
    """K, σ²_y.dark, saturation and linearity from per-exposure means and temporal
    variances of light and dark frames (module docstring; no uncertainties).

    Raises
    ------
    ValueError
        No light at the variance maximum, or too few exposures in a fit range.
    """
    lo, hi = linearity_range
    if not 0.0 <= lo < hi <= 1.0:
        raise ValueError("linearity_range must satisfy 0 <= low < high <= 1")
    signal = mu - mu_d
    excess = var - var_d
    i_sat = int(np.argmax(var))
    sat_signal = float(signal[i_sat])
    if not sat_signal > 0:
        raise ValueError("no positive signal at the variance maximum: is the light on?")
    gain_mask = (signal > 0) & (signal <= gain_fit_fraction * sat_signal)
    if gain_mask.sum() < 2:
        raise ValueError("fewer than two exposures below 70 % of saturation: extend the "
                         "sweep to shorter exposures or take more of them")
    x, y = signal[gain_mask], excess[gain_mask]
    k = float(np.dot(x, y) / np.dot(x, x))
    resid = y - k * x
    dof = max(int(gain_mask.sum()) - 1, 1)
    k_se = float(np.sqrt(np.dot(resid, resid) / dof / np.dot(x, x)))
    t_s = t_us * 1e-6
    lin_mask = (signal >= lo * sat_signal) & (signal <= hi * sat_signal) & (t_us <= t_us[i_sat])
    if lin_mask.sum() < 3:
        raise ValueError("fewer than three exposures between 5 % and 95 % of saturation: "
                         "take more exposures below saturation")
    a1, a0 = np.polyfit(t_s[lin_mask], signal[lin_mask], 1)
    fit = a0 + a1 * t_s
    safe = np.where(fit != 0, fit, 1.0)
    dev = np.where(fit != 0, 100.0 * (signal - fit) / safe, 0.0)
    le = float(0.5 * (dev[lin_mask].max() - dev[lin_mask].min()))
    dark_slope = float(np.polyfit(t_s, mu_d, 1)[0])
    # σ²_y.dark = K²(σ²_d + μ_I t) + σ²_q (R4.0 §7): the intercept at t = 0 uses every dark
    # pair instead of the shortest exposure's alone
    dark_var0 = float(np.polyfit(t_s, var_d, 1)[1])
    return MeansEvaluation(k, k_se, dark_var0, i_sat, float(mu[i_sat]),
                  sat_signal, le, float(a1), dark_slope, gain_mask, lin_mask, fit, dev)


def quantisation_deviation_dn2(sigma_dn: float) -> float:
    """How far the variance of a quantised Gaussian can lie from σ² + 1/12 DN² (DN²).

    σ²_q = 1/12 is exact when the offsets' fractional parts are spread uniformly over the
    quantisation step (Sheppard's correction); a camera whose offsets cluster (a black
    level on a whole DN and a DSNU well below 1 DN) can show any value in between. For a
    pixel at offset phase x the variance of round(x + σZ) is Σ k² p_k − (Σ k p_k)² with
    p_k = Φ((k + ½ − x)/σ) − Φ((k − ½ − x)/σ); the largest deviation over x ∈ [0, 1) is
    returned (±0.0079 DN² at σ = 0.5 DN, 1e-5 at 0.8 DN). It bounds σ²_y.dark's model
    error, entered as a rectangular uncertainty (GUM 4.3.7).
    """
    from scipy.special import ndtr

    if not sigma_dn > 0:
        return 1.0 / 12.0
    if sigma_dn > 2.0:
        return 0.0
    k = np.arange(-int(6 * sigma_dn) - 3, int(6 * sigma_dn) + 4)[None, :]
    x = np.linspace(0.0, 1.0, 101)[:, None]
    p = ndtr((k + 0.5 - x) / sigma_dn) - ndtr((k - 0.5 - x) / sigma_dn)
    m = (p * k).sum(axis=1)
    var = (p * k * k).sum(axis=1) - m * m
    return float(np.max(np.abs(var - sigma_dn**2 - 1.0 / 12.0)))


def spatial_variance(mean_frame: ArrayLike, temporal_var_dn2: float, n_frames: int
                     ) -> tuple[float, float]:
    """Spatial variance of an averaged frame without its temporal part, and its standard
    uncertainty (R4.0 §8: s²_y = s²_y.measured − σ²_y/L).

    The uncertainty is √(var(d²)/N) of the per-pixel squared deviations d² (the sampling
    of the pixel population and of the temporal noise together) and the temporal term's
    own, σ²_y √(2/N)/L.
    """
    y = np.asarray(mean_frame, dtype=np.float64).reshape(-1)
    n = y.size
    d2 = (y - y.mean()) ** 2
    measured = float(d2.sum() / (n - 1))
    s2 = measured - temporal_var_dn2 / n_frames
    u = float(np.hypot(np.std(d2) / np.sqrt(n),
                       temporal_var_dn2 * np.sqrt(2.0 / n) / n_frames))
    return s2, u


def characterize(stats: SweepStatistics, uniformity: Uniformity, *,
                 photons_per_pixel_per_s: float | None = None,
                 u_photons_rel: float = 0.0,
                 gain_fit_fraction: float = 0.7,
                 linearity_range: tuple[float, float] = (0.05, 0.95),
                 n_bootstrap: int = 400, seed: int = 0) -> CameraCharacterization:
    """Evaluate an exposure sweep (module docstring) with uncertainties.

    Parameters
    ----------
    stats : SweepStatistics
    uniformity : Uniformity
        Averaged frames at the exposure nearest 50 % of saturation (see
        :func:`uniformity_exposure_index` to choose it).
    photons_per_pixel_per_s : float, optional
        Mean photons reaching one pixel per second at the sweep's irradiance (from a
        calibrated photodiode); without it η is not measured (None).
    u_photons_rel : float
        Its relative standard uncertainty.
    gain_fit_fraction, linearity_range
        The fit ranges as fractions of the saturation signal (R4.0: 0.7; 0.05–0.95).
    n_bootstrap : int
        Parametric bootstrap draws (≥ 50).
    seed : int
        Seeds the bootstrap (the result is reproducible).

    Raises
    ------
    ValueError
        Too few exposures in a fit range, no light, or bad arguments.
    """
    if n_bootstrap < 50:
        raise ValueError(f"n_bootstrap must be >= 50, got {n_bootstrap}")
    t = stats.exposures_us
    n = stats.n_pixels
    mu_p, var_p = stats.mean_dn, stats.var_dn2
    mu_dp, var_dp = stats.dark_mean_dn, stats.dark_var_dn2

    def reduce(mp: NDArray[np.float64], vp: NDArray[np.float64], mdp: NDArray[np.float64],
               vdp: NDArray[np.float64]) -> MeansEvaluation:
        return evaluate_means(t, mp.mean(axis=1), vp.mean(axis=1), mdp.mean(axis=1),
                         vdp.mean(axis=1), gain_fit_fraction, linearity_range)

    best = reduce(mu_p, var_p, mu_dp, var_dp)
    rng = np.random.default_rng(seed)

    def redraw(mean: NDArray[np.float64], var: NDArray[np.float64]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        v = np.maximum(var, 0.0)
        m = mean + np.sqrt(v / (2.0 * n)) * rng.standard_normal(mean.shape)
        return m, v * (1.0 + np.sqrt(2.0 / n) * rng.standard_normal(var.shape))

    draws = []
    for _ in range(n_bootstrap):
        try:
            p = reduce(*redraw(mu_p, var_p), *redraw(mu_dp, var_dp))
        except ValueError:
            continue
        draws.append((p.k, np.sqrt(max(p.dark_var_dn2 - QUANTISATION_VARIANCE_DN2, 0.0)),
                      p.sat_dn, p.sat_signal_dn / p.k, p.le, p.slope_dn_per_s,
                      p.dark_slope_dn_per_s / p.k))
    if len(draws) < n_bootstrap // 2:
        raise ValueError("the sweep's evaluation fails for most bootstrap draws: the "
                         "fit ranges hold too few exposures")
    boot = np.array(draws)
    sd = boot.std(axis=0, ddof=1)

    k = best.k
    u_k = float(max(sd[0], best.k_residual_se))
    warnings: list[str] = []
    read_var = best.dark_var_dn2 - QUANTISATION_VARIANCE_DN2
    if best.dark_var_dn2 < QUANTISATION_LIMIT_DN2:
        warnings.append(f"dark variance {best.dark_var_dn2:.3g} DN² is below "
                        f"{QUANTISATION_LIMIT_DN2} DN²: quantisation dominates, σ_d is an "
                        "upper bound (EMVA 1288 R4.0 §6)")
    read_dn = float(np.sqrt(max(read_var, 0.0)))
    sigma_d = read_dn / k
    u_read_dn = float(np.hypot(sd[1], quantisation_deviation_dn2(read_dn) / np.sqrt(3.0)
                               / (2.0 * max(read_dn, 1e-300))))
    u_sigma_d = sigma_d * float(np.hypot(u_read_dn / max(read_dn, 1e-300), u_k / k))

    # the saturation point is known to the sweep's step there (rectangular, half-width
    # half the mean neighbouring step): GUM 4.3.7
    i = best.i_sat
    mu = mu_p.mean(axis=1)
    steps = np.diff(mu)
    near = steps[max(i - 1, 0):i + 1]
    half = 0.5 * float(np.mean(np.abs(near))) if near.size else 0.0
    u_sat_dn = float(np.hypot(sd[2], half / np.sqrt(3.0)))
    sat_e = best.sat_signal_dn / k
    u_sat_e = sat_e * float(np.hypot(u_sat_dn / best.sat_signal_dn, u_k / k))

    # LE of a perfectly linear camera with this sweep's noise: the line fitted to the data
    # plus each mean's sampling error, evaluated as the data are (the noise floor)
    se = np.sqrt(np.maximum(var_p, 0.0).mean(axis=1) / (2.0 * n * mu_p.shape[1])
                 + np.maximum(var_dp, 0.0).mean(axis=1) / (2.0 * n * mu_dp.shape[1]))
    lin, t_s = best.lin_mask, t[best.lin_mask] * 1e-6
    floor = np.empty(n_bootstrap)
    for b in range(n_bootstrap):
        y = best.lin_fit[lin] + se[lin] * rng.standard_normal(t_s.size)
        line = np.polyval(np.polyfit(t_s, y, 1), t_s)
        dev = 100.0 * (y - line) / line
        floor[b] = 0.5 * (dev.max() - dev.min())
    le_unbiased = float(best.le - floor.mean())
    u_le = float(sd[4])
    dark_current = best.dark_slope_dn_per_s / k
    u_dark_current = float(np.hypot(sd[6], abs(dark_current) * u_k / k))

    qe = u_qe = resp = None
    if photons_per_pixel_per_s is not None:
        if not photons_per_pixel_per_s > 0:
            raise ValueError("photons_per_pixel_per_s must be > 0")
        resp = best.slope_dn_per_s / photons_per_pixel_per_s
        qe = resp / k
        u_qe = qe * float(np.sqrt((sd[5] / best.slope_dn_per_s) ** 2 + (u_k / k) ** 2
                                  + u_photons_rel ** 2))

    j = int(np.argmin(np.abs(t - uniformity.exposure_us)))
    s2_light, u_s2_light = spatial_variance(uniformity.light_mean_dn, float(var_p[j].mean()),
                                            uniformity.n_light)
    s2_dark, u_s2_dark = spatial_variance(uniformity.dark_mean_dn, float(var_dp[j].mean()),
                                          uniformity.n_dark)
    dsnu_dn = float(np.sqrt(max(s2_dark, 0.0)))
    dsnu = dsnu_dn / k
    u_dsnu = dsnu * float(np.hypot(u_s2_dark / (2.0 * max(s2_dark, 1e-300)), u_k / k))
    signal50 = float(uniformity.light_mean_dn.mean() - uniformity.dark_mean_dn.mean())
    if not signal50 > 0:
        raise ValueError("the uniformity frames have no signal above dark")
    num = s2_light - s2_dark
    prnu = float(np.sqrt(max(num, 0.0))) / signal50
    u_prnu = prnu * float(np.hypot(u_s2_light, u_s2_dark)) / (2.0 * max(num, 1e-300))
    if num <= 0:
        warnings.append("the light frames' spatial variance does not exceed the dark "
                        "frames': PRNU below what the frames resolve")

    return CameraCharacterization(
        system_gain_dn_per_e=k, u_system_gain_dn_per_e=u_k,
        dark_noise_e=sigma_d, u_dark_noise_e=u_sigma_d, dark_noise_dn=read_dn,
        saturation_dn=best.sat_dn, u_saturation_dn=u_sat_dn,
        saturation_capacity_e=sat_e, u_saturation_capacity_e=u_sat_e,
        linearity_error_percent=best.le, linearity_error_unbiased_percent=le_unbiased,
        u_linearity_error_percent=u_le,
        dark_current_e_per_s=dark_current, u_dark_current_e_per_s=u_dark_current,
        dsnu_e=dsnu, u_dsnu_e=u_dsnu, prnu_rel=prnu, u_prnu_rel=u_prnu,
        quantum_efficiency=qe, u_quantum_efficiency=u_qe, responsivity_dn_per_photon=resp,
        n_pixels=n, uniformity_exposure_us=float(uniformity.exposure_us),
        warnings=tuple(warnings), exposures_us=t, mean_dn=mu,
        mean_dark_dn=mu_dp.mean(axis=1), var_dn2=var_p.mean(axis=1),
        var_dark_dn2=var_dp.mean(axis=1), gain_fit_mask=best.gain_mask,
        linearity_fit_mask=best.lin_mask, linearity_fit_dn=best.lin_fit,
        linearity_deviation_percent=best.deviation)


def uniformity_exposure_index(stats: SweepStatistics) -> int:
    """Index of the exposure whose signal is nearest 50 % of the saturation signal (the
    operating point of R4.0 §8's non-uniformity measurement)."""
    mu = stats.mean_dn.mean(axis=1) - stats.dark_mean_dn.mean(axis=1)
    i_sat = int(np.argmax(stats.var_dn2.mean(axis=1)))
    return int(np.argmin(np.abs(mu[: i_sat + 1] - 0.5 * mu[i_sat])))
