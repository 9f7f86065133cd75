"""Which pBRDF the data need: the variants of :func:`analysis.polarimetry.pbrdf.fit_pbrdf`
compared by an information criterion, the chosen one judged by the goodness-of-fit gate.

The variants hold parameters of the one pBRDF model fixed (the project's rule: model only
what a scene requires):

* ``fresnel_dielectric``: microfacet Fresnel reflection of a real index (k = 0), no
  diffuse layer (albedo = 0): n, α;
* ``fresnel_dielectric+diffuse``: the same plus the depolarising Lambertian layer: n, α, ρ;
* ``fresnel_metal``: a complex index n + ik, no diffuse layer: n, k, α;
* ``fresnel_metal+diffuse``: all of n, k, α, ρ.

The polarimeter's frame ``frame_deg`` is free in every variant unless the caller fixes it
(it belongs to the instrument, not the sample; ADR 0107).

The data's covariance is known, so −2 ln L = χ² + const and the criteria are
AIC = χ² + 2p, AICc = AIC + 2p(p+1)/(N−p−1), BIC = χ² + p ln N, N the number of whitened
residuals (Akaike 1974; Schwarz 1978; Burnham & Anderson 2002, §2.4 and §6.4). The rule
is that of the scalar selection (:func:`analysis.brdf.selection.choose_by_criterion`):
among the variants within Δ ≤ 2 of the best score the one with the fewest parameters wins
(Kass & Raftery 1995). The chosen variant's χ² then meets the gate (ADR 0051); a variant
that fails it is reported as failing, never accepted by a looser rule.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from analysis.brdf.reduction.receiver import ReceiverGeometry
from analysis.brdf.selection import ModelScore, choose_by_criterion
from analysis.polarimetry.pbrdf import PBRDF_PARAMS, PbrdfFit, fit_pbrdf
from analysis.polarimetry.validation import PolarimetryInputError

__all__ = ["PBRDF_VARIANTS", "PbrdfSelection", "select_pbrdf"]

#: Variant name → the sample parameters it holds fixed (at k = 0 and albedo = 0).
PBRDF_VARIANTS: Mapping[str, tuple[str, ...]] = {
    "fresnel_dielectric": ("k", "albedo"),
    "fresnel_dielectric+diffuse": ("k",),
    "fresnel_metal": ("albedo",),
    "fresnel_metal+diffuse": (),
}
#: Where a metal variant starts k when the caller's start is a dielectric's (k at its bound
#: 0 the search could not leave the dielectric).
_METAL_K_START = 1.0
_CRITERIA = ("bic", "aic", "aicc")


@dataclass(frozen=True)
class PbrdfSelection:
    """The outcome of :func:`select_pbrdf`.

    Attributes
    ----------
    chosen : str
        The variant the rule chose.
    criterion, rule : str
        The criterion and the rule in words.
    table : tuple of ModelScore
        Every variant's χ², criteria and parameter count, in :data:`PBRDF_VARIANTS` order.
    fits : mapping str → PbrdfFit
        Every variant's fit.
    """

    chosen: str
    criterion: str
    rule: str
    table: tuple[ModelScore, ...]
    fits: Mapping[str, PbrdfFit]

    @property
    def chosen_fit(self) -> PbrdfFit:
        return self.fits[self.chosen]


def _start_for(name: str, start: np.ndarray) -> np.ndarray:
    p = start.copy()
    held = PBRDF_VARIANTS[name]
    if "k" in held:
        p[1] = 0.0
    elif p[1] <= 0.0:
        p[1] = _METAL_K_START
    if "albedo" in held:
        p[3] = 0.0
    elif p[3] <= 0.0:
        p[3] = 0.1  # off the bound, where the search can move it
    return p


def select_pbrdf(m: ArrayLike, cov: ArrayLike, theta_i: ArrayLike, phi_i: ArrayLike,
                 theta_r: ArrayLike, phi_r: ArrayLike, *, start: ArrayLike,
                 variants: Sequence[str] = tuple(PBRDF_VARIANTS),
                 fixed: Sequence[str] = (), distribution: str = "beckmann",
                 criterion: str = "bic", delta: float = 2.0,
                 receiver: ReceiverGeometry | None = None) -> PbrdfSelection:
    """Fit every variant and choose the smallest the data support (module docstring).

    Parameters
    ----------
    m, cov, theta_i, phi_i, theta_r, phi_r, distribution, receiver
        As for :func:`~analysis.polarimetry.pbrdf.fit_pbrdf`.
    start : array_like of shape (5,) or (4,)
        Start values; each variant takes k and albedo from it where it fits them.
    variants : sequence of str
        Names from :data:`PBRDF_VARIANTS`.
    fixed : sequence of str
        Parameters held in every variant besides its own (e.g. ``("frame_deg",)``).
    criterion : {"bic", "aic", "aicc"}
    delta : float
        Tolerance of the "fewest parameters" rule, in units of the criterion.

    Raises
    ------
    PolarimetryInputError
        Unknown variant or criterion, an empty list, or the input errors of ``fit_pbrdf``.
    """
    if criterion not in _CRITERIA:
        raise PolarimetryInputError("criterion", f"must be one of {_CRITERIA}, "
                                    f"got {criterion!r}")
    names = list(variants)
    unknown = [v for v in names if v not in PBRDF_VARIANTS]
    if unknown or not names:
        raise PolarimetryInputError("variants", f"must name some of {tuple(PBRDF_VARIANTS)}, "
                                    f"got {names}")
    p0 = np.asarray(start, dtype=float)
    if p0.shape == (4,):
        p0 = np.append(p0, 0.0)
    if p0.shape != (5,):
        raise PolarimetryInputError("start", f"must hold 4 or 5 values {PBRDF_PARAMS}")
    fits: dict[str, PbrdfFit] = {}
    rows: list[ModelScore] = []
    for name in names:
        held = tuple(dict.fromkeys((*PBRDF_VARIANTS[name], *fixed)))
        fit = fit_pbrdf(m, cov, theta_i, phi_i, theta_r, phi_r, start=_start_for(name, p0),
                        fixed=held, distribution=distribution, receiver=receiver)
        fits[name] = fit
        k = sum(1 for p in PBRDF_PARAMS if p not in held)
        n = fit.goodness.dof + k
        chi2 = fit.goodness.chi2
        aicc = (chi2 + 2 * k + 2 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0
                else math.inf)
        rows.append(ModelScore(name=name, n_params=k, chi2=chi2, log_likelihood=-0.5 * chi2,
                               aic=chi2 + 2 * k, aicc=aicc, bic=chi2 + k * math.log(n),
                               cv_score=math.nan, cv_stderr=math.nan,
                               converged=bool(np.all(np.isfinite(fit.params)))))
    chosen, rule = choose_by_criterion(rows, criterion, delta)
    return PbrdfSelection(chosen=chosen, criterion=criterion, rule=rule, table=tuple(rows),
                          fits=fits)
