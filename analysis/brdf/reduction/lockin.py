"""Lock-in readings of a chopped photodiode → BRDF values with their uncertainty budget.

Signal model (a photodiode of responsivity R(λ) in A/W behind a transimpedance amplifier of
gain G in V/A, the source beam chopped by a 50 % duty square wave). The optical power at
the detector is a 0…P square wave, P/2 + (2P/π)(sin ωt + sin 3ωt/3 + …) (Fourier series of
a square wave); the lock-in measures the rms of the fundamental,

    R_V = (√2/π) · R(λ) · G · P        (V rms)                                   (1)

(SR830 manual, Rev. 2.5, Stanford Research Systems, 2011, p. 3-3 "What does a lock-in
measure?": a square wave of 2 V pk-pk has a fundamental of 1.273 V amplitude, 0.900 V rms).
Unchopped light (ambient) has no component at ω and drops out of (1).

Two routes to the BRDF, both through the absolute relation
f = P_s / (P_i Ω cos θr G_rx) (Nicodemus et al. 1977, NBS Monograph 160; ASTM E2387;
:func:`analysis.brdf.reduction.absolute_brdf`, whose receiver factor G_rx and angular terms
are reused):

* **Absolute** (:func:`lockin_brdf_absolute`): P_s from (1) with the photodiode's
  responsivity and transimpedance, P_i the incident power in W (a power meter in the
  direct beam). The responsivity's and the transimpedance's relative uncertainties enter
  the common scale.
* **Ratio** (:func:`lockin_brdf_ratio`): the same photodiode and lock-in read the direct
  beam, R_ref (its aperture taking the whole beam), so P_s/P_i = R_V/R_ref: responsivity,
  transimpedance and the chopper factor √2/π cancel; the reference reading's own noise
  enters the common scale.

Uncertainty budget (per point, in the columns of :class:`~analysis.brdf.reduction.BRDFPoints`):

* ``u_stat``: the standard error of the reading from the **noise model of the run's
  readings** (:func:`pooled_reading_sigma`), not from each point's own spread: with the
  engine's four snapshots a point's sample variance has 3 degrees of freedom, and
  weighting a fit by such estimates makes E[χ²/ν] = (n−1)/(n−3) = 3 (the reciprocal of a
  χ²₃/3 variable; Student 1908), the lock-in fits' χ²/ν of 3–5. The variance of one
  snapshot is a + b·R: the amplifier's and the ambient light's shot noise (a, also what
  a dark reading sees) and the shot noise of the chopped photocurrent, proportional to
  its fundamental R (photodiode docstring, hw_mocks/sim/photodiode.py; SR830 manual
  p. 3-25, noise ∝ √ENBW at a fixed time constant). a and b are fitted to all the
  points' sample variances together (a variance function estimated from the pooled
  replicates, Carroll & Ruppert 1988, *Transformation and Weighting in Regression*,
  §3.2), so the weights carry hundreds of degrees of freedom instead of three.
* Gain accuracy of the lock-in's sensitivity range: SR830 manual, Rev. 2.5, p. 1-5
  "Specifications — Signal channel: Gain accuracy ±1 % (±0.2 % typical)", one
  specification for every range 2 nV … 1 V. A limit of ±1 % read as a rectangular
  distribution gives u = 1 %/√3 (GUM JCGM 100:2008 §4.3.7). The error belongs to the
  *range*: readings on the same range share it, readings on different ranges have
  independent errors. It is carried as a covariance between points (``cov_corr``,
  propagated into fitted parameters, not fitted as noise; in the ratio route a point on
  the reference's range has it cancelled).
* Common scale ``u_scale_rel``: incident power (absolute) or the reference reading's
  standard error (ratio), the receiver solid angle, and in the absolute route the
  responsivity u(R)/R and transimpedance u(G)/G.

Readings taken while the lock-in reported an overload are not values: they are flagged
``clipped`` (left out of fits and named), like saturated camera pixels.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.reduction.receiver import ReceiverGeometry
from analysis.brdf.reduction.values import BRDFPoints, absolute_brdf

__all__ = [
    "SQUARE_CHOPPER_FUNDAMENTAL_RMS",
    "SR830_GAIN_ACCURACY_LIMIT_REL",
    "SR830_SENSITIVITIES_V",
    "Photodiode",
    "expected_lockin_r_v",
    "lockin_brdf_absolute",
    "lockin_brdf_ratio",
    "lockin_gain_u_rel",
    "lockin_power_w",
    "photodiode_from_profile",
    "pooled_reading_sigma",
    "range_covariance_rel",
]

#: rms of the fundamental of a 0…1 square wave of 50 % duty: (2/π)/√2 = √2/π (eq. 1).
SQUARE_CHOPPER_FUNDAMENTAL_RMS = math.sqrt(2.0) / math.pi
#: SR830 full-scale sensitivities, V rms (SR830 manual Rev. 2.5, p. 5-6, ``SENS`` i = 0…26).
SR830_SENSITIVITIES_V = tuple(float(f"{m}e{e}") for e in range(-9, 0) for m in (2, 5, 10))
#: SR830 gain accuracy limit, the same for every sensitivity (manual p. 1-5).
SR830_GAIN_ACCURACY_LIMIT_REL = 0.01


@dataclass(frozen=True)
class Photodiode:
    """A photodiode with its transimpedance amplifier (the bench profile's ``[photodiode]``).

    Attributes
    ----------
    responsivity_nm : tuple of float
        Wavelengths (nm, increasing) of the responsivity table; one entry: a constant.
    responsivity_a_per_w : tuple of float
        R(λ) in A/W at those wavelengths (linear interpolation; constant beyond the ends).
    u_responsivity_rel : float
        Relative standard uncertainty of R (calibration certificate).
    transimpedance_v_per_a : float
        G in V/A.
    u_transimpedance_rel : float
        Relative standard uncertainty of G.
    """

    responsivity_nm: tuple[float, ...]
    responsivity_a_per_w: tuple[float, ...]
    u_responsivity_rel: float
    transimpedance_v_per_a: float
    u_transimpedance_rel: float = 0.0

    def __post_init__(self) -> None:
        nm, r = self.responsivity_nm, self.responsivity_a_per_w
        if len(nm) != len(r) or not r:
            raise ValueError("photodiode: responsivity_nm and responsivity_a_per_w must have "
                             "the same, non-zero length")
        if any(b <= a for a, b in itertools.pairwise(nm)):
            raise ValueError("photodiode: responsivity_nm must be strictly increasing")
        if not all(math.isfinite(v) and v > 0 for v in r):
            raise ValueError("photodiode: responsivity_a_per_w must be > 0")
        if not (math.isfinite(self.transimpedance_v_per_a) and self.transimpedance_v_per_a > 0):
            raise ValueError("photodiode: transimpedance_v_per_a must be > 0")
        for label, u in (("u_responsivity_rel", self.u_responsivity_rel),
                         ("u_transimpedance_rel", self.u_transimpedance_rel)):
            if not (math.isfinite(u) and u >= 0):
                raise ValueError(f"photodiode: {label} must be ≥ 0")

    @classmethod
    def constant(cls, responsivity_a_per_w: float, transimpedance_v_per_a: float, *,
                 u_responsivity_rel: float = 0.0, u_transimpedance_rel: float = 0.0
                 ) -> Photodiode:
        """A photodiode whose responsivity does not depend on the wavelength."""
        return cls((550.0,), (float(responsivity_a_per_w),), float(u_responsivity_rel),
                   float(transimpedance_v_per_a), float(u_transimpedance_rel))

    def responsivity(self, wavelength_nm: float) -> float:
        """R(λ) in A/W."""
        if not (math.isfinite(wavelength_nm) and wavelength_nm > 0):
            raise ValueError(f"photodiode: wavelength must be > 0 nm, got {wavelength_nm}")
        return float(np.interp(wavelength_nm, self.responsivity_nm, self.responsivity_a_per_w))

    def volts_rms_per_watt(self, wavelength_nm: float) -> float:
        """(√2/π)·R(λ)·G: lock-in R per watt of chopped light (eq. 1)."""
        return (SQUARE_CHOPPER_FUNDAMENTAL_RMS * self.responsivity(wavelength_nm)
                * self.transimpedance_v_per_a)

    @property
    def u_scale_rel(self) -> float:
        """√((u_R/R)² + (u_G/G)²): what does not cancel in the absolute route."""
        return math.hypot(self.u_responsivity_rel, self.u_transimpedance_rel)


def lockin_gain_u_rel(sensitivity_v: ArrayLike, *,
                      limit_rel: float = SR830_GAIN_ACCURACY_LIMIT_REL) -> NDArray[np.float64]:
    """Standard uncertainty of the lock-in's gain at each reading's sensitivity range.

    The SR830 specifies ±1 % for every range (module docstring), read as a rectangular
    limit: u = limit/√3. A non-finite sensitivity (not recorded) gets the same value.

    Raises
    ------
    ValueError
        A sensitivity that is not positive.
    """
    s = np.asarray(sensitivity_v, dtype=float)
    if np.any(np.isfinite(s) & (s <= 0)):
        raise ValueError("lock-in sensitivity must be > 0 V (full-scale range)")
    return np.full(s.shape, limit_rel / math.sqrt(3.0))


def _range_key(sensitivity_v: NDArray[np.float64]) -> NDArray[np.int64]:
    """An integer per sensitivity range (readings on one range share its gain error);
    unrecorded ranges each get a key of their own (nothing known to be shared)."""
    s = np.asarray(sensitivity_v, dtype=float)
    key = np.round(np.log10(np.where(np.isfinite(s) & (s > 0), s, 1.0)) * 1000).astype(int)
    unknown = ~(np.isfinite(s) & (s > 0))
    key[unknown] = -10**6 - np.arange(int(unknown.sum()))
    return key


def range_covariance_rel(sensitivity_v: ArrayLike, *, reference_sensitivity_v: float | None
                         = None, limit_rel: float = SR830_GAIN_ACCURACY_LIMIT_REL
                         ) -> NDArray[np.float64]:
    """Relative covariance of the readings' gain errors, shape (n, n).

    Reading i carries the error e_s of its range s (variance u² from
    :func:`lockin_gain_u_rel`, independent between ranges): cov_ij = u² δ(s_i, s_j). Divided
    by a reference reading on range r, the error is e_{s_i} − e_r, so
    cov_ij = u² (δ(s_i, s_j) − δ(s_i, r) − δ(s_j, r) + 1), zero for a point on the
    reference's range (the error cancels).
    """
    s = np.asarray(sensitivity_v, dtype=float).reshape(-1)
    u2 = float(lockin_gain_u_rel(1.0, limit_rel=limit_rel)) ** 2
    key = _range_key(s)
    same = (key[:, None] == key[None, :]).astype(float)
    if reference_sensitivity_v is None:
        return u2 * same
    ref = _range_key(np.array([reference_sensitivity_v]))[0]
    on_ref = (key == ref).astype(float)
    return u2 * (same - on_ref[:, None] - on_ref[None, :] + 1.0)


def pooled_reading_sigma(r_v: ArrayLike, u_r_v: ArrayLike, n_readings: ArrayLike, *,
                         dark_u_v: ArrayLike | None = None,
                         n_dark_readings: ArrayLike | None = None,
                         iterations: int = 20) -> tuple[NDArray[np.float64], float, float]:
    """The standard error of each mean reading from the run's noise model (module
    docstring): (σ per point, a in V², b in V) with var(one snapshot) = a + b·R.

    Parameters
    ----------
    r_v, u_r_v : array_like, shape (n,)
        Mean R (V rms) of each point and its standard error from the point's own spread.
    n_readings : array_like of int
        Snapshots averaged at each point (≥ 2).
    dark_u_v, n_dark_readings : array_like, optional
        The dark readings' standard error of one component and their snapshot counts:
        points at R = 0 whose X and Y each carry ``n − 1`` degrees of freedom.

    a, b ≥ 0 minimise Σ ν_k (s_k² − v_k)²/v_k², the weights of a sample variance with ν_k
    degrees of freedom (Var s² = 2v²/ν), iterated from equal weights. With all spreads zero
    (noiseless readings) the points' own σ are returned unchanged.
    """
    from scipy.optimize import nnls

    r = np.abs(np.asarray(r_v, dtype=float).reshape(-1))
    n = np.broadcast_to(np.asarray(n_readings, dtype=float), r.shape)
    if np.any(n < 2):
        raise ValueError("the lock-in's noise needs at least two readings per point")
    own = np.abs(np.asarray(u_r_v, dtype=float).reshape(-1))
    s2, level, dof = own**2 * n, r, n - 1.0
    if dark_u_v is not None:
        du = np.asarray(dark_u_v, dtype=float).reshape(-1)
        dn = np.broadcast_to(np.asarray(n_dark_readings if n_dark_readings is not None
                                        else 4, dtype=float), du.shape)
        ok = np.isfinite(du)
        s2 = np.concatenate([s2, du[ok]**2 * dn[ok]])
        level = np.concatenate([level, np.zeros(int(ok.sum()))])
        dof = np.concatenate([dof, 2.0 * (dn[ok] - 1.0)])
    if not np.any(s2 > 0):
        return own, 0.0, 0.0
    design = np.stack([np.ones_like(level), level], axis=1)
    v = np.full(level.shape, float(np.mean(s2)))
    coef = np.zeros(2)
    for _ in range(iterations):
        w = np.sqrt(dof) / v
        coef, _ = nnls(design * w[:, None], s2 * w)
        new = np.maximum(design @ coef, 1e-300)
        if np.allclose(new, v, rtol=1e-6):
            break
        v = new
    a, b = float(coef[0]), float(coef[1])
    return np.sqrt((a + b * r) / n), a, b


def lockin_power_w(r_v: ArrayLike, u_r_v: ArrayLike, *, photodiode: Photodiode,
                   wavelength_nm: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(P, u_P) in W of chopped light from lock-in readings R (V rms) and their standard
    errors, inverting eq. (1)."""
    k = photodiode.volts_rms_per_watt(wavelength_nm)
    r = np.asarray(r_v, dtype=float)
    return r / k, np.abs(np.asarray(u_r_v, dtype=float)) / k


