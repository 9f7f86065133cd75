"""The forward model a fit compares the data with, and the fit that keeps it honest.

A reduced value is the normalised average of the BRDF over what its reading integrated
(:mod:`analysis.brdf.reduction.receiver`: beam footprint and divergence, receiver
aperture, axis set-point spread). :func:`forward_model` is a model under that average
with a quadrature level per point; :func:`fit_forward` fits it and chooses the levels and
the noise so that neither limits the answer:

1. **Quadrature error below the noise.** Every point starts at level 0 of
   :data:`~analysis.brdf.reduction.receiver.LEVELS`. At the optimum the model is also
   evaluated one level finer; a point whose value moves by more than ``tau`` × its σ
   (default 0.1: a bias of at most a tenth of a standard deviation) goes up a level and
   the fit is repeated from where it stopped, until no point moves (or the finest level
   is reached, which is reported). The finer level is far more accurate than the coarser,
   so their difference bounds the coarser one's error — the adaptive rule of nested
   quadratures (e.g. Gander & Gautschi 2000, *BIT* 40:84, on error estimation by a finer
   rule).
2. **Set-point scatter as noise** (effective variance; Orear 1982, *Am. J. Phys.* 50:912,
   eq. 8): an axis that stops within σθ of its read-back scatters the reading by
   |∂F/∂θ| σθ. With the slopes of the *model* (central differences of F, not of the data,
   which are too coarse across a sharp lobe), σ_eff² = σ² + (∂F/∂θi σθi)² + (∂F/∂θr σθr)²
   is recomputed at each optimum and the fit repeated until σ_eff changes by less than
   5 %. The log-likelihood, and so every information criterion, uses σ_eff.

Both loops share the refits; three or four rounds are typical for a sharp lobe, one for a
smooth model (level 0 already agrees with level 1 within the noise).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.fit import FitResult, fit_brdf
from analysis.brdf.geometry import Geometry, flat_angles, make_geometry
from analysis.brdf.model import BRDFModel
from analysis.brdf.reduction.receiver import LEVELS, ReceiverGeometry, _AtLevels, prepared_nodes

__all__ = ["ForwardFit", "fit_forward", "forward_model", "forward_slopes", "point_keys"]

#: The quadrature level of a fitted forward model at geometries it was not fitted on.
_DISPLAY_LEVEL = 2
#: Finite-difference step of the model slopes (radians): far below any lobe this instrument
#: resolves (its kernel is ~10⁻² rad), far above rounding.
_SLOPE_STEP = 1e-4


def point_keys(g: Geometry) -> list[tuple[float, ...]]:
    """A hashable key per point of ``g`` (its direction components rounded to 1e-12):
    the same measured point in a subset of the data (a cross-validation fold) has the
    same key. Cached on the geometry."""
    if "point_keys" not in g.cache:
        comps = np.round(np.stack([g.xi, g.yi, g.mu_i, g.xr, g.yr, g.mu_r], axis=-1)
                         .reshape(-1, 6), 12)
        g.cache["point_keys"] = [tuple(row) for row in comps.tolist()]
    return g.cache["point_keys"]


def forward_model(model: BRDFModel, receiver: ReceiverGeometry,
                  levels: dict[tuple[float, ...], int] | None = None, *,
                  default_level: int = 0) -> BRDFModel:
    """``model`` averaged over each reading's nodes, at the level ``levels`` gives the point
    (by :func:`point_keys`; ``default_level`` for points not listed). Same name and
    parameters as ``model``; a plain :class:`~analysis.brdf.model.BRDFModel`."""
    table = dict(levels or {})

    def levels_for(g: Geometry) -> NDArray[np.intp]:
        return np.array([table.get(k, default_level) for k in point_keys(g)], dtype=np.intp)

    n_up = sum(1 for v in table.values() if v > default_level)
    label = f"quadrature level {default_level}" + (f", {n_up} points finer" if n_up else "")
    return _AtLevels(model, receiver, levels_for, label, by_geometry=True).as_model()


def _evaluate(model: BRDFModel, receiver: ReceiverGeometry, p: NDArray[Any], g: Geometry,
              levels: NDArray[np.intp]) -> NDArray[np.float64]:
    nodes = prepared_nodes(g, receiver, levels)
    return nodes.sums(model.value_fn(p, nodes.geometry) * nodes.weights)


def _shifted(g: Geometry, d_theta_i: float, d_theta_r: float) -> Geometry:
    """``g`` with every polar angle moved by the given amounts (clipped to [0, π/2]),
    cached on ``g`` (so are the shifted geometry's quadrature nodes)."""
    key = ("shifted", d_theta_i, d_theta_r)
    if key not in g.cache:
        g.cache[key] = _shift(g, d_theta_i, d_theta_r)
    return g.cache[key]


def _shift(g: Geometry, d_theta_i: float, d_theta_r: float) -> Geometry:
    ti = np.arccos(np.clip(g.mu_i, -1.0, 1.0)).reshape(-1)
    tr = np.arccos(np.clip(g.mu_r, -1.0, 1.0)).reshape(-1)
    pi_ = np.arctan2(g.yi, g.xi).reshape(-1)
    pr = np.arctan2(g.yr, g.xr).reshape(-1)
    return make_geometry(np.clip(ti + d_theta_i, 0.0, np.pi / 2), pi_,
                         np.clip(tr + d_theta_r, 0.0, np.pi / 2), pr)


def forward_slopes(model: BRDFModel, receiver: ReceiverGeometry, params: ArrayLike,
                   g: Geometry, levels: ArrayLike) -> tuple[NDArray[Any], NDArray[Any]]:
    """(∂F/∂θi, ∂F/∂θr) of the forward model at every point of ``g`` (per radian),
    by central differences of step 10⁻⁴ rad at the given levels."""
    p = np.asarray(params, dtype=float)
    lev = np.asarray(levels, dtype=np.intp).reshape(-1)
    h = _SLOPE_STEP
    out = []
    for di, dr in ((h, 0.0), (0.0, h)):
        up = _evaluate(model, receiver, p, _shifted(g, di, dr), lev)
        dn = _evaluate(model, receiver, p, _shifted(g, -di, -dr), lev)
        out.append((up - dn) / (2.0 * h))
    return out[0], out[1]


@dataclass(frozen=True)
class ForwardFit:
    """Result of :func:`fit_forward`.

    Attributes
    ----------
    fit : FitResult
        The fit at the final levels and noise (its σ-scaled residuals, χ², criteria).
    model : BRDFModel
        The forward model at the final levels (for predictions and cross-validation);
        at level 2 on geometries it was not fitted on.
    levels : dict
        Quadrature level per point key (points at 0 are left out).
    sigma : ndarray, shape (n,)
        The noise the final fit used: σ_eff (module docstring).
    quadrature_error : ndarray, shape (n,)
        |F(next level) − F| at the optimum, the bound on each value's quadrature error
        (at the finest level, the change from the level below).
    quadrature_converged : bool
        Every point's bound is within ``tau`` σ (False: the finest level was not enough).
    rounds : int
        Fits made.
    """

    fit: FitResult
    model: BRDFModel
    levels: dict[tuple[float, ...], int]
    sigma: NDArray[np.float64]
    quadrature_error: NDArray[np.float64]
    quadrature_converged: bool
    rounds: int
    notes: tuple[str, ...] = field(default=())


def fit_forward(
    model: BRDFModel,
    brdf: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
    receiver: ReceiverGeometry,
    start: ArrayLike | None = None,
    n_starts: int = 1,
    seed: int = 0,
    tau: float = 0.1,
    levels: dict[tuple[float, ...], int] | None = None,
    geometry: Geometry | None = None,
    max_rounds: int = 8,
    effective_variance: bool = True,
    ftol: float = 1e-10,
) -> ForwardFit:
    """Fit ``model`` as the instrument sees it (module docstring).

    Parameters
    ----------
    model : BRDFModel
        The BRDF model (not yet averaged).
    brdf, theta_i, phi_i, theta_r, phi_r : array_like, shape (n,)
        Reduced values (receiver factor divided out) and nominal angles (radians).
    sigma : array_like, shape (n,)
        Independent standard uncertainty of each value *without* the angular term (signal
        noise, reference table), which :func:`fit_forward` adds from the model's slopes
        and the receiver's σθ.
    receiver : ReceiverGeometry
    start, n_starts, seed
        As for :func:`~analysis.brdf.fit.fit_brdf` (the extra random starts are used in the
        first round only; later rounds start from the previous optimum).
    tau : float
        Largest quadrature error allowed, in units of each point's σ.
    levels : dict, optional
        Starting levels (e.g. from a fit of a similar model).
    geometry : Geometry, optional
        Prebuilt geometry of the points.
    effective_variance : bool
        Add the set-point scatter from the model's slopes (False: ``sigma`` is used as it
        is, e.g. when it already holds an angular term taken from the data).
    ftol : float
        The LM solver's relative cost tolerance (:func:`~analysis.brdf.fit.fit_brdf`).

    Returns
    -------
    ForwardFit
    """
    y = np.asarray(brdf, dtype=float).reshape(-1)
    sig0 = np.broadcast_to(np.asarray(sigma, dtype=float), y.shape).astype(float)
    g = geometry if geometry is not None else make_geometry(
        *flat_angles(theta_i, phi_i, theta_r, phi_r))
    keys = point_keys(g)
    table = {k: v for k, v in (levels or {}).items() if v > 0}
    top = len(LEVELS) - 1
    sti, str_ = receiver.sigma_theta_i_rad, receiver.sigma_theta_r_rad
    if not effective_variance:
        sti = str_ = 0.0
    sig = sig0.copy()
    p0 = None if start is None else np.asarray(start, dtype=float)
    fit: FitResult | None = None
    fm = forward_model(model, receiver, table)
    err = np.zeros(y.size)
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        fm = forward_model(model, receiver, table)
        fit = fit_brdf(fm, y, theta_i, phi_i, theta_r, phi_r, sigma=sig, start=p0,
                       n_starts=n_starts if rounds == 1 else 1, seed=seed, geometry=g,
                       ftol=ftol)
        p0 = fit.params
        if not np.all(np.isfinite(fit.params)):
            break
        lev = np.array([table.get(k, 0) for k in keys], dtype=np.intp)
        value = _evaluate(model, receiver, fit.params, g, lev)
        # the bound on each value's quadrature error: the change to the next level (at the
        # finest level, the change from the one below, which over-states it)
        other = np.where(lev < top, lev + 1, lev - 1)
        err = np.abs(_evaluate(model, receiver, fit.params, g, other) - value)
        move = (err > tau * sig) & (lev < top)
        changed = False
        if sti > 0 or str_ > 0:
            d_i, d_r = forward_slopes(model, receiver, fit.params, g, lev)
            new = np.sqrt(sig0**2 + (d_i * sti) ** 2 + (d_r * str_) ** 2)
            changed = bool(np.max(np.abs(new / sig - 1.0)) > 0.05)
            sig = new
        if not move.any() and not changed:
            break
        for j in np.flatnonzero(move):
            table[keys[j]] = int(lev[j]) + 1
    assert fit is not None
    # the model to report: every fitted point at its level, other geometries (plots,
    # predictions) at a level accurate for all but the sharpest grazing lobes
    full = {k: table.get(k, 0) for k in keys}
    fm = forward_model(model, receiver, full, default_level=_DISPLAY_LEVEL)
    converged = bool(np.all(err <= tau * sig))
    notes = () if converged else (
        f"{model.name}: the instrument-function quadrature did not reach {tau:g}σ at "
        f"{int(np.sum(err > tau * sig))} point(s) even at the finest level",)
    return ForwardFit(fit, fm, table, sig, err, converged, rounds, notes)
