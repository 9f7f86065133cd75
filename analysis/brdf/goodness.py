"""Goodness of fit: does the model describe the data within their stated noise?

With the noise known (σ from the reduction's budget, s = 1), the weighted residual sum
χ² = Σ r² of a correct linear(ised) model with k fitted parameters follows the χ²
distribution with ν = n − k degrees of freedom: mean ν, standard deviation √(2ν), so
χ²/ν = 1 ± √(2/ν) (Press et al., *Numerical Recipes*, 3rd ed., §15.1–15.2; Bevington &
Robinson, *Data Reduction and Error Analysis*, 3rd ed., §11.1). The p-value is
P(χ²_ν ≥ χ²) — the chance that a correct model fits this badly or worse.

The rule the pipeline applies (docs/decisions/0051-goodness-of-fit-gate.md):

* p < ``alpha`` (default 0.001): **the model does not describe the data**. The fitted
  parameters are the best approximation the model allows, and their covariance σ,
  computed as if the model were right, is not an uncertainty of the sample's properties.
  They are reported with their standard errors multiplied by the Birge ratio
  R_B = √(χ²/ν) (Birge 1932, *Phys. Rev.* 40:207; the scale factor of the Particle Data
  Group, PDG *Review of Particle Physics*, Introduction §5.2.2) and flagged as inflated.
  The inflation only makes the scatter of the residuals consistent with the σ; a model
  error is not noise, so the flag, not the number, is the message.
* the points that disagree are named: those with |r| > 3 (two-sided probability 0.27 %
  each under the model), largest first; when a rejected model spreads its misfit so that
  none exceeds 3, the five largest.
* p > 1 − ``alpha``: χ² far below its expected value — the stated σ are likely too large
  (a conservative budget); reported, not acted on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["DEFAULT_ALPHA", "GoodnessOfFit", "OffsetPattern", "goodness_of_fit", "offset_pattern"]

#: p-value below which a model is rejected.
DEFAULT_ALPHA = 1e-3
#: |r| above which a point is named as disagreeing.
OUTLIER_Z = 3.0


@dataclass(frozen=True)
class GoodnessOfFit:
    """χ² test of one fit (module docstring).

    Attributes
    ----------
    chi2 : float
    dof : int
        ν = n − k.
    p_value : float
        P(χ²_ν ≥ χ²).
    alpha : float
        The rejection threshold used.
    disagreeing : tuple of int
        Indices (into the fitted points) of the points that disagree, largest |r| first.
    residuals : tuple of float
        Their normalised residuals r = (y − F)/σ.
    """

    chi2: float
    dof: int
    p_value: float
    alpha: float
    disagreeing: tuple[int, ...]
    residuals: tuple[float, ...]

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    @property
    def expected_spread(self) -> float:
        """√(2/ν): one standard deviation of χ²/ν for a correct model."""
        return float(np.sqrt(2.0 / self.dof)) if self.dof > 0 else float("nan")

    @property
    def adequate(self) -> bool:
        """Not rejected at ``alpha`` (a NaN χ², a failed fit, counts as rejected)."""
        return bool(np.isfinite(self.p_value) and self.p_value >= self.alpha)

    @property
    def too_good(self) -> bool:
        """χ² improbably small: the stated σ are likely overestimated."""
        return bool(np.isfinite(self.p_value) and self.p_value > 1.0 - self.alpha)

    @property
    def birge_ratio(self) -> float:
        """√(χ²/ν), the factor the rule inflates σ by when the model is rejected (≥ 1)."""
        return float(max(1.0, np.sqrt(self.reduced_chi2))) if self.dof > 0 else float("nan")

    def summary(self) -> str:
        """χ²/ν with its expected spread and the p-value, in words."""
        p = "p < 1e-300" if self.p_value == 0.0 else f"p = {self.p_value:.2g}"
        return (f"χ²/dof = {self.reduced_chi2:.4g} for {self.dof} dof (expected 1 ± "
                f"{self.expected_spread:.2g}), {p}")

    def verdict(self) -> str:
        """The sentence reports print."""
        if not self.adequate:
            return f"the model does not describe the data ({self.summary()})"
        if self.too_good:
            return (f"the model describes the data; χ² is improbably small, so the stated "
                    f"uncertainties of the data are likely too large ({self.summary()})")
        return f"the model describes the data ({self.summary()})"

    def to_dict(self) -> dict[str, object]:
        return {"chi2": self.chi2, "dof": self.dof, "reduced_chi2": self.reduced_chi2,
                "expected_spread": self.expected_spread, "p_value": self.p_value,
                "alpha": self.alpha, "adequate": self.adequate, "too_good": self.too_good,
                "birge_ratio": self.birge_ratio, "disagreeing": list(self.disagreeing),
                "disagreeing_residuals": list(self.residuals), "verdict": self.verdict()}


def goodness_of_fit(residuals: ArrayLike, n_params: int, *,
                    alpha: float = DEFAULT_ALPHA) -> GoodnessOfFit:
    """χ² test of normalised residuals r = (y − F)/σ of a fit with ``n_params`` parameters
    (module docstring).

    Parameters
    ----------
    residuals : array_like, shape (n,)
    n_params : int
        k, the number of fitted parameters.
    alpha : float
        Rejection threshold of the p-value.
    """
    if not 0.0 < alpha < 0.5:
        raise ValueError("alpha must lie in (0, 0.5)")
    r = np.asarray(residuals, dtype=float).reshape(-1)
    dof = int(r.size - n_params)
    chi2 = float(r @ r)
    ok = dof > 0 and np.isfinite(chi2)
    # imported here, not at the top: scipy.stats costs about 1 s of CPU to import, which
    # a process that imports the BRDF package without testing a fit should not pay
    from scipy.stats import chi2 as chi2_dist

    p = float(chi2_dist.sf(chi2, dof)) if ok else float("nan")
    order = np.argsort(-np.abs(np.nan_to_num(r, nan=np.inf)), kind="stable")
    big = [int(i) for i in order if abs(r[i]) > OUTLIER_Z or not np.isfinite(r[i])]
    if not big and (not np.isfinite(p) or p < alpha):
        big = [int(i) for i in order[:5]]
    return GoodnessOfFit(chi2, dof, p, float(alpha), tuple(big),
                         tuple(float(r[i]) for i in big))


@dataclass(frozen=True)
class OffsetPattern:
    """How much of a fit's misfit a constant offset of the detector reading explains
    (:func:`offset_pattern`).

    ``amplitude`` is the offset in the template's units, ``z`` its significance (σ),
    ``chi2_drop`` the χ² it removes (z²) and ``fraction`` that drop as a fraction of the
    excess χ² − ν (0 when there is no excess).
    """

    amplitude: float
    z: float
    chi2_drop: float
    fraction: float

    def looks_like_offset(self, *, min_z: float = 5.0, min_fraction: float = 0.5) -> bool:
        """Significant, and the larger part of the excess χ²."""
        return bool(abs(self.z) >= min_z and self.fraction >= min_fraction)


def offset_pattern(residuals: ArrayLike, sigma: ArrayLike, template: ArrayLike, *,
                   jacobian: ArrayLike | None = None, dof: int | None = None
                   ) -> OffsetPattern:
    """Project a fit's normalised residuals r = (y − F)/σ on an offset's signature.

    ``template`` (shape (n,)) is what a unit offset of the detector reading adds to each
    data value (for an absolute BRDF from a power reading, 1/(P_i Ω cos θr) up to a
    constant: ∝ 1/cos θr). The part of it the model's parameters can absorb (the columns
    of ``jacobian``, shape (n, k), unnormalised) is removed first, so that only what the
    model cannot mimic is counted: the least-squares amplitude of the normalised
    template t̃ = t/σ (made orthogonal to J/σ) in r is a = t̃·r / t̃·t̃, its χ² drop
    (t̃·r)²/t̃·t̃ (the linear F-test's numerator; Bevington & Robinson, *Data Reduction and
    Error Analysis*, 3rd ed., §11.4).
    """
    r = np.asarray(residuals, dtype=float).reshape(-1)
    s = np.asarray(sigma, dtype=float).reshape(-1)
    t = np.asarray(template, dtype=float).reshape(-1) / s
    if jacobian is not None:
        j = np.asarray(jacobian, dtype=float).reshape(r.size, -1) / s[:, None]
        j = j[:, np.all(np.isfinite(j), axis=0)]
        if j.size:
            coef, *_ = np.linalg.lstsq(j, t, rcond=None)
            t = t - j @ coef
    tt = float(t @ t)
    if not (np.isfinite(tt) and tt > 1e-300 * max(1.0, float(np.sum(r**2)))):
        return OffsetPattern(0.0, 0.0, 0.0, 0.0)
    a = float(t @ r) / tt
    drop = float(t @ r) ** 2 / tt
    nu = r.size if dof is None else dof
    excess = float(np.sum(r**2)) - nu
    return OffsetPattern(a, float(np.sign(a) * np.sqrt(drop)), drop,
                         float(min(drop / excess, 1.0)) if excess > 0 else 0.0)
