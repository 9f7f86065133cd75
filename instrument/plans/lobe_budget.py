"""The error budget of a planned reading: the σ the fit will give it, before it is taken.

A promise of the lobe planner (:mod:`instrument.plans.lobe`) holds only if it weighs each
candidate reading as the fit will weigh the reading once it exists. The fit
(:func:`instrument.pipelines.brdf.analyse.analyse` on
:func:`instrument.pipelines.brdf.reduce.reduce_run`) takes

1. **the detector's noise**: shot noise and the dark-subtracted frame's read and
   dark-current noise at the exposure the point gets (the speed/accuracy planner's camera
   model, :func:`instrument.plans.tradeoff._point_noise`), with the light through the
   neutral-density filter the point will be read through;
2. **the angular error** of the read-back angles (ADR 0016): σθi of the sample stage and
   σθr of both stages (:func:`instrument.bench.angles.angular_model`), as the effective
   variance (∂F/∂θi σθi)² + (∂F/∂θr σθr)² from the model's own slopes (Orear 1982,
   *Am. J. Phys.* 50:912, eq. 8; what :func:`analysis.brdf.reduction.fit_forward` adds);
3. **the filter's transmission** (ADR 0018): an uncalibrated filter's error in each of its
   points' σ, a calibrated filter's error shared by every point read through it;
4. **the common scale** (incident power, solid angle, responsivity), propagated after the
   fit.

Items 1–2 (and an uncalibrated filter) are the independent σ the fit weighs the points
with; items 3–4 are correlated errors it propagates after the fit. The predicted
covariance of the parameters is therefore the fit's own sandwich,
C = C₀ + S Σ Sᵀ + u_s² δp δpᵀ, C₀ = (JᵀWJ)⁻¹, S = C₀JᵀW, δp = C₀JᵀW f
(GUM, JCGM 100:2008, §5.2; :mod:`analysis.brdf.reduction.uncertainty` computes the same
terms for a fit).

**Clipping.** A reading whose brightest pixel fills the well even at the shortest
exposure is a lower bound, not a value, and the fit leaves it out. The engine then reads
the point again through the next denser filter (ADR 0018); the planner predicts which:
the lightest filter (lightest first) through which the predicted peak pixel at the
shortest exposure stays below ``clip_margin`` of the well — the engine's own 20 % margin
(:meth:`instrument.run.engine.RunEngine._next_level`) — and charges the filter's costs: the
clipped open exposure and one turn of the wheel. Without a filter that helps, the
candidate is *not measurable* and is never placed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np

from analysis.brdf.geometry import make_geometry
from analysis.brdf.model import BRDFModel
from instrument.plans.tradeoff import (
    DetectorSetup,
    ScanOption,
    _point_noise,
    full_well_e,
    peak_electron_rate,
)

__all__ = ["CLIPPED", "OPEN", "ErrorBudget", "NDStep", "PointBudget", "angular_sigma",
           "point_budget", "predicted_covariance", "shared_covariance"]

#: ``PointBudget.level`` of a reading in the open beam.
OPEN = -1
#: ``PointBudget.level`` of a reading that clips whatever filter is in the beam (not
#: measurable).
CLIPPED = -2
#: Finite-difference step of the model slopes (radians), as the fit's
#: (:data:`analysis.brdf.reduction.forward._SLOPE_STEP`).
_SLOPE_STEP = 1e-4


@dataclass(frozen=True)
class NDStep:
    """A neutral-density filter of the wheel: its slot, the transmission the reduction
    will divide by and its standard uncertainty; ``calibrated`` (measured: an error shared
    by its points) or nominal (an error in each point's σ)."""

    slot: int
    transmission: float
    u: float
    calibrated: bool = True
    label: str = ""


@dataclass(frozen=True)
class ErrorBudget:
    """What besides the detector's noise the fit will put in each reading's σ (module
    docstring).

    Attributes
    ----------
    sigma_theta_i_rad, sigma_theta_r_rad : float
        The read-back angles' standard uncertainty (ADR 0016).
    filters : tuple of NDStep
        The wheel's neutral-density filters, lightest first (empty: no wheel).
    filter_move_s : float
        Seconds of one wheel turn from the open slot into a filter, charged to each
        filtered reading.
    scale_rel : float
        The run's common relative scale uncertainty (what the fit propagates).
    clip_margin : float
        Fraction of the well the predicted peak pixel must stay under at the shortest
        exposure for a reading not to be predicted clipped.
    """

    sigma_theta_i_rad: float = 0.0
    sigma_theta_r_rad: float = 0.0
    filters: tuple[NDStep, ...] = field(default=())
    filter_move_s: float = 0.0
    scale_rel: float = 0.0
    clip_margin: float = 0.8


@dataclass(frozen=True)
class PointBudget:
    """The predicted error budget of each of n readings (:func:`point_budget`).

    Attributes
    ----------
    f : ndarray (n,)
        The model's value (what the reading will measure).
    sigma : ndarray (n,)
        The independent σ the fit will weigh it with (NaN where not measurable).
    level : ndarray of int (n,)
        :data:`OPEN`, the index into ``ErrorBudget.filters`` of the filter it is read
        through, or :data:`CLIPPED`.
    rel_shared : ndarray (n,)
        The relative error shared with every reading through the same calibrated filter.
    t_us : ndarray (n,)
        The exposure it gets.
    extra_s : ndarray (n,)
        Seconds the filter adds (the clipped open exposure and the wheel's turns).
    """

    f: np.ndarray
    sigma: np.ndarray
    level: np.ndarray
    rel_shared: np.ndarray
    t_us: np.ndarray
    extra_s: np.ndarray

    @property
    def measurable(self) -> np.ndarray:
        return cast(np.ndarray, self.level != CLIPPED)  # numpy's stubs: Any

    def slots(self, budget: ErrorBudget) -> np.ndarray:
        """The wheel slot each reading is read through (-1: open beam or clipped)."""
        table = np.array([s.slot for s in budget.filters] + [-1, -1], dtype=np.int64)
        return table[np.where(self.level >= 0, self.level, len(budget.filters))]


def _shifted(angles_rad: np.ndarray, d_i: float, d_r: float) -> np.ndarray:
    out = np.array(angles_rad, dtype=float, copy=True)
    out[:, 0] = np.clip(out[:, 0] + d_i, 0.0, np.pi / 2)
    out[:, 2] = np.clip(out[:, 2] + d_r, 0.0, np.pi / 2)
    return out


def angular_sigma(model: BRDFModel, params: np.ndarray, angles_rad: np.ndarray,
                  sigma_theta_i_rad: float, sigma_theta_r_rad: float) -> np.ndarray:
    """√((∂F/∂θi σθi)² + (∂F/∂θr σθr)²) per reading: the fit's effective-variance term
    from the model's slopes (central differences of 10⁻⁴ rad, as the fit's)."""
    a = np.asarray(angles_rad, dtype=float)
    out = np.zeros(len(a))
    h = _SLOPE_STEP
    for k, s in ((0, sigma_theta_i_rad), (2, sigma_theta_r_rad)):
        if s <= 0:
            continue
        d = (h, 0.0) if k == 0 else (0.0, h)
        up = model.evaluate_geometry(params, make_geometry(*_shifted(a, *d).T))
        dn = model.evaluate_geometry(params, make_geometry(*_shifted(a, -d[0], -d[1]).T))
        out = np.hypot(out, (up - dn) / (2.0 * h) * s)
    return out


def point_budget(model: BRDFModel, params: np.ndarray, angles_rad: np.ndarray, *,
                 det: DetectorSetup, option: ScanOption, budget: ErrorBudget,
                 readout_s: float = 0.0) -> PointBudget:
    """The error budget of readings at ``angles_rad`` (n, 4) of a sample described by
    ``model`` at ``params`` (module docstring)."""
    a = np.asarray(angles_rad, dtype=float)
    p = np.asarray(params, dtype=float)
    f = np.maximum(model.evaluate_geometry(p, make_geometry(*a.T)), 1e-300)
    _, peak = peak_electron_rate(f, a[:, 0], a[:, 2], det)
    limit = budget.clip_margin * full_well_e(det)
    at_shortest = peak * det.min_exposure_us * 1e-6
    level = np.where(at_shortest < limit, OPEN, CLIPPED)
    for k, step in enumerate(budget.filters):  # lightest first: the engine's ladder
        level = np.where((level == CLIPPED) & (at_shortest * step.transmission < limit),
                         k, level)
    trans = np.ones(a.shape[0])
    rel_indep = np.zeros(a.shape[0])
    rel_shared = np.zeros(a.shape[0])
    extra = np.zeros(a.shape[0])
    # a filtered reading: the light frames that clipped in the open beam (no dark is read
    # for them), and the wheel's turn
    clipped_try = option.frames * (det.min_exposure_us * 1e-6 + readout_s)
    for k, step in enumerate(budget.filters):
        on = level == k
        trans[on] = step.transmission
        rel = step.u / step.transmission
        if step.calibrated:
            rel_shared[on] = rel
        else:
            rel_indep[on] = rel
        extra[on] = clipped_try + budget.filter_move_s
    rel, t_us = _point_noise(f, a[:, 0], a[:, 2], option, det, transmission=trans)
    sig = f * np.hypot(rel, rel_indep)
    sig = np.hypot(sig, angular_sigma(model, p, a, budget.sigma_theta_i_rad,
                                      budget.sigma_theta_r_rad))
    sig = np.where(level == CLIPPED, np.nan, sig)
    return PointBudget(f, sig, level, rel_shared, t_us, extra)


def shared_covariance(f: np.ndarray, slots: np.ndarray, rel_shared: np.ndarray
                      ) -> np.ndarray | None:
    """Covariance (BRDF units²) of readings that share a calibrated filter's error:
    f_j f_k (u_T/T)² for two readings through the same slot (None when none does)."""
    rel = np.asarray(rel_shared, dtype=float)
    if not np.any(rel > 0):
        return None
    s = np.asarray(slots)
    same = (s[:, None] == s[None, :]) & (rel[:, None] > 0) & (s[:, None] >= 0)
    fr = np.asarray(f, dtype=float) * rel
    return np.where(same, np.outer(fr, fr), 0.0)


def predicted_covariance(model: BRDFModel, params: np.ndarray, angles_rad: np.ndarray,
                         sigma: np.ndarray, *, shared: np.ndarray | None = None,
                         scale_rel: float = 0.0) -> np.ndarray:
    """The parameters' covariance a fit of readings with independent σ ``sigma``, errors
    shared as ``shared`` (n, n) and common scale ``scale_rel`` will report:
    C₀ + S Σ Sᵀ + u_s² δp δpᵀ (module docstring)."""
    a = np.asarray(angles_rad, dtype=float)
    p = np.asarray(params, dtype=float)
    g = make_geometry(*a.T)
    jac = model.jacobian_geometry(p, g).reshape(len(a), -1)
    w = 1.0 / np.asarray(sigma, dtype=float) ** 2
    c0 = np.linalg.pinv(jac.T @ (jac * w[:, None]), rcond=1e-12)
    sens = c0 @ (jac.T * w[None, :])
    cov = c0
    if shared is not None:
        cov = cov + sens @ shared @ sens.T
    if scale_rel > 0:
        dp = sens @ model.evaluate_geometry(p, g)
        cov = cov + scale_rel**2 * np.outer(dp, dp)
    return cov