def _check_readings(r_v: ArrayLike, u_r_v: ArrayLike, sensitivity_v: ArrayLike,
                    overload: ArrayLike | None,
                    ) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]:
    r = np.asarray(r_v, dtype=float).reshape(-1)
    u = np.broadcast_to(np.asarray(u_r_v, dtype=float), r.shape).copy()
    s = np.broadcast_to(np.asarray(sensitivity_v, dtype=float), r.shape).copy()
    o = (np.zeros(r.shape, dtype=bool) if overload is None
         else np.broadcast_to(np.asarray(overload).astype(bool), r.shape).copy())
    if not np.all(np.isfinite(r)):
        raise ValueError("lock-in readings (lockin_r_v) must be finite at every point: the "
                         "run has points without a lock-in reading")
    if np.any(~np.isfinite(u) | (u < 0)):
        raise ValueError("the readings' standard errors (lockin_u_r_v) must be finite and "
                         "≥ 0; take at least two readings per point")
    return r, u, s, o


def lockin_brdf_absolute(
    r_v: ArrayLike,
    u_r_v: ArrayLike,
    sensitivity_v: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    photodiode: Photodiode,
    wavelength_nm: float,
    incident_power_w: float,
    u_incident_power_w: float = 0.0,
    solid_angle: float,
    u_solid_angle: float = 0.0,
    overload: ArrayLike | None = None,
    gain_limit_rel: float = SR830_GAIN_ACCURACY_LIMIT_REL,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    cosine_corrected: bool = False,
    receiver: ReceiverGeometry | None = None,
    cov_extra_rel: NDArray[np.float64] | None = None,
) -> BRDFPoints:
    """BRDF from lock-in readings through the photodiode's responsivity (module docstring).

    Parameters
    ----------
    r_v, u_r_v, sensitivity_v : array_like, shape (n,)
        Lock-in R (V rms, mean of the readings at each point), its standard error, and the
        full-scale sensitivity (V rms) it was read on.
    theta_i, phi_i, theta_r, phi_r : array_like, shape (n,)
        Radians (:mod:`analysis.brdf.geometry`).
    photodiode : Photodiode
    wavelength_nm : float
        Centre wavelength of the light (for R(λ)).
    incident_power_w, u_incident_power_w : float
        P_i on the sample (W) and its standard uncertainty, at this wavelength.
    solid_angle, u_solid_angle : float
        The photodiode aperture's solid angle (sr) from the sample.
    overload : array_like of bool, optional
        Readings taken in overload: flagged ``clipped``.
    gain_limit_rel : float
        The lock-in's gain accuracy limit (SR830: 0.01).
    cov_extra_rel : ndarray (n, n), optional
        Other relative errors shared between readings, added to the ranges' covariance
        (a calibrated neutral-density filter's transmission, ADR 0018).

    Returns
    -------
    BRDFPoints
        ``method`` "absolute-lockin"; ``cov_corr`` the range-shared gain errors.
    """
    r, u, s, o = _check_readings(r_v, u_r_v, sensitivity_v, overload)
    p, up = lockin_power_w(r, u, photodiode=photodiode, wavelength_nm=wavelength_nm)
    pts = absolute_brdf(p, up, theta_i, phi_i, theta_r, phi_r,
                        incident_power_w=incident_power_w,
                        u_incident_power_w=u_incident_power_w, solid_angle=solid_angle,
                        u_solid_angle=u_solid_angle,
                        u_responsivity_rel=photodiode.u_scale_rel,
                        sigma_theta_i=sigma_theta_i, sigma_theta_r=sigma_theta_r,
                        cosine_corrected=cosine_corrected, receiver=receiver,
                        cov_power_rel=_with(range_covariance_rel(s, limit_rel=gain_limit_rel),
                                            cov_extra_rel))
    return replace(pts, method="absolute-lockin", clipped=o)


