"""Image-consistency checking: identity errors per order against the noise level.

Mahajan, Ramamoorthi & Curless (PAMI 2008, §8) detect tampering by testing an identity (e.g. M10
with known lighting, M16, M21: equation numbers of the ECCV 2006 paper) on the images; the residual
must be tested against the noise level, not against exact zero. Noise, the finite view (grazing
pixels, the unseen cap behind the sphere) and the departures of a real sphere from the ideal
radially symmetric convolution all give consistent images non-zero identity errors, so the
reference is measured: per order l, the distribution of the normalised error e_l over consistent
data (simulated with the measured noise level, or held out), summarised by a robust centre (median)
and scale (1.4826·MAD).

The decision statistic is T = Σ_l max(z_l, 0)², z_l = (e_l − median_l)/scale_l: only
errors larger than consistent data produce count. Its threshold is the empirical
(1 − α) quantile of T over the calibration cases (the ⌈(n+1)(1−α)⌉-th order statistic,
the conformal choice, whose false-alarm rate on new consistent data is at most α).

With known lighting the same test can be made in the image domain, where the noise is
white and where pixels that break the ideal model (grazing views, whose lobes the sphere's
own horizon clips) can be left out: :func:`known_lighting_residual` fits the unknown
radially symmetric filter A_l of B = Σ_l A_l Σ_m L_lm Y_lm(R) to the chosen pixels (the
image-domain form of M10) and returns the residual, whose rms joins the per-order errors as
one more calibrated component.

Where the cases a calibration can simulate miss a departure that real consistent data
share (a noise-only bootstrap of sphere captures misses the sphere's horizon), the decision
can be recalibrated one level up: :func:`threshold_factor` takes u = T / threshold of
≳ 1/α consistent captures of the same instrument, each judged against its own calibration,
and returns the conformal (1 − α) quantile q of u; testing T > q · threshold
(:func:`scale_threshold`) then has false-alarm rate ≤ α on new captures exchangeable with
those.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from analysis.sh.convention import band_slice
from analysis.sh.transform import real_sh_matrix
from analysis.sh.validation import (
    SHInputError,
    check_coefficients,
    check_degree,
    check_finite,
    check_scalar,
)

__all__ = [
    "NO_TEST",
    "ConsistencyCalibration",
    "ConsistencyReport",
    "KnownLightingResidual",
    "bootstrap_consistent_errors",
    "calibrate",
    "check",
    "known_lighting_residual",
    "scale_threshold",
    "statistic",
    "threshold_factor",
]


@dataclass(frozen=True)
class ConsistencyCalibration:
    """Reference distribution of per-order identity errors on consistent data.

    Attributes
    ----------
    orders : ndarray of int, shape (n,)
    noise_error : ndarray of shape (n,)
        Median normalised error per order on consistent data: the noise level.
    noise_scale : ndarray of shape (n,)
        Robust spread (1.4826·MAD, floored) per order.
    threshold : float
        Decision threshold on T.
    false_alarm : float
        The target false-alarm rate α.
    n_cases : int
        Number of consistent cases the calibration rests on.
    informative : ndarray of bool, shape (n,)
        Orders whose error varies over the consistent cases (MAD > 0). An order whose
        error is the same on all (most) consistent cases — an identity that holds
        whatever the data — cannot tell anything apart.
    """

    orders: np.ndarray
    noise_error: np.ndarray
    noise_scale: np.ndarray
    threshold: float
    false_alarm: float
    n_cases: int
    informative: np.ndarray | None = None


@dataclass(frozen=True)
class ConsistencyReport:
    """Outcome of :func:`check`.

    Attributes
    ----------
    orders : ndarray of int, shape (n,)
    error : ndarray of shape (n,)
        The image's normalised identity error per order.
    noise_error : ndarray of shape (n,)
        The calibrated noise level per order.
    ratio : ndarray of shape (n,)
        error / noise_error.
    z : ndarray of shape (n,)
        (error − noise_error) / noise_scale.
    statistic : float
        T = Σ max(z, 0)².
    threshold : float
    inconsistent : bool
        T > threshold (never when ``testable`` is False).
    false_alarm : float
    testable : bool
        Whether the test can flag anything at these orders (:func:`check`).
    no_test_reason : str
        Why not ("" when testable).
    """

    orders: np.ndarray
    error: np.ndarray
    noise_error: np.ndarray
    ratio: np.ndarray
    z: np.ndarray
    statistic: float
    threshold: float
    inconsistent: bool
    false_alarm: float
    testable: bool = True
    no_test_reason: str = ""

    @property
    def verdict(self) -> str:
        """"inconsistent", "consistent" or :data:`NO_TEST`."""
        if not self.testable:
            return NO_TEST
        return "inconsistent" if self.inconsistent else "consistent"


#: The verdict of a check that cannot flag anything at the chosen orders.
NO_TEST = "no test possible at this L"


def _z(errors: np.ndarray, centre: np.ndarray, scale: np.ndarray) -> np.ndarray:
    return (errors - centre) / scale


def statistic(z: np.ndarray) -> np.ndarray:
    """T = Σ_l max(z_l, 0)² along the last axis."""
    zz = np.maximum(check_finite("z", z), 0.0)
    return np.sum(zz * zz, axis=-1)


def calibrate(
    consistent_errors: np.ndarray,
    *,
    orders: np.ndarray | None = None,
    false_alarm: float = 0.05,
) -> ConsistencyCalibration:
    """Calibrate the checker on identity errors of consistent data.

    Parameters
    ----------
    consistent_errors : ndarray of shape (n_cases, n_orders)
        Per-order normalised errors e_l (e.g. ``IdentityError.error``) of consistent cases.
    orders : ndarray of int, shape (n_orders,), optional
    false_alarm : float
        Target false-alarm rate α, 0 < α < 1; needs n_cases ≥ 1/α − 1.
    """
    e = check_finite("consistent_errors", consistent_errors, ndim=2)
    if e.shape[1] == 0:
        raise SHInputError("consistent_errors", "must hold at least one order")
    rank = _conformal_rank(e.shape[0], false_alarm)
    centre = np.median(e, axis=0)
    raw = 1.4826 * np.median(np.abs(e - centre), axis=0)
    # An order with no spread (exact identity, noise-free) must not divide by zero.
    floor = max(float(np.max(raw)) * 1e-3, np.finfo(float).tiny)
    scale = np.maximum(raw, floor)
    # Orders without spread carry no information; check() leaves them out of T too.
    t = np.sort(statistic(np.where(raw > 0, _z(e, centre, scale), 0.0)))
    thr = float(t[rank - 1])
    if orders is None:
        ords = np.arange(e.shape[1])
    else:
        ords = check_finite("orders", orders, ndim=1)
        if ords.size != e.shape[1]:
            raise SHInputError("orders", f"must name the {e.shape[1]} orders of "
                               f"consistent_errors, got {ords.size}")
        ords = ords.astype(int)
    return ConsistencyCalibration(ords, centre, scale, thr, float(false_alarm), e.shape[0],
                                  raw > 0)


def _conformal_rank(n: int, false_alarm: float) -> int:
    """⌈(n + 1)(1 − α)⌉, the order statistic of n cases that bounds the false alarms by α."""
    false_alarm = check_scalar("false_alarm", false_alarm, low=0.0, high=1.0, low_open=True,
                               high_open=True)
    rank = int(np.ceil((n + 1) * (1.0 - false_alarm)))
    if rank > n:
        raise SHInputError("false_alarm", f"= {false_alarm:g} cannot be calibrated on {n} "
                           f"cases: that needs ≥ {rank}")
    return rank


def threshold_factor(normalised_statistics: np.ndarray, *, false_alarm: float) -> float:
    """Conformal factor q on u = T / threshold over consistent captures (module docstring).

    Parameters
    ----------
    normalised_statistics : ndarray of shape (n,)
        u = T / threshold of n consistent captures, each against its own calibration.
    false_alarm : float
        Target α of the recalibrated decision T > q · threshold; needs n ≥ 1/α − 1.

    Returns
    -------
    float
        The ⌈(n + 1)(1 − α)⌉-th smallest u.
    """
    u = np.sort(check_finite("normalised_statistics", normalised_statistics).ravel())
    if u.size == 0 or np.any(u < 0):
        raise SHInputError("normalised_statistics", "must be ≥ 0 and not empty")
    return float(u[_conformal_rank(u.size, false_alarm) - 1])


def scale_threshold(calibration: ConsistencyCalibration, factor: float,
                    *, false_alarm: float | None = None) -> ConsistencyCalibration:
    """The calibration with its threshold multiplied by ``factor`` (> 0), e.g. the
    :func:`threshold_factor` of the instrument, and the α that factor was calibrated for."""
    factor = check_scalar("factor", factor, low=0.0, low_open=True)
    alpha = calibration.false_alarm if false_alarm is None else check_scalar(
        "false_alarm", false_alarm, low=0.0, high=1.0, low_open=True, high_open=True)
    return replace(calibration, threshold=calibration.threshold * float(factor),
                   false_alarm=alpha)


def bootstrap_consistent_errors(
    consistent_model: np.ndarray,
    noise_sigma: float | np.ndarray,
    errors_of: Callable[[np.ndarray], np.ndarray],
    *,
    n_cases: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Identity errors of simulated consistent data: a parametric bootstrap for :func:`calibrate`.

    Adds Gaussian noise of the measured level to an image that satisfies the identity
    exactly (e.g. the known-lighting fit A_l L_lm rendered back to the pixels) and returns
    the identity errors of each draw. This calibrates against the noise alone; where model
    departures (grazing pixels, the unseen cap) matter, calibrate on held-out consistent
    images instead, or exclude those pixels.

    Parameters
    ----------
    consistent_model : ndarray of shape (N,)
        Samples (pixels) of a consistent image.
    noise_sigma : float or ndarray of shape (N,)
        Per-sample noise standard deviation (e.g. from the HDR merge's variance).
    errors_of : callable
        Maps samples of shape (N,) to per-order errors of shape (n_orders,).
    n_cases : int
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of shape (n_cases, n_orders)
    """
    model = check_finite("consistent_model", consistent_model)
    noise = check_finite("noise_sigma", noise_sigma)
    if np.any(noise < 0):
        raise SHInputError("noise_sigma", "must be ≥ 0")
    try:
        sig = np.broadcast_to(noise, model.shape)
    except ValueError:
        raise SHInputError("noise_sigma", f"must be a scalar or of shape {model.shape}, got "
                           f"{noise.shape}") from None
    n_cases = check_degree("n_cases", n_cases, minimum=1)
    return np.array([
        np.asarray(errors_of(model + sig * rng.standard_normal(model.shape)), dtype=float)
        for _ in range(n_cases)
    ])


