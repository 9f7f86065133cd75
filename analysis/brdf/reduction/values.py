"""BRDF values with their uncertainty budget: the absolute and the relative (reference) method.

Nicodemus et al. 1977 (NBS Monograph 160) for f = dL_r/dE_i; ASTM E2387 practice for the
absolute method; Li & Torrance 2003 for the reference-standard method; instrument-signature
subtraction point by point. Conventions in the package docstring of
:mod:`analysis.brdf.reduction`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.geometry import flat_angles
from analysis.brdf.reduction.angular import angular_uncertainty
from analysis.brdf.reduction.receiver import ReceiverGeometry, receiver_factor


@dataclass(frozen=True)
class BRDFPoints:
    """Reduced BRDF values with their uncertainty budget; every array has shape (n,).

    Attributes
    ----------
    theta_i, phi_i, theta_r, phi_r : ndarray
        Radians (conventions of :mod:`analysis.brdf.geometry`).
    brdf : ndarray
        f (1/sr), or f·cos θr when ``cosine_corrected``.
    u_stat, u_angle, u_ref : ndarray
        Independent standard uncertainties (same unit as ``brdf``); see the module docstring.
    u_scale_rel : float
        Relative standard uncertainty common to all points (correlated).
    cosine_corrected : bool
    method : str
        "absolute" or "relative" (with "-signature" appended after a subtraction).
    receiver : ReceiverGeometry or None
        What each reading integrated (beam footprint × receiver aperture); the values are
        then the normalised average of f over it (:func:`receiver_model`), which an
        instrument-aware fit compares them with. ``None``: treated as point samples.
    cov_corr : ndarray, shape (n, n), or None
        Covariance (unit of ``brdf`` squared) of errors shared between points, e.g. the
        camera's pixel response (:func:`pixel_response_covariance`). Like the common scale
        it is not fitted as noise: :func:`with_correlated_uncertainty` propagates it.
    clipped : ndarray of bool, shape (n,), or None
        Readings clipped by the detector (pixels saturated even in the shortest exposure,
        :attr:`CameraSignal.clipped_pixels`): lower bounds, not values. Fits leave them
        out and say so.
    """

    theta_i: NDArray[np.float64]
    phi_i: NDArray[np.float64]
    theta_r: NDArray[np.float64]
    phi_r: NDArray[np.float64]
    brdf: NDArray[np.float64]
    u_stat: NDArray[np.float64]
    u_angle: NDArray[np.float64]
    u_ref: NDArray[np.float64]
    u_scale_rel: float
    cosine_corrected: bool
    method: str
    receiver: ReceiverGeometry | None = None
    cov_corr: NDArray[np.float64] | None = None
    clipped: NDArray[np.bool_] | None = None

    @property
    def n(self) -> int:
        return int(self.brdf.size)

    @property
    def u_point(self) -> NDArray[np.float64]:
        """Independent part: √(u_stat² + u_angle² + u_ref²) — the σ to fit with."""
        return np.sqrt(self.u_stat**2 + self.u_angle**2 + self.u_ref**2)

    @property
    def u_indep(self) -> NDArray[np.float64]:
        """√(u_stat² + u_ref²): the independent part without the angular term, for fits
        that take the angular scatter from the model's own slopes (effective variance,
        :func:`analysis.brdf.reduction.fit_forward`)."""
        return np.sqrt(self.u_stat**2 + self.u_ref**2)

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Points that are values (not clipped lower bounds)."""
        return np.ones(self.n, dtype=bool) if self.clipped is None else ~self.clipped

    @property
    def u_total(self) -> NDArray[np.float64]:
        """Combined standard uncertainty of each value, common and correlated parts
        included."""
        corr = np.diag(self.cov_corr) if self.cov_corr is not None else 0.0
        return np.sqrt(self.u_point**2 + (self.brdf * self.u_scale_rel) ** 2 + corr)

    def plain_brdf(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(f, u_point) as the BRDF f whatever ``cosine_corrected`` is."""
        if not self.cosine_corrected:
            return self.brdf, self.u_point
        c = np.maximum(np.cos(self.theta_r), 1e-12)
        return self.brdf / c, self.u_point / c

    def plain_u_indep(self) -> NDArray[np.float64]:
        """:attr:`u_indep` for the BRDF f whatever ``cosine_corrected`` is."""
        if not self.cosine_corrected:
            return self.u_indep
        return self.u_indep / np.maximum(np.cos(self.theta_r), 1e-12)

    def plain_cov_corr(self) -> NDArray[np.float64] | None:
        """:attr:`cov_corr` for the BRDF f whatever ``cosine_corrected`` is."""
        if self.cov_corr is None or not self.cosine_corrected:
            return self.cov_corr
        c = np.maximum(np.cos(self.theta_r), 1e-12)
        return self.cov_corr / np.outer(c, c)

    def take(self, index: ArrayLike) -> BRDFPoints:
        """The subset ``index`` (boolean mask or integer indices)."""
        idx = np.asarray(index)
        return replace(
            self, theta_i=self.theta_i[idx], phi_i=self.phi_i[idx],
            theta_r=self.theta_r[idx], phi_r=self.phi_r[idx], brdf=self.brdf[idx],
            u_stat=self.u_stat[idx], u_angle=self.u_angle[idx], u_ref=self.u_ref[idx],
            cov_corr=(None if self.cov_corr is None
                      else self.cov_corr[np.ix_(*(np.arange(self.n)[idx],) * 2)]),
            clipped=None if self.clipped is None else self.clipped[idx],
        )


def absolute_brdf(
    power_w: ArrayLike,
    u_power_w: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    incident_power_w: float,
    u_incident_power_w: float = 0.0,
    solid_angle: float,
    u_solid_angle: float = 0.0,
    u_responsivity_rel: float = 0.0,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    cosine_corrected: bool = False,
    receiver: ReceiverGeometry | None = None,
    cov_power_rel: ArrayLike | None = None,
) -> BRDFPoints:
    """BRDF by the absolute method, f = P_s / (P_i Ω cos θr G) (module docstring, step 2).

    Parameters
    ----------
    power_w, u_power_w : array_like, shape (n,)
        Collected scattered power P_s (W) and its independent standard uncertainty.
    theta_i, phi_i, theta_r, phi_r : array_like, shape (n,)
        Radians.
    incident_power_w, u_incident_power_w : float
        P_i on the sample (W) and its standard uncertainty.
    solid_angle, u_solid_angle : float
        Receiver solid angle Ω (sr), e.g. from
        :func:`~analysis.brdf.reduction.detector.solid_angle_sr`.
    u_responsivity_rel : float
        Relative uncertainty of the detector's responsivity that does not cancel against
        P_i (e.g. the camera's Kη when P_i comes from a power meter).
    sigma_theta_i, sigma_theta_r : float
        Angular standard uncertainties (radians), propagated through the local slope.
    cosine_corrected : bool
        Return f·cos θr instead of f (module docstring).
    receiver : ReceiverGeometry, optional
        What each reading integrated. Given, the receiver factor G
        (:func:`receiver_factor`) is divided out, so that a value is the normalised
        average of f over the footprint and aperture (exact for a Lambertian sample), and
        the geometry is kept on the result for instrument-aware fitting. Without it G = 1:
        a point spot and a point receiver (biased by a few 10⁻⁴ on the sim bench).
    cov_power_rel : array_like, shape (n, n), optional
        Relative covariance of the collected powers shared between points (the camera's
        pixel response, :func:`pixel_response_covariance`); kept as ``cov_corr``.

    Returns
    -------
    BRDFPoints
        ``u_scale_rel`` = √((u_Pi/Pi)² + (u_Ω/Ω)² + u_resp²).
    """
    p = np.asarray(power_w, dtype=float).reshape(-1)
    up = np.broadcast_to(np.asarray(u_power_w, dtype=float), p.shape)
    ti, pi_, tr, pr = flat_angles(theta_i, phi_i, theta_r, phi_r)
    if ti.shape != p.shape:
        raise ValueError(f"angles have shape {ti.shape} but power has {p.shape}")
    if not (incident_power_w > 0 and solid_angle > 0):
        raise ValueError("incident power and solid angle must be > 0")
    cos_r = np.maximum(np.cos(tr), 1e-12)
    denom = incident_power_w * solid_angle * (1.0 if cosine_corrected else cos_r)
    if receiver is not None:
        denom = denom * receiver_factor(ti, pi_, tr, pr, receiver=receiver)
    f = p / denom
    u_stat = np.abs(up / denom)
    scale = float(np.sqrt((u_incident_power_w / incident_power_w) ** 2
                          + (u_solid_angle / solid_angle) ** 2 + u_responsivity_rel**2))
    u_ang = angular_uncertainty(f, ti, tr, sigma_theta_i=sigma_theta_i,
                                sigma_theta_r=sigma_theta_r, phi_i=pi_, phi_r=pr)
    cov = None
    if cov_power_rel is not None:
        c_rel = np.asarray(cov_power_rel, dtype=float)
        if c_rel.shape != (f.size, f.size):
            raise ValueError(f"cov_power_rel must have shape ({f.size}, {f.size})")
        cov = c_rel * np.outer(f, f)
    return BRDFPoints(ti, pi_, tr, pr, f, u_stat, u_ang, np.zeros_like(f), scale,
                      bool(cosine_corrected), "absolute", receiver, cov)


@dataclass(frozen=True)
class ReferenceStandard:
    """The measured BRDF table of a reference standard (calibration certificate).

    Attributes
    ----------
    name : str
    theta_i_deg : ndarray, shape (m,)
        Increasing incidence angles of the table (degrees).
    theta_r_deg : ndarray, shape (q,)
        Increasing *signed* in-plane viewing angles (degrees; > 0 on the specular side,
        < 0 on the source side, as in plan files).
    brdf : ndarray, shape (m, q)
        f_ref (1/sr).
    u_rel : ndarray, shape (m, q)
        Relative standard uncertainty of each entry (independent part).
    u_scale_rel : float
        Relative uncertainty of the certificate's overall scale (e.g. of the DHR it was
        scaled to), common to all entries.
    """

    name: str
    theta_i_deg: NDArray[np.float64]
    theta_r_deg: NDArray[np.float64]
    brdf: NDArray[np.float64]
    u_rel: NDArray[np.float64]
    u_scale_rel: float = 0.0

    def __post_init__(self) -> None:
        ti = np.asarray(self.theta_i_deg, dtype=float)
        tr = np.asarray(self.theta_r_deg, dtype=float)
        f = np.asarray(self.brdf, dtype=float)
        u = np.broadcast_to(np.asarray(self.u_rel, dtype=float), f.shape)
        if f.shape != (ti.size, tr.size):
            raise ValueError(f"brdf must have shape ({ti.size}, {tr.size}), got {f.shape}")
        if np.any(np.diff(ti) <= 0) or np.any(np.diff(tr) <= 0):
            raise ValueError("table angles must be strictly increasing")
        if np.any(f <= 0) or np.any(u < 0):
            raise ValueError("table values must be > 0 and uncertainties >= 0")
        for name, v in (("theta_i_deg", ti), ("theta_r_deg", tr), ("brdf", f),
                        ("u_rel", np.array(u))):
            object.__setattr__(self, name, v)

    @classmethod
    def uniform(
        cls, name: str, reflectance: float, *, u_rel: float = 0.0, u_scale_rel: float = 0.0,
        theta_i_deg: ArrayLike = (0.0, 89.0), theta_r_deg: ArrayLike = (-89.0, 89.0),
    ) -> ReferenceStandard:
        """A table with the same value ρ/π everywhere — an *ideal* diffuser's certificate.

        Only for ideal simulated standards: a real diffuser's table comes from its
        certificate (ASTM E2387: Spectralon is not Lambertian at large angles).
        """
        ti = np.asarray(theta_i_deg, dtype=float)
        tr = np.asarray(theta_r_deg, dtype=float)
        f = np.full((ti.size, tr.size), reflectance / np.pi)
        return cls(name, ti, tr, f, np.full(f.shape, u_rel), u_scale_rel)

    def evaluate(self, theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike,
                 phi_r: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(f_ref, u_ref) at in-plane angles in radians, bilinear in (θi, signed θr).

        The signed viewing angle is +θr when the detector is on the far side of the normal
        from the source (|φr − φi| ≈ π), −θr otherwise. Outside the table: ValueError.
        """
        ti, pi_, tr, pr = flat_angles(theta_i, phi_i, theta_r, phi_r)
        dphi = np.abs(np.angle(np.exp(1j * (pr - pi_))))
        signed = np.where(dphi > np.pi / 2, tr, -tr)
        x, y = np.degrees(ti), np.degrees(signed)
        tol = 1e-6
        if (np.any(x < self.theta_i_deg[0] - tol) or np.any(x > self.theta_i_deg[-1] + tol)
                or np.any(y < self.theta_r_deg[0] - tol)
                or np.any(y > self.theta_r_deg[-1] + tol)):
            raise ValueError(f"angles outside the table of reference {self.name!r}")
        f = _bilinear(self.theta_i_deg, self.theta_r_deg, self.brdf, x, y)
        u = _bilinear(self.theta_i_deg, self.theta_r_deg, self.brdf * self.u_rel, x, y)
        return f, u


def _bilinear(gx: NDArray[Any], gy: NDArray[Any], table: NDArray[Any], x: NDArray[Any],
              y: NDArray[Any]) -> NDArray[Any]:
    """Bilinear interpolation on a rectilinear grid (size-1 axes are constant)."""

    def locate(g: NDArray[Any], v: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
        if g.size == 1:
            return np.zeros(v.shape, dtype=int), np.zeros(v.shape)
        j = np.clip(np.searchsorted(g, v, side="right") - 1, 0, g.size - 2)
        w = np.clip((v - g[j]) / (g[j + 1] - g[j]), 0.0, 1.0)
        return j, w

    jx, wx = locate(gx, x)
    jy, wy = locate(gy, y)
    jx1 = np.minimum(jx + 1, gx.size - 1)
    jy1 = np.minimum(jy + 1, gy.size - 1)
    return ((1 - wx) * (1 - wy) * table[jx, jy] + wx * (1 - wy) * table[jx1, jy]
            + (1 - wx) * wy * table[jx, jy1] + wx * wy * table[jx1, jy1])


def relative_brdf(
    signal: ArrayLike,
    u_signal: ArrayLike,
    ref_signal: ArrayLike,
    u_ref_signal: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    reference: ReferenceStandard,
    monitor: ArrayLike | None = None,
    ref_monitor: ArrayLike | None = None,
    u_monitor_rel: float = 0.0,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    cosine_corrected: bool = False,
) -> BRDFPoints:
    """BRDF by the relative method, f = (S/S_ref)·(M_ref/M)·f_ref(θi, θr) (module docstring).

    Parameters
    ----------
    signal, u_signal : array_like, shape (n,)
        Sample signal (any unit proportional to collected power) and its σ.
    ref_signal, u_ref_signal : array_like, shape (n,)
        Reference-standard signal at the same geometry, same unit.
    theta_i, phi_i, theta_r, phi_r : array_like, shape (n,)
        Radians; the table is looked up here.
    reference : ReferenceStandard
    monitor, ref_monitor : array_like, optional
        Source monitor readings during the sample and reference measurements (drift).
    u_monitor_rel : float
        Relative uncertainty of one monitor ratio (common to all points).

    Returns
    -------
    BRDFPoints
        ``u_stat`` from both signals, ``u_ref`` from the table, ``u_scale_rel`` from the
        certificate scale and the monitor.
    """
    s = np.asarray(signal, dtype=float).reshape(-1)
    us = np.broadcast_to(np.asarray(u_signal, dtype=float), s.shape)
    r = np.broadcast_to(np.asarray(ref_signal, dtype=float), s.shape)
    ur = np.broadcast_to(np.asarray(u_ref_signal, dtype=float), s.shape)
    ti, pi_, tr, pr = flat_angles(theta_i, phi_i, theta_r, phi_r)
    if ti.shape != s.shape:
        raise ValueError(f"angles have shape {ti.shape} but signal has {s.shape}")
    if np.any(r <= 0):
        raise ValueError("reference signals must be > 0")
    drift = np.ones_like(s)
    if monitor is not None or ref_monitor is not None:
        if monitor is None or ref_monitor is None:
            raise ValueError("give both monitor and ref_monitor, or neither")
        drift = (np.broadcast_to(np.asarray(ref_monitor, float), s.shape)
                 / np.broadcast_to(np.asarray(monitor, float), s.shape))
    f_ref, u_fref = reference.evaluate(ti, pi_, tr, pr)
    ratio = s / r * drift
    # the table is f; cosine-corrected output multiplies both sides by cos θr
    c = np.cos(tr) if cosine_corrected else np.ones_like(tr)
    f = ratio * f_ref * c
    # independent: both signals' noise (first order), and the table entry
    u_stat = np.abs(f) * np.sqrt((us / np.where(s != 0, s, np.inf)) ** 2 + (ur / r) ** 2)
    u_stat = np.where(s != 0, u_stat, np.abs(us / r * drift * f_ref * c))
    u_tab = np.abs(ratio * u_fref * c)
    scale = float(np.hypot(reference.u_scale_rel, u_monitor_rel))
    u_ang = angular_uncertainty(f, ti, tr, sigma_theta_i=sigma_theta_i,
                                sigma_theta_r=sigma_theta_r, phi_i=pi_, phi_r=pr)
    return BRDFPoints(ti, pi_, tr, pr, f, u_stat, u_ang, u_tab, scale,
                      bool(cosine_corrected), "relative")


def subtract_signature(
    points: BRDFPoints, signature: ArrayLike, u_signature: ArrayLike
) -> BRDFPoints:
    """Remove the instrument signature (ASTM E2387; Li & Torrance 2003), point by point.

    ``signature`` is the BRDF-equivalent signal measured with no sample (or a beam dump) at
    the same detector positions and reduced the same way (same method, same
    ``cosine_corrected``), shape (n,). Its uncertainty adds to ``u_stat`` in quadrature.
    """
    sig = np.broadcast_to(np.asarray(signature, dtype=float), points.brdf.shape)
    us = np.broadcast_to(np.asarray(u_signature, dtype=float), points.brdf.shape)
    method = points.method if points.method.endswith("-signature") else (
        points.method + "-signature")
    return replace(points, brdf=points.brdf - sig, u_stat=np.hypot(points.u_stat, us),
                   method=method)

