"""Model selection among candidates fitted as the instrument sees them.

Every candidate is fitted with :func:`~analysis.brdf.reduction.forward.fit_forward` (its
own quadrature levels) under one noise model, ``sigma`` — the reduction's budget, whose
angular term comes from the slopes of the data. The candidates within ``plausible_delta``
of the best score (the plausible set) are then refitted with the set-point scatter taken
from their own slopes (effective variance, from ``sigma_indep``), and one rule chooses
among them — the information criterion with cross-validation:

1. **Information criterion.** Among the models within ``delta`` of the best plausible
   score, the one with the fewest parameters (ties: the lower score). The pipeline's
   ``delta`` is 6 ("strong" evidence on Kass & Raftery's 1995 scale: with 23 candidates
   some fit a smaller model's noise better by 2–6 by chance;
   :data:`instrument.pipelines.brdf.analyse.SELECTION_DELTA`); this function defaults to
   2 ("not worth more than a bare mention"). ``plausible_delta`` defaults to 10 ("very
   strong" evidence against the models beyond, same source).
2. **Cross-validation as the check.** The plausible models are scored by grouped k-fold
   cross-validation that holds out whole incidence angles (prediction at an unseen θi,
   :func:`analysis.brdf.selection.cross_validate`'s folds), each fold refitted from the
   full-data optimum with the candidate's final forward model and noise. Every model sees
   the same folds, so models are compared fold by fold (paired differences, whose
   spread is far smaller than that of the scores themselves; Hastie, Tibshirani &
   Friedman, *ESL* §7.10 on the standard error of CV estimates). CV is the check against
   over-fitting: the IC's choice stands unless a plausible model *no larger* predicts the
   held-out θi better beyond doubt — a mean paired difference above Student's t
   (97.5 %, folds − 1 degrees of freedom) standard errors; then the smallest such model
   is chosen and the rule says that CV overrode the IC. (With three incidence angles the
   standard error of a CV score rests on three folds: the unpaired one-standard-error
   rule, or two standard errors without Student's t, overrode on noise in the closed
   loop, e.g. toward Oren–Nayar at σ → 0 for a Lambertian.)

``criterion="cv"`` uses step 2 alone over the plausible set: the smallest model that the
best-scoring one does not beat beyond doubt.

Speed (benchmarks/bench_brdf_fit.py, the default 23 candidates): the sums of a diffuse and
a lobe model start from the fits of their parts and inherit the lobe part's quadrature
levels, so most converge in a few iterations; the first pass stops at χ² to 10⁻⁷ and the
plausible set is refitted to full precision; only the candidates near the best score are
refitted from more starts, and only the plausible set is cross-validated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import t as student_t

from analysis.brdf.fit import FitResult, _random_starts, fit_brdf
from analysis.brdf.geometry import flat_angles, make_geometry
from analysis.brdf.model import BRDFModel, CompositeModel
from analysis.brdf.reduction.forward import ForwardFit, fit_forward
from analysis.brdf.reduction.receiver import ReceiverGeometry
from analysis.brdf.selection import (
    ModelScore,
    SelectionResult,
    _heldout_score,
    grouped_folds,
    incidence_groups,
)

__all__ = ["ForwardSelection", "select_forward"]

_CRITERIA = ("bic", "aic", "aicc", "cv")
#: The LM tolerance of the first pass: χ² to ~10⁻⁶ is enough to rank the candidates; the
#: plausible ones are refitted to full precision.
_SCREEN_FTOL = 1e-7
#: LM iterations of a cross-validation fold (it starts at the full-data optimum).
_CV_STEPS = 6
#: Candidates within this score of the best (or whose fit failed) are refitted from their
#: other starts: a local optimum there could change the choice; far above, it cannot.
_RESTART_DELTA = 50.0


@dataclass(frozen=True)
class ForwardSelection:
    """:class:`~analysis.brdf.selection.SelectionResult` with each candidate's forward fit
    (its model at the final quadrature levels and the noise it used) and the plausible
    set."""

    selection: SelectionResult
    forward: dict[str, ForwardFit]
    plausible: tuple[str, ...]


def _starts(model: BRDFModel, fitted: dict[str, ForwardFit]) -> list[np.ndarray]:
    """The model's default start and, for a sum whose parts were fitted alone, their
    optima side by side."""
    starts = [model.start]
    if isinstance(model, CompositeModel) and all(p.name in fitted for p in model.parts):
        joined = np.concatenate([fitted[p.name].fit.params for p in model.parts])
        if np.all(np.isfinite(joined)):
            starts.insert(0, np.clip(joined, model.lower, model.upper))
    return starts


def _levels_from_parts(model: BRDFModel, fitted: dict[str, ForwardFit]) -> dict[Any, Any]:
    levels: dict[Any, Any] = {}
    if isinstance(model, CompositeModel):
        for p in model.parts:
            if p.name in fitted:
                for k, v in fitted[p.name].levels.items():
                    levels[k] = max(levels.get(k, 0), v)
    return levels


def _fit_candidate(model: BRDFModel, y: Any, angles: Any, *, sigma: Any, receiver: Any,
                   geometry: Any, fitted: dict[str, ForwardFit],
                   seed: int, tau: float) -> ForwardFit:
    """One candidate from its first start (a sum: its parts' optima), at the inherited
    levels."""
    return fit_forward(model, y, *angles, sigma=sigma, receiver=receiver,
                       start=_starts(model, fitted)[0], seed=seed, tau=tau,
                       levels=_levels_from_parts(model, fitted), geometry=geometry,
                       effective_variance=False, ftol=_SCREEN_FTOL)


def _restart(ff: ForwardFit, model: BRDFModel, y: Any, angles: Any, *, sigma: Any,
             receiver: Any, geometry: Any, fitted: dict[str, ForwardFit], seed: int,
             tau: float, n_starts: int) -> ForwardFit:
    """Look for a better optimum of a plausible candidate from its other starts (the
    default start of a sum, seeded random starts) at its final levels; refit from the best
    if one is lower."""
    starts = _starts(model, fitted)[1:]
    rng = np.random.default_rng(seed)
    starts += _random_starts(model, max(n_starts - 1 - len(starts), 0), rng)
    if not starts:
        return ff
    trials = [fit_brdf(ff.model, y, *angles, sigma=ff.sigma, start=s, geometry=geometry,
                       ftol=_SCREEN_FTOL) for s in starts]
    best = min(trials, key=lambda f: f.chi2 if np.isfinite(f.chi2) else np.inf)
    if not best.chi2 < ff.fit.chi2 - 1e-6 * max(ff.fit.chi2, 1.0):
        return ff
    return fit_forward(model, y, *angles, sigma=sigma, receiver=receiver, start=best.params,
                       seed=seed, tau=tau, levels=ff.levels, geometry=geometry,
                       effective_variance=False, ftol=_SCREEN_FTOL)


def select_forward(
    models: Sequence[BRDFModel],
    brdf: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
    receiver: ReceiverGeometry,
    sigma_indep: ArrayLike | None = None,
    criterion: str = "bic",
    delta: float = 2.0,
    plausible_delta: float = 10.0,
    n_folds: int = 5,
    run_cv: bool = True,
    seed: int = 0,
    tau: float = 0.1,
    n_starts: int = 3,
) -> ForwardSelection:
    """Fit every candidate as the instrument sees it and choose (module docstring).

    Parameters
    ----------
    models : sequence of BRDFModel
        Candidates (distinct names), as BRDF models (not yet averaged).
    brdf, theta_i, phi_i, theta_r, phi_r : array_like, shape (n,)
    sigma : array_like, shape (n,)
        The noise of the first pass (independent, its angular term from the data).
    receiver : ReceiverGeometry
    sigma_indep : array_like, shape (n,), optional
        The independent noise without the angular term: the plausible set is refitted with
        the angular term from each model's slopes (:func:`fit_forward`). None: no refit
        (``sigma`` is final).
    criterion : {"bic", "aic", "aicc", "cv"}
    delta, plausible_delta : float
        Criterion tolerances of the choice and of the plausible set.
    n_folds : int
        Folds of the grouped cross-validation.
    run_cv : bool
        Cross-validate the plausible set (forced for ``criterion="cv"``).
    n_starts : int
        Starts of a candidate within 50 of the best score (or whose fit failed): the
        first (a sum: its parts' optima), the default start of a sum, and seeded random
        ones up to ``n_starts``; the others keep their first start.
    """
    if criterion not in _CRITERIA:
        raise ValueError(f"criterion must be one of {_CRITERIA}")
    names = [m.name for m in models]
    if not names or len(set(names)) != len(names):
        raise ValueError("candidate models must be non-empty with distinct names")
    angles = flat_angles(theta_i, phi_i, theta_r, phi_r)
    y = np.asarray(brdf, dtype=float).reshape(-1)
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), y.shape)
    g = make_geometry(*angles)
    # parts before sums, so that sums can start from their parts
    order = sorted(range(len(models)), key=lambda i: isinstance(models[i], CompositeModel))
    fitted: dict[str, ForwardFit] = {}
    for i in order:
        m = models[i]
        fitted[m.name] = _fit_candidate(m, y, angles, sigma=sig, receiver=receiver,
                                        geometry=g, fitted=fitted, seed=seed, tau=tau)
    ic = "bic" if criterion == "cv" else criterion
    scores = np.array([_score(fitted[n].fit, ic) for n in names])
    ok = np.isfinite(scores)
    if not ok.any():
        raise ValueError("no candidate could be fitted (every score is NaN)")
    # multiple starts where they can change the answer: the candidates near the best
    best = float(np.min(scores[ok]))
    by_name = {m.name: m for m in models}
    for n, sc in zip(names, scores, strict=True):
        if not np.isfinite(sc) or sc <= best + _RESTART_DELTA:
            fitted[n] = _restart(fitted[n], by_name[n], y, angles, sigma=sig,
                                 receiver=receiver, geometry=g, fitted=fitted, seed=seed,
                                 tau=tau, n_starts=n_starts)
    scores = np.array([_score(fitted[n].fit, ic) for n in names])
    ok = np.isfinite(scores)
    best = float(np.min(scores[ok]))
    plausible = [n for n, sc, good in zip(names, scores, ok, strict=True)
                 if good and sc <= best + plausible_delta]
    # the plausible set to full precision, and with the set-point scatter from each
    # model's own slopes where the axes have one
    angular = sigma_indep is not None and (receiver.sigma_theta_i_rad > 0
                                           or receiver.sigma_theta_r_rad > 0)
    s_fin = (np.broadcast_to(np.asarray(sigma_indep, dtype=float), y.shape) if angular
             else sig)
    for n in plausible:
        ff = fitted[n]
        fitted[n] = fit_forward(by_name[n], y, *angles, sigma=s_fin, receiver=receiver,
                                start=ff.fit.params, seed=seed, tau=tau, levels=ff.levels,
                                geometry=g, effective_variance=angular)
    cv: dict[str, np.ndarray] = {}
    folds = grouped_folds(incidence_groups(angles[0]), n_folds, seed=seed)
    if (run_cv or criterion == "cv") and folds:
        for n in plausible:
            cv[n] = _cross_validate(fitted[n], y, angles, folds)
    rows = tuple(
        ModelScore(name=n, n_params=fitted[n].fit.n_params, chi2=fitted[n].fit.chi2,
                   log_likelihood=fitted[n].fit.log_likelihood, aic=fitted[n].fit.aic,
                   aicc=fitted[n].fit.aicc, bic=fitted[n].fit.bic,
                   cv_score=_mean_se(cv[n])[0] if n in cv else float("nan"),
                   cv_stderr=_mean_se(cv[n])[1] if n in cv else float("nan"),
                   converged=fitted[n].fit.converged)
        for n in names)
    why_no_cv = ("cross-validation not asked for" if not (run_cv or criterion == "cv")
                 else "fewer than two θi")
    chosen, rule = _choose(rows, ic, criterion, delta, plausible, cv, why_no_cv)
    sel = SelectionResult(chosen, criterion, rule, rows,
                          {n: fitted[n].fit for n in names})
    return ForwardSelection(sel, fitted, tuple(plausible))


def _score(fit: FitResult, criterion: str) -> float:
    value = {"bic": fit.bic, "aic": fit.aic, "aicc": fit.aicc}[criterion]
    return float(value) if fit.converged and np.isfinite(value) else float("nan")


def _mean_se(x: np.ndarray) -> tuple[float, float]:
    """(mean, standard error of the mean) of fold scores (NaN error for one fold)."""
    x = np.asarray(x, dtype=float)
    se = float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")
    return float(x.mean()), se


def _cross_validate(ff: ForwardFit, y: Any, angles: Any, folds: Any) -> np.ndarray:
    """Grouped-fold CV of a fitted candidate: each fold refitted from the full-data optimum
    with its final forward model and noise; the held-out mean r² of each fold."""
    g = make_geometry(*angles)
    scores = []
    for test in folds:
        train = ~test
        # from the full-data optimum the fold's optimum is a few LM steps away
        fit = fit_brdf(ff.model, y[train], *(a[train] for a in angles), sigma=ff.sigma[train],
                       start=ff.fit.params, geometry=g.take(train), ftol=_SCREEN_FTOL,
                       max_nfev=_CV_STEPS)
        pred = ff.model.evaluate_geometry(fit.params, g.take(test))
        scores.append(_heldout_score(y[test], pred, ff.sigma[test], "absolute"))
    return np.array(scores)


def _choose(rows: Sequence[ModelScore], ic: str, criterion: str, delta: float,
            plausible: list[str], cv: dict[str, np.ndarray],
            why_no_cv: str = "fewer than two θi") -> tuple[str, str]:
    by = {r.name: r for r in rows}

    def ic_score(r: ModelScore) -> float:
        return r.score(ic) if r.converged else float("nan")

    # the plausible set was refitted under its final noise: compare within it only
    scored = [r for r in rows if r.name in plausible and np.isfinite(ic_score(r))]
    best = min(ic_score(r) for r in scored)
    near = [r for r in scored if ic_score(r) <= best + delta]
    ic_pick = min(near, key=lambda r: (r.n_params, ic_score(r)))
    rule_ic = f"fewest parameters within Δ{ic.upper()} ≤ {delta:g} of the best"
    cvs = {n: cv[n] for n in plausible if n in cv and np.all(np.isfinite(cv[n]))}
    if not cvs:
        if criterion == "cv":
            raise ValueError("cross-validation needs at least two incidence angles")
        return ic_pick.name, rule_ic + f" (no cross-validation: {why_no_cv})"
    c_best = min(cvs, key=lambda n: float(np.mean(cvs[n])))

    def beaten(name: str, by: str) -> bool:
        """``by`` predicts held-out θi better than ``name`` beyond doubt: the mean paired
        fold difference exceeds Student's t (97.5 %, folds − 1 dof) standard errors."""
        d = cvs[name] - cvs[by]
        m, se = _mean_se(d)
        if d.size < 2 or not np.isfinite(se):
            return False
        return m > float(student_t.ppf(0.975, d.size - 1)) * se

    rule_cv = ("grouped-by-θi cross-validation: fewest parameters not beaten beyond doubt "
               "(paired fold differences, Student's t at 97.5 %)")
    if criterion == "cv":
        ok = [by[n] for n in cvs if n == c_best or not beaten(n, c_best)]
        pick = min(ok, key=lambda r: (r.n_params, float(np.mean(cvs[r.name]))))
        return pick.name, rule_cv + " (plausible set)"
    # CV is the check against over-fitting: it can move the choice to a model no larger
    # than the IC's that predicts unseen θi better beyond doubt, never to a larger one
    better = [by[n] for n in cvs if by[n].n_params <= ic_pick.n_params
              and n != ic_pick.name and ic_pick.name in cvs and beaten(ic_pick.name, n)]
    if not better:
        return ic_pick.name, (rule_ic + "; no model as small predicts held-out θi better "
                              "on grouped cross-validation beyond doubt")
    pick = min(better, key=lambda r: (r.n_params, float(np.mean(cvs[r.name]))))
    return pick.name, (f"{rule_ic} gave {ic_pick.name}; {pick.name}, no larger, predicts "
                       f"held-out θi better beyond doubt (grouped cross-validation, paired "
                       f"fold differences, Student's t at 97.5 %): CV overrode it")