def check(
    errors: np.ndarray,
    calibration: ConsistencyCalibration,
    *,
    defined: np.ndarray | None = None,
    max_error: float | None = None,
) -> ConsistencyReport:
    """Report per-order errors against the calibrated noise level, and the decision.

    The test is possible only where it could flag something. It is not (``testable``
    False, verdict :data:`NO_TEST`, never "inconsistent" nor "consistent") when no order
    is informative — every order's identity is undefined for these images (``defined``)
    or shows no spread over the consistent cases (it holds whatever the data) — or when
    even the largest error the identity admits (``max_error``, 1 for the normalised
    identity errors of :mod:`analysis.sh.identities`) at every informative order would
    not reach the threshold: a "consistent" there would say nothing.

    Parameters
    ----------
    errors : ndarray of shape (n_orders,)
        The image's normalised identity errors, same orders as the calibration.
    calibration : ConsistencyCalibration
    defined : bool ndarray of shape (n_orders,), optional
        Orders where the identity has content for these images (``IdentityError.defined``);
        default all.
    max_error : float, optional
        Largest possible error per order (> 0); default: no bound known (the power
        condition is not tested).
    """
    if not isinstance(calibration, ConsistencyCalibration):
        raise SHInputError("calibration", "must be a ConsistencyCalibration (calibrate())")
    e = check_finite("errors", errors)
    if e.shape != calibration.noise_error.shape:
        raise SHInputError("errors", f"must have one value per calibrated order "
                           f"{calibration.noise_error.shape}, got {e.shape}")
    ok = np.ones(e.shape, dtype=bool) if defined is None else np.asarray(defined, dtype=bool)
    if ok.shape != e.shape:
        raise SHInputError("defined", f"must have shape {e.shape}, got {ok.shape}")
    if calibration.informative is not None:
        ok = ok & calibration.informative
    if max_error is not None:
        max_error = check_scalar("max_error", max_error, low=0.0, low_open=True)
    z = _z(e, calibration.noise_error, calibration.noise_scale)
    t = float(statistic(np.where(ok, z, 0.0)))
    reason = ""
    if not ok.any():
        reason = ("no order carries information: the identity is undefined for these images "
                  "or holds whatever the data at every order tested")
    elif max_error is not None:
        z_max = _z(np.full(e.shape, max_error), calibration.noise_error,
                   calibration.noise_scale)
        t_max = float(statistic(np.where(ok, z_max, 0.0)))
        if t_max <= calibration.threshold:
            reason = (f"even the largest possible errors would give a statistic of "
                      f"{t_max:.3g}, not above the threshold {calibration.threshold:.3g}")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(calibration.noise_error > 0, e / calibration.noise_error, np.inf)
    return ConsistencyReport(
        orders=calibration.orders,
        error=e,
        noise_error=calibration.noise_error,
        ratio=ratio,
        z=z,
        statistic=t,
        threshold=calibration.threshold,
        inconsistent=not reason and t > calibration.threshold,
        false_alarm=calibration.false_alarm,
        testable=not reason,
        no_test_reason=reason,
    )


