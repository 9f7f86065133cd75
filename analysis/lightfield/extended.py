"""One extended object or two point objects: a model comparison on the reconstructed rays.

Two nearby components of a localisation are either two point sources or one object larger
than the blur, which the point model samples with two components (a uniform bar of width
W fits as two points W/√3 apart).  Their spacing cannot decide it: a 15 mm bar on the
emulated bench fits as two points 1.10 δy apart, two 3 mm discs 1.13 δy apart as two
points 1.13 δy apart (ADR 0032).  The data can, because the two hypotheses predict
different rays beyond their second moment:

* H₂, two points: ``a₁ K(θ − θ*(c; P₁)) + a₂ K(θ − θ*(c; P₂))`` (six parameters, the
  model the localiser fits, :func:`.ray_fit.fit_points`);
* H₁, one uniform segment from E₁ to E₂ (a bar; across, in depth or oblique):
  ``a ∫₀¹ K(θ − θ*(c; E₁ + t (E₂ − E₁))) dt`` (five parameters; the integral by the
  midpoint rule on :data:`SEGMENT_NODES` nodes, its error ≤ (L/δy)²/(24 n²) of the
  response for a segment L long, < 10⁻³ up to 3 δy).

Both are fitted by least squares to the same rays ``g = L cos θ`` of the solvable domain
(with every other object's fitted response removed), and the statistic is the residual
difference in noise variances, ``Δ = (RSS₁ − RSS₂)/σ²``.  ``σ²`` is the variance per
independent sample, ``RSS/(n_eff − k)`` of the full fit as in the localiser's other model
choice (``n_eff = R (2 p̂ + 1)(B − A)/(b − a)``: the reconstructed rays are band-limited
to ``2 p̂ + 1`` orders per wall point); with a residual dominated by the point model's
mismatch (discs are not points) it is that mismatch, so both hypotheses are judged
against it and not against the bare noise.  The decision is the Bayesian information
criterion (Schwarz 1978, *Ann. Stat.* 6, 461, eq. 2; the Gaussian-likelihood form
``RSS/σ² + k ln n``): two points when ``Δ > ln n_eff`` (the one parameter H₂ has more),
otherwise one extended object with the segment's length as its size.  Under H₂ with
noise only, ``Δ`` grows as the squared difference of the two models' rays, i.e. with the
signal-to-noise ratio squared; under H₁, ``Δ ≤ 0`` up to noise (the segment is the truth,
two points only approximate it) — so the decision improves with the data, unlike any
fixed spacing.  Measured on the two cases above in ``tests/analysis/lightfield/
test_extended.py`` and ADR 0032.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .field import LightField2D
from .ray_fit import fit_points as _fit_points
from .ray_fit import ray_model as _ray_model

__all__ = ["SEGMENT_NODES", "OneOrTwo", "extended_groups", "one_or_two"]

#: Midpoint-rule nodes along a segment (module doc: error < 10⁻³ of the response up to
#: 3 δy long).
SEGMENT_NODES = 24


@dataclass(frozen=True)
class OneOrTwo:
    """The comparison of one extended object with two points (module doc).

    Attributes
    ----------
    statistic : Δ = (RSS_segment − RSS_two)/σ², in noise variances per independent sample
    penalty : ln n_eff — the BIC's price of H₂'s extra parameter
    extended : bool — one extended object (Δ ≤ penalty)
    ends_mm : (2, 2) — the fitted segment's ends, rows (y, z)
    amplitude : float — the segment's fitted amplitude (the sum of its points')
    rss_two, rss_segment : float — residual sums of squares of the two fits
    points_mm : (2, 2) — the two fitted points, rows (y, z) (the better of the fits started
        from the components and, with ``across_mm``, side by side)
    """

    statistic: float
    penalty: float
    extended: bool
    ends_mm: NDArray[np.float64]
    amplitude: float
    rss_two: float
    rss_segment: float
    points_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros((2, 2)))

    @property
    def size_mm(self) -> tuple[float, float]:
        """The segment's extent (across, in depth), mm."""
        d = np.abs(self.ends_mm[1] - self.ends_mm[0])
        return float(d[0]), float(d[1])