def _with(cov: NDArray[np.float64], extra: NDArray[np.float64] | None) -> NDArray[np.float64]:
    return cov if extra is None else cov + np.asarray(extra, dtype=float)


def lockin_brdf_ratio(
    r_v: ArrayLike,
    u_r_v: ArrayLike,
    sensitivity_v: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    reference_r_v: float,
    u_reference_r_v: float,
    reference_sensitivity_v: float,
    solid_angle: float,
    u_solid_angle: float = 0.0,
    overload: ArrayLike | None = None,
    gain_limit_rel: float = SR830_GAIN_ACCURACY_LIMIT_REL,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    cosine_corrected: bool = False,
    receiver: ReceiverGeometry | None = None,
    cov_extra_rel: NDArray[np.float64] | None = None,
) -> BRDFPoints:
    """BRDF from the ratio of lock-in readings to a direct-beam reading of the same
    photodiode and lock-in: f = (R_V/R_ref) / (Ω cos θr G_rx). Responsivity, transimpedance
    and the chopper factor cancel (module docstring).

    ``reference_r_v``, ``u_reference_r_v`` and ``reference_sensitivity_v`` are the
    direct-beam reading (V rms), its standard error and its range; the photodiode's
    aperture must take the whole beam there. Other parameters as
    :func:`lockin_brdf_absolute`.

    Returns
    -------
    BRDFPoints
        ``method`` "ratio-lockin"; the reference's noise in ``u_scale_rel``.
    """
    r, u, s, o = _check_readings(r_v, u_r_v, sensitivity_v, overload)
    if not (math.isfinite(reference_r_v) and reference_r_v > 0):
        raise ValueError(f"the direct-beam reference reading must be > 0 V, got "
                         f"{reference_r_v}")
    if not (math.isfinite(u_reference_r_v) and u_reference_r_v >= 0):
        raise ValueError("the reference reading's standard error must be ≥ 0")
    cov = _with(range_covariance_rel(s, reference_sensitivity_v=reference_sensitivity_v,
                                     limit_rel=gain_limit_rel), cov_extra_rel)
    pts = absolute_brdf(r, u, theta_i, phi_i, theta_r, phi_r,
                        incident_power_w=float(reference_r_v),
                        u_incident_power_w=float(u_reference_r_v), solid_angle=solid_angle,
                        u_solid_angle=u_solid_angle, sigma_theta_i=sigma_theta_i,
                        sigma_theta_r=sigma_theta_r, cosine_corrected=cosine_corrected,
                        receiver=receiver, cov_power_rel=cov)
    return replace(pts, method="ratio-lockin", clipped=o)