@dataclass(frozen=True)
class KnownLightingResidual:
    """Image-domain fit of an unknown radially symmetric BRDF under known lighting.

    Attributes
    ----------
    filter : ndarray of shape (L+1,)
        Fitted A_l.
    residual : ndarray of shape (N,)
        Samples minus the fitted image.
    relative_rms : float
        rms(residual) / mean(|samples|).
    """

    filter: np.ndarray
    residual: np.ndarray
    relative_rms: float


def known_lighting_residual(
    values: np.ndarray,
    theta: np.ndarray,
    phi: np.ndarray,
    lighting: np.ndarray,
) -> KnownLightingResidual:
    """Fit B(R) = Σ_l A_l Σ_m L_lm Y_lm(R) to samples, A_l unknown (M10 in the image domain).

    Parameters
    ----------
    values : ndarray of shape (N,)
        Image samples (radiance), e.g. the interior pixels of a sphere image.
    theta, phi : ndarray of shape (N,)
        Their reflected directions.
    lighting : ndarray of shape ((L+1)²,)
        Known lighting coefficients; L must exceed the BRDF's band limit, since the image
        holds every band the filter passes.
    """
    v = check_finite("values", values, ndim=1)
    lig, lmax = check_coefficients("lighting", lighting)
    th = check_finite("theta", theta, ndim=1)
    ph = check_finite("phi", phi, ndim=1)
    if not v.size == th.size == ph.size:
        raise SHInputError("values", f"must have one value per direction: {v.size} values, "
                           f"{th.size} theta, {ph.size} phi")
    y = real_sh_matrix(lmax, th, ph)
    basis = np.stack([y[:, band_slice(l)] @ lig[band_slice(l)] for l in range(lmax + 1)], 1)
    a, *_ = np.linalg.lstsq(basis, v, rcond=None)
    res = v - basis @ a
    scale = float(np.mean(np.abs(v)))
    rel = float(np.sqrt(np.mean(res**2)) / scale) if scale > 0 else 0.0
    return KnownLightingResidual(a, res, rel)
