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
at every n_theta alike.  The localisation's point-response stacks (one per candidate
examined, 37 on the near-mirror disc) share the data's geometry: :class:`SamplePlan` lays
the samples' interpolation out once as sparse matrices, and each model is then one sparse
product per depth (BENCHMARKS.md, "locate at n_theta 1024" and "locate at n_theta 1024 in
about a minute").
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
    runs = _runs(n_rows, lo, dy, y, z, t, hi)
    if runs is None:
        return (np.zeros((sample_weights.shape[0], n_y)),
                np.zeros((hit_weights.shape[0], n_y)))
    ii, q, run, inside, i0, w = runs
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


def _runs(
    n_rows: int, lo: float, dy: float, y: NDArray[Any], z: float, t: NDArray[Any], hi: float,
) -> tuple[NDArray[Any], ...] | None:
    """The samples of one depth on the rays' runs of trial points (module doc).

    Returns ``ii`` (C, W): the trial point of each sample (the runs padded to one width W,
    the padding clipped to the last point), ``q`` (C, W) its wall coordinate, ``run`` (C, W)
    whether it belongs to its run, ``inside`` whether it is interpolated (on the wall and on
    the run), ``i0`` (C, W) the wall row below it and ``w`` (C, W) the weight of the row
    above — the arithmetic of :func:`.propagate.sample_columns`; None when no ray meets
    the wall.
    """
    n_y = y.size
    shift = z * t
    start = np.searchsorted(y, lo + shift - _MARGIN_ROWS * dy, side="left")
    stop = np.searchsorted(y, hi + shift + _MARGIN_ROWS * dy, side="right")
    width = int((stop - start).max()) if t.size else 0
    if width <= 0:
        return None
    ii = start[:, None] + np.arange(width)[None, :]
    run = ii < stop[:, None]
    ii = np.minimum(ii, n_y - 1)
    # the same arithmetic as sample_columns on q = y[:, None] − z·t[None, :]
    q = y[ii] - shift[:, None]
    idx = (q - lo) / dy
    inside = (idx >= -1e-9) & (idx <= n_rows - 1 + 1e-9) & run
    i0 = np.clip(np.floor(idx).astype(np.int64), 0, n_rows - 2)
    w = np.clip(idx - i0, 0.0, 1.0)
    return ii, q, run, inside, i0, w


def _weighted_counts(at: NDArray[Any], values: NDArray[Any], weights: NDArray[Any],
                     n_y: int) -> NDArray[Any]:
    """``Σ_j values_jk weights_j`` scattered onto the trial points ``at_jk``, over the
    columns of nonzero weight only (a weight vector is often an indicator of half the
    rays)."""
    cols = np.flatnonzero(weights)
    return np.bincount(at[cols].ravel(), weights=(values[cols] * weights[cols, None]).ravel(),
                       minlength=n_y)


class SamplePlan:
    """Every depth's samples as sparse matrices, for many fields on the same geometry.

    The samples of :func:`ray_sums` depend on the field only through the two wall rows
    each interpolates, with weights fixed by the geometry (the wall rows, the ray slopes,
    the trial grid and depth).  The localisation's point-response models (one per
    candidate) are all taken on the data's geometry, so the interpolation is laid out once,
    per depth, as a CSR matrix (N_y, R·C) whose rows are the trial points and whose
    entries are the two weights ``1 − w`` and ``w`` of each sample that meets the wall;
    a field's sum over rays is then one sparse product with its column-major samples.
    Same samples, same weights: the sums agree with :func:`ray_sums` to rounding (only the
    order of the additions differs).  The columns are split in two groups (the first
    ``n_first`` and the rest), summed separately.

    Memory: 12 bytes per weight, two weights per sample that meets the wall (at n_theta
    1024 on the default search of the example scan 1.5 GB; BENCHMARKS.md, "locate at
    n_theta 1024 in about a minute").  :meth:`build` gives up (None) beyond a budget.
    """

    def __init__(self, parts: list[tuple[Any, Any]]) -> None:
        self._parts = parts

    @classmethod
    def build(cls, n_rows: int, n_first: int, lo: float, dy: float, y: NDArray[Any],
              zs: NDArray[Any], t: NDArray[Any], hi: float,
              max_bytes: float = np.inf) -> SamplePlan | None:
        """The plan of the wall rows ``lo + r·dy`` (r < R = ``n_rows``, ``hi`` the last),
        the ray slopes ``t`` (C,) (the first ``n_first`` one group), the trial points ``y``
        (increasing) and depths ``zs``; None once its matrices would pass ``max_bytes``
        (checked depth by depth, before each depth's matrices are made)."""
        from scipy.sparse import csr_matrix

        n_cols, n_y = t.size, y.size
        groups = ((0, n_first), (n_first, n_cols))
        held = 0
        per_depth: list[tuple[Any, Any]] = []
        for z in zs:
            runs = _runs(n_rows, lo, dy, y, float(z), t, hi)
            pair = []
            for j0, j1 in groups:
                shape = (n_y, n_rows * (j1 - j0))
                if runs is None or j1 == j0:
                    pair.append(csr_matrix(shape))
                    continue
                ii, _, _, inside, i0, w = (v[j0:j1] for v in runs)
                # two weights of 8 bytes and two column indices of 4 per sample
                held += 24 * int(np.count_nonzero(inside))
                if held > max_bytes:
                    return None
                col = i0 + (np.arange(j1 - j0) * n_rows)[:, None]
                pair.append(_by_rows(ii[inside], col[inside], w[inside], shape))
            per_depth.append((pair[0], pair[1]))
        return cls(per_depth)

    @property
    def nbytes(self) -> int:
        """Memory held by the matrices."""
        return sum(m.data.nbytes + m.indices.nbytes + m.indptr.nbytes
                   for pair in self._parts for m in pair)

    def sums(self, first: NDArray[Any], rest: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
        """``Σ_j s_ij`` over the first group's columns ``first`` (R, n_first) and over the
        rest's ``rest`` (R, C − n_first) at every depth: two (N_z, N_y) arrays (weights
        per column are folded into the columns by the caller)."""
        x0, x1 = (np.ascontiguousarray(np.asarray(c, dtype=float).T).ravel()
                  for c in (first, rest))
        out0 = np.stack([m0 @ x0 for m0, _ in self._parts])
        out1 = np.stack([m1 @ x1 for _, m1 in self._parts])
        return out0, out1


def _by_rows(rows: NDArray[Any], col: NDArray[Any], w: NDArray[Any],
             shape: tuple[int, int]) -> Any:
    """The CSR matrix of the samples at trial points ``rows`` interpolating wall rows
    ``col`` and ``col + 1`` with weights ``1 − w`` and ``w``.  The entries are grouped by
    trial point with a stable counting sort (the trial index fits 16 bits, where numpy's
    stable sort is a radix sort) rather than through scipy's COO conversion, which also
    sorts the column indices of every row — not needed for products, and most of the
    plan's cost."""
    from scipy.sparse import csr_matrix

    order = np.argsort(rows.astype(np.uint16 if shape[0] < 2**16 else np.int64),
                       kind="stable")
    r0 = col[order].astype(np.int32 if shape[1] < 2**31 - 1 else np.int64)
    indices = np.stack([r0, r0 + 1], axis=1).ravel()
    ws = w[order]
    data = np.stack([1.0 - ws, ws], axis=1).ravel()
    indptr = np.zeros(shape[0] + 1, dtype=r0.dtype)
    np.cumsum(2 * np.bincount(rows, minlength=shape[0]), out=indptr[1:])
    return csr_matrix((data, indices, indptr), shape=shape)