def _segment_model(
    lf_wall: LightField2D, use: NDArray[np.bool_], phi: NDArray[Any], ends: NDArray[Any]
) -> tuple[NDArray[Any], NDArray[Any]]:
    """Unit-amplitude response of a uniform segment (R, n_use) and its derivatives in the
    four end coordinates (4, R, n_use) — (y₁, z₁, y₂, z₂) — by the chain rule through
    the nodes ``E₁ + t (E₂ − E₁)``."""
    t = (np.arange(SEGMENT_NODES) + 0.5) / SEGMENT_NODES
    nodes = ends[0][None, :] + t[:, None] * (ends[1] - ends[0])[None, :]
    r, dy, dz = _ray_model(lf_wall, use, phi, nodes)
    w1 = (1.0 - t)[:, None, None] / SEGMENT_NODES
    w2 = t[:, None, None] / SEGMENT_NODES
    d = np.stack([(w1 * dy).sum(0), (w1 * dz).sum(0), (w2 * dy).sum(0), (w2 * dz).sum(0)])
    return r.mean(axis=0), d


def _fit_segment(
    g: NDArray[Any], lf_wall: LightField2D, use: NDArray[np.bool_], phi: NDArray[Any],
    ends: NDArray[Any],
    bounds: tuple[tuple[float, float], tuple[float, float]],
) -> tuple[NDArray[Any], float, float]:
    """Least squares of one uniform segment (amplitude and ends) to the rays ``g``
    (R, n_use), started at ``ends`` (2, 2): (ends, amplitude, RSS)."""
    from scipy.optimize import least_squares

    flat = g.ravel()
    (ylo, yhi), (zlo, zhi) = bounds
    start = np.column_stack([np.clip(ends[:, 0], ylo, yhi), np.clip(ends[:, 1], zlo, zhi)])
    r0, _ = _segment_model(lf_wall, use, phi, start)
    x0r = r0.ravel()
    amp0 = float(x0r @ flat / max(float(x0r @ x0r), 1e-300))

    def resid(x: NDArray[Any]) -> NDArray[Any]:
        r, _ = _segment_model(lf_wall, use, phi, x[1:].reshape(2, 2))
        return x[0] * r.ravel() - flat

    def jac(x: NDArray[Any]) -> NDArray[Any]:
        r, d = _segment_model(lf_wall, use, phi, x[1:].reshape(2, 2))
        return np.column_stack([r.ravel(), (x[0] * d).reshape(4, -1).T])

    x0 = np.concatenate([[amp0], start.ravel()])
    lo = np.array([-np.inf, ylo, zlo, ylo, zlo])
    hi = np.array([np.inf, yhi, zhi, yhi, zhi])
    scale = np.array([max(abs(amp0), 1e-12), 1.0, 10.0, 1.0, 10.0])
    # the trust-region steps solved exactly (SVD of the small Jacobian) and the fit run to
    # tight tolerances: with lsmr's iterative steps stopped at ftol 1e-6 the stopping point
    # followed the rounding, and the brushed metal's pair came out one extended object with
    # one BLAS thread and a phantom beside it with two (ADR 0109)
    sol = least_squares(resid, x0, jac=jac, bounds=(lo, hi), x_scale=scale, max_nfev=40,
                        ftol=1e-10, xtol=1e-10, tr_solver="exact")
    return sol.x[1:].reshape(2, 2), float(sol.x[0]), float(np.sum(sol.fun**2))


