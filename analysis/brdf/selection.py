"""Model selection: information criteria with an explicit noise model and k-fold
cross-validation grouped by incidence angle; the smallest model the data support wins.

Rules (the smallest model the data support)
-----------------------------------------------------------------
* ``criterion`` in {"bic", "aic", "aicc"}: every candidate is fitted to all data under the
  same noise model (:mod:`analysis.brdf.fit`); the best score is found and, among the models
  within ``delta`` of it (default 2: "not worth more than a bare mention", Kass & Raftery 1995;
  Burnham & Anderson 2002 §2.6), the one with the fewest parameters is chosen (ties: lower
  score).
* ``criterion="cv"``: grouped k-fold cross-validation — the folds hold out whole incidence
  angles, so the score measures prediction at an *unseen* θi; the score is the mean squared
  normalised residual on held-out points. The one-standard-error rule (Hastie, Tibshirani &
  Friedman, *ESL* §7.10) picks the smallest model whose score is within one standard error of
  the best.

The whole comparison table is kept in :class:`SelectionResult`, CV scores included whenever
there are at least two incidence angles.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from analysis.brdf.fit import FitResult, fit_brdf
from analysis.brdf.geometry import make_geometry
from analysis.brdf.model import BRDFModel

_CRITERIA = ("bic", "aic", "aicc", "cv")


@dataclass(frozen=True)
class ModelScore:
    """One row of the comparison table.

    Attributes
    ----------
    name : str
    n_params : int
    chi2 : float
    log_likelihood, aic, aicc, bic : float
    cv_score, cv_stderr : float
        Mean held-out squared normalised residual and its standard error (NaN if not run).
    converged : bool
    """

    name: str
    n_params: int
    chi2: float
    log_likelihood: float
    aic: float
    aicc: float
    bic: float
    cv_score: float
    cv_stderr: float
    converged: bool

    def score(self, criterion: str) -> float:
        return float(
            {"bic": self.bic, "aic": self.aic, "aicc": self.aicc, "cv": self.cv_score}[criterion]
        )


@dataclass(frozen=True)
class SelectionResult:
    """Outcome of :func:`select_model`.

    Attributes
    ----------
    chosen : str
        Name of the selected model.
    criterion : str
    rule : str
        The decision rule in words (for the report).
    table : tuple of ModelScore
        All candidates, in the order given.
    fits : mapping str → FitResult
        Full-data fits of every candidate.
    """

    chosen: str
    criterion: str
    rule: str
    table: tuple[ModelScore, ...]
    fits: Mapping[str, FitResult]

    @property
    def chosen_fit(self) -> FitResult:
        return self.fits[self.chosen]

    def to_dict(self) -> dict[str, object]:
        """Plain values: the decision, the table (one dict per model) and every fit."""
        return {
            "chosen": self.chosen,
            "criterion": self.criterion,
            "rule": self.rule,
            "table": [asdict(r) for r in self.table],
            "fits": {k: f.to_dict() for k, f in self.fits.items()},
        }


def incidence_groups(theta_i: ArrayLike, *, tol_rad: float = 1e-3) -> np.ndarray:
    """Integer group label per point, one per set incidence angle.

    Sorted θi closer than ``tol_rad`` to their neighbour share a label (default 10⁻³ rad ≈
    0.06°: stage read-backs jitter by ~10⁻⁵ rad around the set angle, scan steps are
    degrees), so a fold never splits one incidence angle into "seen" and "unseen" parts.
    """
    t = np.asarray(theta_i, dtype=float).reshape(-1)
    order = np.argsort(t, kind="stable")
    labels = np.empty(t.size, dtype=np.int64)
    labels[order] = np.concatenate([[0], np.cumsum(np.diff(t[order]) > tol_rad)])
    return labels


def grouped_folds(groups: np.ndarray, n_folds: int, *, seed: int = 0) -> list[np.ndarray]:
    """Boolean test masks of k folds that never split a group (shuffled with ``seed``)."""
    uniq = np.unique(groups)
    k = min(n_folds, uniq.size)
    if k < 2:
        return []
    perm = np.random.default_rng(seed).permutation(uniq)
    return [np.isin(groups, perm[f::k]) for f in range(k)]


def cross_validate(
    model: BRDFModel,
    brdf: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike | None = None,
    residual: str = "absolute",
    n_folds: int = 5,
    seed: int = 0,
    n_starts: int = 1,
) -> tuple[float, float]:
    """Grouped (by incidence angle) k-fold CV: (mean held-out r², its standard error).

    Returns (nan, nan) when there are fewer than two incidence angles.
    """
    ti, pi_, tr, pr = np.broadcast_arrays(
        *(np.asarray(a, dtype=float).reshape(-1) for a in (theta_i, phi_i, theta_r, phi_r))
    )
    y = np.asarray(brdf, dtype=float).reshape(-1)
    sig = None if sigma is None else np.broadcast_to(np.asarray(sigma, float), y.shape)
    folds = grouped_folds(incidence_groups(ti), n_folds, seed=seed)
    if not folds:
        return float("nan"), float("nan")
    g = make_geometry(ti, pi_, tr, pr)
    scores = []
    for test in folds:
        train = ~test
        fit = fit_brdf(
            model, y[train], ti[train], pi_[train], tr[train], pr[train],
            sigma=None if sig is None else sig[train], residual=residual,
            n_starts=n_starts, seed=seed, geometry=g.take(train),
        )
        m = model.evaluate_geometry(fit.params, g.take(test))
        scores.append(_heldout_score(y[test], m, None if sig is None else sig[test], residual))
    arr = np.array(scores)
    se = float(arr.std(ddof=1) / np.sqrt(arr.size)) if arr.size > 1 else float("nan")
    return float(arr.mean()), se


def _heldout_score(y: np.ndarray, m: np.ndarray, sig: np.ndarray | None, residual: str) -> float:
    floor = 1e-6
    if residual == "log":
        r = np.log(np.maximum(y, 0.0) + floor) - np.log(np.maximum(m, 0.0) + floor)
        if sig is not None:
            r = r * (np.maximum(y, 0.0) + floor) / sig
    elif residual == "relative" and sig is None:
        r = (y - m) / np.maximum(np.abs(y), floor)
    else:
        r = (y - m) / (1.0 if sig is None else sig)
    return float(np.mean(r * r))


def select_model(
    models: Sequence[BRDFModel],
    brdf: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike | None = None,
    residual: str = "absolute",
    criterion: str = "bic",
    delta: float = 2.0,
    n_folds: int = 5,
    run_cv: bool = True,
    n_starts: int = 3,
    seed: int = 0,
) -> SelectionResult:
    """Fit every candidate and choose the smallest model the data support.

    Parameters
    ----------
    models : sequence of BRDFModel
        Candidates (names must be distinct).
    brdf, theta_i, phi_i, theta_r, phi_r, sigma, residual
        As for :func:`~analysis.brdf.fit.fit_brdf`; one noise model for all candidates.
    criterion : {"bic", "aic", "aicc", "cv"}
    delta : float
        Information-criterion tolerance of the "smallest model" rule (ignored for "cv").
    n_folds : int
        Folds of the grouped cross-validation.
    run_cv : bool
        Compute CV scores for the table even when the criterion is an IC (costs n_folds fits
        per model); forced on for ``criterion="cv"``.

    Returns
    -------
    SelectionResult
    """
    if criterion not in _CRITERIA:
        raise ValueError(f"criterion must be one of {_CRITERIA}")
    names = [m.name for m in models]
    if len(set(names)) != len(names) or not names:
        raise ValueError("candidate models must be non-empty with distinct names")
    fits: dict[str, FitResult] = {}
    rows: list[ModelScore] = []
    do_cv = run_cv or criterion == "cv"
    y = np.asarray(brdf, dtype=float).reshape(-1)
    angles = [
        np.broadcast_to(np.asarray(a, dtype=float), np.shape(brdf)).reshape(-1)
        for a in (theta_i, phi_i, theta_r, phi_r)
    ]
    if sigma is not None:
        sigma = np.broadcast_to(np.asarray(sigma, dtype=float), np.shape(brdf)).reshape(-1)
    geometry = make_geometry(*angles)  # shared by every candidate's full-data fit
    for m in models:
        fit = fit_brdf(
            m, y, *angles, sigma=sigma, residual=residual, n_starts=n_starts, seed=seed,
            geometry=geometry,
        )
        fits[m.name] = fit
        cv, cv_se = (
            cross_validate(
                m, y, *angles, sigma=sigma, residual=residual,
                n_folds=n_folds, seed=seed, n_starts=n_starts,
            )
            if do_cv
            else (float("nan"), float("nan"))
        )
        rows.append(
            ModelScore(
                name=m.name, n_params=m.n_params, chi2=fit.chi2,
                log_likelihood=fit.log_likelihood, aic=fit.aic, aicc=fit.aicc, bic=fit.bic,
                cv_score=cv, cv_stderr=cv_se, converged=fit.converged,
            )
        )
    chosen, rule = choose_by_criterion(rows, criterion, delta)
    return SelectionResult(chosen, criterion, rule, tuple(rows), fits)


def choose_by_criterion(rows: Sequence[ModelScore], criterion: str,
                        delta: float) -> tuple[str, str]:
    """The rule of :func:`select_model` on a filled comparison table: the chosen name and
    the rule in words (shared with the polarimetric selection,
    :mod:`analysis.polarimetry.pbrdf_selection`)."""
    scores = np.array([r.score(criterion) for r in rows])
    ok = np.isfinite(scores)
    if not np.any(ok):
        raise ValueError(f"no candidate has a finite {criterion} score (too few θi for CV?)")
    best = int(np.nanargmin(np.where(ok, scores, np.inf)))
    if criterion == "cv":
        se = rows[best].cv_stderr
        tol = se if np.isfinite(se) else 0.0
        rule = "one-standard-error rule on grouped-by-θi cross-validation"
    else:
        tol = delta
        rule = f"fewest parameters within Δ{criterion.upper()} ≤ {delta:g} of the best"
    cand = [i for i in range(len(rows)) if ok[i] and scores[i] <= scores[best] + tol]
    pick = min(cand, key=lambda i: (rows[i].n_params, scores[i]))
    return rows[pick].name, rule
