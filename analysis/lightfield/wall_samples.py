"""The focal stacks' sums over rays, evaluated only where a ray meets the measured wall.

A trial point (y, z) collects ray j from the wall point ``q = y − z tan θ_j``
(:mod:`.localize`, module doc); a ray that misses the wall (q outside the wall points)
contributes exactly 0 to every stack.  With the default search (the wall points ± 60 mm
across) most of the (y, j) pairs of a depth miss: for the 60 mm wall of the example scan
two thirds of them.  For one depth and one ray direction the trial points whose ray meets
the wall are a contiguous run of the (increasing) y grid, found by bisection, so the sums
are made over those runs alone and scattered back onto the grid (``numpy.bincount``).

Each sample is the same linear interpolation, with the same arithmetic, as
:func:`.propagate.sample_columns` on the whole grid; only the order of the sums over rays
changes (the results agree to rounding, ~1e-15 relative: ``tests/analysis/lightfield/
test_wall_samples.py``).  The cost falls with the fraction of pairs that meet the wall,
at every n_theta alike; the localisation's point-response stacks (one per candidate) are
where ``locate`` spends its time (BENCHMARKS.md, "locate at n_theta 1024").
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Extra trial points taken at each end of a run (the bisection's bounds are widened by
#: one wall row; the exact inside test of the interpolation then decides)
_MARGIN_ROWS = 1.0


def ray_sums(
    cols: NDArray[Any], lo: float, dy: float, y: NDArray[Any], z: float, t: NDArray[Any],
    hi: float, sample_weights: NDArray[Any], hit_weights: NDArray[Any],
) -> tuple[NDArray[Any], NDArray[Any]]:
    """Weighted sums over rays at one depth: ``Σ_j s_ij u_kj`` and ``Σ_j ok_ij v_kj``.

    ``cols`` (R, C) holds the columns sampled along the wall rows ``lo + r·dy`` (r < R,
    ``hi`` the last); ``t`` (C,) the ray slopes tan θ_j; ``sample_weights`` (K, C) and
    ``hit_weights`` (L, C) the weight vectors; ``y`` (N_y,) the trial points, strictly
    increasing.  Sample ``s_ij`` is the
    column j linearly interpolated at ``q = y_i − z t_j`` (0 outside the wall) and
    ``ok_ij`` says whether q lies on the wall.  Returns the sums of the samples (K, N_y)
    and of the indicators (L, N_y; L = 0 skips them: they depend on the geometry
    alone).
    """
    n_rows, n_cols = cols.shape
    n_y = y.size
    shift = z * t
    start = np.searchsorted(y, lo + shift - _MARGIN_ROWS * dy, side="left")
    stop = np.searchsorted(y, hi + shift + _MARGIN_ROWS * dy, side="right")
    width = int((stop - start).max()) if n_cols else 0
    if width <= 0:
        return (np.zeros((sample_weights.shape[0], n_y)),
                np.zeros((hit_weights.shape[0], n_y)))
    ii = start[:, None] + np.arange(width)[None, :]
    run = ii < stop[:, None]
    ii = np.minimum(ii, n_y - 1)
    # the same arithmetic as sample_columns on q = y[:, None] − z·t[None, :]
    q = y[ii] - shift[:, None]
    idx = (q - lo) / dy
    inside = (idx >= -1e-9) & (idx <= n_rows - 1 + 1e-9) & run
    i0 = np.clip(np.floor(idx).astype(np.int64), 0, n_rows - 2)
    w = np.clip(idx - i0, 0.0, 1.0)
    flat = cols.T.ravel()  # column-major: sample (r, j) at j·R + r
    base = i0 + (np.arange(n_cols) * n_rows)[:, None]
    s = (1.0 - w) * flat[base] + w * flat[base + 1]
    s = np.where(inside, s, 0.0)
    # the runs' padding (clipped to the last trial point) carries weight 0
    sums = np.stack([_weighted_counts(ii, s, u, n_y) for u in sample_weights])
    if not hit_weights.shape[0]:
        return sums, np.zeros((0, n_y))
    ok = ((q >= lo) & (q <= hi) & run).astype(float)
    return sums, np.stack([_weighted_counts(ii, ok, v, n_y) for v in hit_weights])


def _weighted_counts(at: NDArray[Any], values: NDArray[Any], weights: NDArray[Any],
                     n_y: int) -> NDArray[Any]:
    """``Σ_j values_jk weights_j`` scattered onto the trial points ``at_jk``, over the
    columns of nonzero weight only (a weight vector is often an indicator of half the
    rays)."""
    cols = np.flatnonzero(weights)
    return np.bincount(at[cols].ravel(), weights=(values[cols] * weights[cols, None]).ravel(),
                       minlength=n_y)
