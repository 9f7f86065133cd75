"""Lobe-adaptive rendering of the wall's outgoing radiance: any specular width, bounded cost.

The quantity is that of the reference quadrature in :mod:`hw_mocks.sim.lightfield_scene`
(Sasaki 2020, PhD thesis, Univ. of Minnesota, eqs. 2-3, 2-6 with the BRDF of eq. 2-14)::

    L_m(c, θ_m) = Σ_k ∫_{lo_k}^{hi_k} f(θ_o − Θ, θ_m − Θ) cos⁺(θ_o − Θ) L_k(c, θ_o) dθ_o

with ``f = s_s(c) f_wind(θ_o − Θ) ρ_s N(θ_m − θ_o; 0, σ) + s_d(c) ρ_d/2``.  The reference
integrates the whole object interval with panels of σ/4, so its cost grows as 1/σ (20 s per
camera view at σ = 0.0001°).  Here the two terms are integrated apart:

* **Specular.** In the lobe's own variable ``t = (θ_o − θ_m)/σ`` the Gaussian is the
  standard normal density φ(t) (``N(θ_m − θ_o; 0, σ) dθ_o = φ(t) dt``), so the term is
  ``ρ_s s_s ∫ φ(t) G(θ_m + σ t) dt`` with ``G = f_wind cos⁺ L_k``.  The limits are the object's
  exact angular edges ``(lo − θ_m)/σ, (hi − θ_m)/σ`` clipped to the lobe's window ±8
  (φ beyond it < 10⁻¹⁵ of the total): nodes fall only where the lobe does, and an edge of
  the object inside the lobe is an integration limit, not a discontinuity between nodes.
  Gauss–Legendre panels at most one unit of t wide (and at most ``PANEL_RAD`` in θ where
  the object's radiance varies), so at most 16 panels per ray whatever σ is.  As σ → 0 the
  integral tends to ``G(θ_m)`` when θ_m lies inside the object's interval and 0 outside:
  the perfect mirror, which the same formula gives at σ = 0 exactly.
* **Diffuse.** ``s_d ρ_d/2 ∫ cos⁺(θ_o − Θ) L_k dθ_o``: for an object of uniform radiance R
  (a disc, a bar) in closed form ``R [sin x]`` between the clipped relative edges; otherwise
  Gauss–Legendre panels of at most ``PANEL_RAD``.

The reference renderer stays, as the check of this one where both run
(``tests/analysis/lightfield/test_lobe_renderer.py``; ADR 0033).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from analysis.lightfield.brdf import FlatlandBRDF, SpatiallyVaryingBRDF

__all__ = ["LOBE_WINDOW", "PANEL_RAD", "lobe_radiance", "supports"]

#: Half-width of the specular window in units of σ: φ(t) beyond ±8 integrates to 1.2e-15.
LOBE_WINDOW = 8.0
#: Largest panel (rad) over which an object's varying radiance is integrated: the
#: reference's default panel where the BRDF gives no width.
PANEL_RAD = 2e-3
_GL_NODES = 8
_HALF_PI = np.pi / 2 - 1e-9
#: Ray × node evaluations per vectorised block (bounds the memory of one call).
_CHUNK = 1_000_000

_X, _W = np.polynomial.legendre.leggauss(_GL_NODES)
_X = (_X + 1.0) / 2.0
_W = _W / 2.0
_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


def supports(brdf: Any) -> bool:
    """True for the BRDFs this renderer knows the lobe of (eq. 2-14, homogeneous or not)."""
    return isinstance(brdf, FlatlandBRDF | SpatiallyVaryingBRDF)


def _gl(fun: Callable[[NDArray, NDArray], NDArray], a: NDArray, b: NDArray, n_panels: int,
        rows: NDArray[np.intp]) -> NDArray[np.float64]:
    """∫_a^b fun(rows, x) dx per ray by ``n_panels`` equal Gauss–Legendre panels.

    ``fun(sel, x)`` gets the ray indices ``sel`` (k,) and nodes ``x`` (k, m) and returns
    the integrand there; the rays are done in blocks of at most ``_CHUNK`` evaluations.
    """
    out = np.zeros(a.size)
    nodes = ((np.arange(n_panels)[:, None] + _X[None, :]) / n_panels).ravel()
    weights = np.tile(_W / n_panels, n_panels)
    per = max(1, _CHUNK // nodes.size)
    for s in range(0, a.size, per):
        width = (b[s:s + per] - a[s:s + per])[:, None]
        x = a[s:s + per, None] + width * nodes[None, :]
        out[s:s + per] = np.sum(fun(rows[s:s + per], x) * weights[None, :], axis=1) \
            * width[:, 0]
    return out


def _uniform(obj: Any) -> float | None:
    """The object's radiance if it is the same on every ray that meets it, else None."""
    value = getattr(obj, "uniform_radiance", None)
    return None if value is None else float(value)