def one_or_two(
    g: NDArray[Any], lf_wall: LightField2D, use: NDArray[np.bool_], phi: NDArray[Any],
    pair_mm: NDArray[Any], *, sigma2: float, n_eff: float,
    bounds: tuple[tuple[float, float], tuple[float, float]], across_mm: float = 0.0,
) -> OneOrTwo:
    """Decide whether two components at ``pair_mm`` (2, 2) — rows (y, z) — are one extended
    object or two points (module doc).

    ``g`` (R, n_use) are the rays of the solvable domain with every other object's fitted
    response removed; ``use`` (N,) marks those rays on the angle grid, ``phi`` (N,) the
    filter factors; ``sigma2`` the noise variance per independent sample and ``n_eff`` the
    number of independent samples; ``bounds`` the searched (y, z) box.

    Both least-squares fits are local.  With ``across_mm`` (the transverse blur there) each
    is also started across the line of sight, centred on the pair, ``across_mm`` wide (or
    as wide as the pair, if wider), and the better start is kept: on a near-mirror wall a
    3 mm disc, wider than the 2.6 mm blur, and two discs side by side two blurs apart came
    out of the search as two points on one line of sight, a few depth cells apart, and a
    segment started along that line (in depth) cannot reach the disc across.
    """
    if not (sigma2 > 0 and np.isfinite(sigma2)):
        raise ValueError(f"sigma2 {sigma2!r} must be a positive noise variance")
    pair = np.asarray(pair_mm, dtype=float)
    two = _fit_points(g, lf_wall, use, phi, pair, bounds)
    centre = two.positions.mean(axis=0)
    # a uniform segment's two-point fit sits at ±L/(2√3) from its centre
    half = 0.5 * np.sqrt(3.0) * (two.positions[1] - two.positions[0])
    ends, amp, rss_seg = _fit_segment(g, lf_wall, use, phi,
                                      np.vstack([centre - half, centre + half]), bounds)
    if across_mm > 0:
        mid = pair.mean(axis=0)
        width = max(float(across_mm), abs(float(pair[1, 0] - pair[0, 0])))
        span = np.array([0.5 * width, 0.0])
        across = np.vstack([mid - span, mid + span])
        side = _fit_points(g, lf_wall, use, phi, across, bounds)
        if side.rss < two.rss:
            two = side
        seg = _fit_segment(g, lf_wall, use, phi, across, bounds)
        if seg[2] < rss_seg:
            ends, amp, rss_seg = seg
    stat = (rss_seg - two.rss) / sigma2
    penalty = float(np.log(max(n_eff, 2.0)))
    return OneOrTwo(float(stat), penalty, bool(stat <= penalty), ends, amp, two.rss, rss_seg,
                    two.positions.copy())


def extended_groups(
    g: NDArray[Any], lf_wall: LightField2D, use: NDArray[np.bool_], phi: NDArray[Any],
    positions_mm: NDArray[Any], pairs: list[tuple[int, int]], *, n_eff: float,
    bounds: tuple[tuple[float, float], tuple[float, float]],
    across_mm: list[float] | None = None,
) -> tuple[list[list[int]], dict[tuple[int, int], OneOrTwo]]:
    """Group the components at ``positions_mm`` (K, 2) into objects: each candidate pair
    in ``pairs`` (indices, near enough for their responses to overlap) is tested by
    :func:`one_or_two` with the other components' jointly fitted responses removed from
    the rays ``g`` (R, n_use); pairs judged one extended object are joined (transitively).
    ``across_mm`` (one per pair) are the transverse blurs passed to :func:`one_or_two`.

    Returns the groups (lists of component indices, in order of their first member) and
    the test of each pair.
    """
    pos = np.asarray(positions_mm, dtype=float).reshape(-1, 2)
    k = pos.shape[0]
    parent = list(range(k))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    tests: dict[tuple[int, int], OneOrTwo] = {}
    if pairs:
        r, _, _ = _ray_model(lf_wall, use, phi, pos)
        x = r.reshape(k, -1)
        amp = np.linalg.lstsq(x.T, g.ravel(), rcond=None)[0]
        resid = g - np.tensordot(amp, r, axes=1)
        rss = float(np.sum(resid**2))
        # noise per independent sample from the joint fit (three parameters a point); a
        # noise-free field still needs a scale: a 10⁻²⁰ share of the signal power
        floor = 1e-20 * float(np.sum(g**2)) / max(n_eff, 1.0)
        sigma2 = max(rss / max(n_eff - 3.0 * k, 1.0), floor, np.finfo(float).tiny)
        widths = across_mm if across_mm is not None else [0.0] * len(pairs)
        for (i, j), width in zip(pairs, widths, strict=True):
            mine = resid + amp[i] * r[i] + amp[j] * r[j]
            t = one_or_two(mine, lf_wall, use, phi, pos[[i, j]], sigma2=sigma2,
                           n_eff=n_eff, bounds=bounds, across_mm=width)
            tests[(i, j)] = t
            if t.extended:
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(k):
        groups.setdefault(root(i), []).append(i)
    return sorted(groups.values(), key=lambda gr: gr[0]), tests