def expected_lockin_r_v(brdf: ArrayLike, theta_r: ArrayLike, *, photodiode: Photodiode,
                        wavelength_nm: float, incident_power_w: float, solid_angle: float
                        ) -> NDArray[np.float64]:
    """Forward model for tests and benchmarks: R_V = (√2/π) R(λ) G · f P_i Ω cos θr
    (small aperture, point spot)."""
    p_s = (np.asarray(brdf, dtype=float) * incident_power_w * solid_angle
           * np.cos(np.asarray(theta_r, dtype=float)))
    return photodiode.volts_rms_per_watt(wavelength_nm) * p_s


def photodiode_from_profile(section: dict[str, Any], *, where: str = "[photodiode]") -> Photodiode:
    """A :class:`Photodiode` from the bench profile's ``[photodiode]`` table (plain data):
    ``responsivity_a_per_w`` (a number, or a list with ``responsivity_nm``),
    ``u_responsivity_rel``, ``transimpedance_v_per_a`` and optional
    ``u_transimpedance_rel``.

    Raises
    ------
    ValueError
        A missing or malformed key (named).
    """
    if "responsivity_a_per_w" not in section or "transimpedance_v_per_a" not in section:
        raise ValueError(f"{where} needs responsivity_a_per_w and transimpedance_v_per_a "
                         "to reduce lock-in readings")
    resp = section["responsivity_a_per_w"]
    if isinstance(resp, Sequence) and not isinstance(resp, str):
        if "responsivity_nm" not in section:
            raise ValueError(f"{where} responsivity_a_per_w is a table: give responsivity_nm")
        nm = tuple(float(x) for x in section["responsivity_nm"])
        vals = tuple(float(x) for x in resp)
    else:
        nm, vals = (550.0,), (float(resp),)
    return Photodiode(nm, vals, float(section.get("u_responsivity_rel", 0.0)),
                      float(section["transimpedance_v_per_a"]),
                      float(section.get("u_transimpedance_rel", 0.0)))