def lobe_radiance(
    brdf: FlatlandBRDF | SpatiallyVaryingBRDF,
    normal_rad: NDArray[np.float64],
    objects: Sequence[Any],
    c_mm: NDArray[np.float64],
    theta_m_rad: NDArray[np.float64],
    *,
    width_rad: float | None = None,
) -> NDArray[np.float64]:
    """Radiance leaving wall points ``c_mm`` along ``theta_m_rad`` (1-D arrays, one per ray).

    Parameters
    ----------
    brdf : the wall's BRDF (:func:`supports` must hold)
    normal_rad : (n,) — the wall's local normal angle Θ at each ray's wall point
    objects : the hidden objects (``interval``, ``radiance_at`` and, for uniform ones,
        ``uniform_radiance``)
    c_mm, theta_m_rad : (n,) — each ray's wall point and outgoing angle
    width_rad : σ of the lobe instead of the BRDF's (0: the perfect-mirror limit)
    """
    base = brdf.base if isinstance(brdf, SpatiallyVaryingBRDF) else brdf
    c = np.asarray(c_mm, dtype=float)
    tm = np.asarray(theta_m_rad, dtype=float)
    tn = np.asarray(normal_rad, dtype=float)
    if isinstance(brdf, SpatiallyVaryingBRDF):
        s_spec = np.asarray(brdf.specular_scale(c), dtype=float) * base.specular_reflectance
        s_diff = np.asarray(brdf.diffuse_scale(c), dtype=float) * (0.5 * base.diffuse_reflectance)
    else:
        s_spec = np.full(c.shape, base.specular_reflectance)
        s_diff = np.full(c.shape, 0.5 * base.diffuse_reflectance)
    sigma = base.specular_width_rad if width_rad is None else float(width_rad)
    q = base.window_exponent
    out = np.zeros(c.size)
    if c.size == 0:
        return out
    for obj in objects:
        lo, hi = obj.interval(c)
        lo = np.clip(lo, -_HALF_PI, _HALF_PI)
        hi = np.clip(hi, -_HALF_PI, _HALF_PI)
        radiance = _uniform(obj)
        out += s_diff * _diffuse(obj, radiance, c, tn, lo, hi)
        out += s_spec * _specular(obj, radiance, c, tn, tm, lo, hi, sigma, q)
    return out


def _diffuse(obj: Any, radiance: float | None, c: NDArray, tn: NDArray, lo: NDArray,
             hi: NDArray) -> NDArray[np.float64]:
    """∫_lo^hi cos⁺(θ_o − Θ) L(c, θ_o) dθ_o per ray."""
    if radiance is not None:
        # ∫ cos⁺ x dx = sin x on [−π/2, π/2], flat outside it
        x_lo = np.clip(lo - tn, -np.pi / 2, np.pi / 2)
        x_hi = np.clip(hi - tn, -np.pi / 2, np.pi / 2)
        return radiance * (np.sin(x_hi) - np.sin(x_lo))
    span = float(np.max(hi - lo))
    n = max(1, int(np.ceil(span / PANEL_RAD)))

    def integrand(sel, x):
        cc = c[sel][:, None]
        return np.clip(np.cos(x - tn[sel][:, None]), 0.0, None) * obj.radiance_at(cc, x)

    return _gl(integrand, lo, hi, n, np.arange(c.size))


def _specular(obj: Any, radiance: float | None, c: NDArray, tn: NDArray, tm: NDArray,
              lo: NDArray, hi: NDArray, sigma: float, q: float) -> NDArray[np.float64]:
    """∫ φ(t) f_wind cos⁺ L at θ_o = θ_m + σt, t between the object's edges in the window."""
    out = np.zeros(c.size)
    if sigma > 0:
        t_lo = np.clip((lo - tm) / sigma, -LOBE_WINDOW, LOBE_WINDOW)
        t_hi = np.clip((hi - tm) / sigma, -LOBE_WINDOW, LOBE_WINDOW)
    else:
        # the mirror: the whole window where θ_m lies within the object's interval
        inside = (lo <= tm) & (tm <= hi)
        t_lo = np.where(inside, -LOBE_WINDOW, 0.0)
        t_hi = np.where(inside, LOBE_WINDOW, 0.0)
    rows = np.nonzero(t_hi > t_lo)[0]
    if rows.size == 0:
        return out
    t_range = float(np.max(t_hi[rows] - t_lo[rows]))
    n = max(1, int(np.ceil(t_range)))
    if radiance is None and sigma > 0:
        n = max(n, int(np.ceil(t_range * sigma / PANEL_RAD)))

    def integrand(sel, t):
        theta_o = tm[sel][:, None] + sigma * t
        rel = theta_o - tn[sel][:, None]
        g = np.clip(np.cos(rel), 0.0, None)
        if q:
            g = g ** (1.0 + q)
        lobe = _INV_SQRT_2PI * np.exp(-0.5 * t * t)
        if radiance is not None:
            return lobe * g * radiance
        return lobe * g * obj.radiance_at(c[sel][:, None], theta_o)

    out[rows] = _gl(integrand, t_lo[rows], t_hi[rows], n, rows)
    return out
