"""Point order: minimise total motion time instead of running a naive raster.

Cost of a step = the slowest axis's trapezoidal move (axes start together,
:mod:`instrument.bench.dynamics`). Candidates: the generated (raster) order, a serpentine of it
(alternate the fastest-varying axis's direction per row), and greedy nearest neighbour
from the start; the best is then improved by 2-opt segment reversals until no reversal
helps or ``max_passes`` passes ran. Deterministic: the same points always give the
same order (resume relies on the stored order anyway).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from instrument.bench.dynamics import AxisDynamics, move_times, route_time

__all__ = ["NO_ROUTE_S", "MoveCosts", "optimise_order", "path_cost", "serpentine"]

#: The price (s) of a move the arms cannot make (no collision-free route) in a cost matrix.
NO_ROUTE_S = 1e7


def _cost_from(t: np.ndarray, i_row: np.ndarray, axes: Sequence[str],
               dyn: Mapping[str, AxisDynamics]) -> np.ndarray:
    """Step times from one position (shape (A,)) to every row of t (shape (N, A))."""
    out = np.zeros(len(t))
    for k, r in enumerate(axes):
        np.maximum(out, move_times(t[:, k] - i_row[k], dyn[r]), out=out)
    return out


def serpentine(targets: np.ndarray) -> np.ndarray:
    """Permutation reversing every other run of equal first-axis values."""
    n = len(targets)
    if n == 0:
        return np.zeros(0, int)
    order: list[int] = []
    run: list[int] = [0]
    flip = False
    for i in range(1, n + 1):
        if i < n and np.array_equal(targets[i, :-1], targets[run[0], :-1]):
            run.append(i)
            continue
        order.extend(reversed(run) if flip else run)
        flip = not flip
        if i < n:
            run = [i]
    return np.array(order)


def _nearest(t: np.ndarray, axes: Sequence[str], dyn: Mapping[str, AxisDynamics],
             start: np.ndarray | None) -> np.ndarray:
    n = len(t)
    left = np.ones(n, bool)
    cur = t[0] if start is None else start
    order = []
    for _ in range(n):
        c = _cost_from(t, cur, axes, dyn)
        c[~left] = np.inf
        j = int(np.argmin(c))
        order.append(j)
        left[j] = False
        cur = t[j]
    return np.array(order)


def _two_opt(t: np.ndarray, order: np.ndarray, axes: Sequence[str],
             dyn: Mapping[str, AxisDynamics], start: np.ndarray | None,
             max_passes: int) -> np.ndarray:
    path = np.vstack([t[:1] if start is None else start[None, :], t[order]])
    idx = np.concatenate([[-1], order])
    n = len(path)
    for _ in range(max_passes):
        improved = False
        for i in range(1, n - 1):
            a, b = path[i - 1], path[i]
            d_ab = _cost_from(b[None, :], a, axes, dyn)[0]
            js = np.arange(i + 1, n)
            c_ = path[js]
            d_ac = _cost_from(c_, a, axes, dyn)
            d_cd_old = np.zeros(len(js))
            d_bd_new = np.zeros(len(js))
            has_next = js + 1 < n
            nxt = path[js[has_next] + 1]
            # old edge c→d and new edge b→d (no d after the last point: open path)
            d_cd_old[has_next] = np.max(
                [move_times(nxt[:, k] - c_[has_next, k], dyn[r]) for k, r in enumerate(axes)],
                axis=0) if has_next.any() else 0.0
            d_bd_new[has_next] = _cost_from(nxt, b, axes, dyn)
            delta = d_ac + d_bd_new - d_ab - d_cd_old
            j_best = int(np.argmin(delta))
            if delta[j_best] < -1e-9:
                j = js[j_best]
                path[i:j + 1] = path[i:j + 1][::-1].copy()
                idx[i:j + 1] = idx[i:j + 1][::-1].copy()
                improved = True
        if not improved:
            break
    return idx[1:]


def path_cost(costs: np.ndarray, order: np.ndarray) -> float:
    """Seconds of visiting the points in ``order`` with the move costs ``costs`` (shape
    (N + 1, N + 1), row N the start: ``instrument.plans.route_costs.move_cost_matrix``)."""
    n = len(costs) - 1
    return float(costs[n, order[0]] + costs[order[:-1], order[1:]].sum())


def _nearest_by_cost(costs: np.ndarray) -> np.ndarray:
    n = len(costs) - 1
    left = np.ones(n, bool)
    cur, order = n, []
    for _ in range(n):
        c = np.where(left, costs[cur, :n], np.inf)
        j = int(np.argmin(c))
        order.append(j)
        left[j] = False
        cur = j
    return np.array(order)


def _two_opt_by_cost(costs: np.ndarray, order: np.ndarray, max_passes: int) -> np.ndarray:
    """2-opt on a cost matrix that need not be symmetric: a reversed segment is priced by
    its backward moves (prefix sums), so each reversal's gain is exact."""
    n = len(costs) - 1
    path = np.concatenate([[n], order])
    m = len(path)
    for _ in range(max_passes):
        improved = False
        for i in range(1, m - 1):
            fwd = costs[path[:-1], path[1:]]   # fwd[k]: path[k] → path[k+1]
            bwd = costs[path[1:], path[:-1]]   # bwd[k]: path[k+1] → path[k]
            cf = np.concatenate([[0.0], np.cumsum(fwd)])
            cb = np.concatenate([[0.0], np.cumsum(bwd)])
            a, b = path[i - 1], path[i]
            js = np.arange(i + 1, m)
            inner_old = cf[js] - cf[i]
            inner_new = cb[js] - cb[i]
            nxt = np.where(js + 1 < m, path[np.minimum(js + 1, m - 1)], n)
            out_old = np.where(js + 1 < m, costs[path[js], nxt], 0.0)
            out_new = np.where(js + 1 < m, costs[b, nxt], 0.0)
            delta = (costs[a, path[js]] + inner_new + out_new
                     - costs[a, b] - inner_old - out_old)
            k = int(np.argmin(delta))
            if delta[k] < -1e-9:
                j = js[k]
                path[i:j + 1] = path[i:j + 1][::-1].copy()
                improved = True
        if not improved:
            break
    return path[1:]


class MoveCosts(Protocol):
    """Move costs as the engine runs the moves (``RouteCosts`` of
    ``instrument.plans.route_costs``): a matrix, row N the start, whose entries may be
    provisional until :meth:`price` has priced the moves of an order exactly."""

    matrix: np.ndarray

    def price(self, order: np.ndarray) -> bool: ...


#: Rounds of optimising on the costs and pricing the moves the order uses.
MAX_ROUNDS = 8


def optimise_order(targets: np.ndarray, axes: Sequence[str],
                   dynamics: Mapping[str, AxisDynamics], *, start: np.ndarray | None = None,
                   max_passes: int = 20, two_opt_limit: int = 3000,
                   costs: MoveCosts | None = None) -> np.ndarray:
    """A permutation of the rows of ``targets`` (shape (N, A)) with short motion time.

    With ``costs`` the order found with the concurrent cost is improved on those costs:
    nearest neighbour and 2-opt again, the cheapest of all candidates wins; the moves it
    uses are priced exactly (:meth:`MoveCosts.price`) and the search repeats until their
    prices hold (at most :data:`MAX_ROUNDS` rounds). The cheapest exactly priced order
    is returned."""
    t = np.asarray(targets, dtype=float)
    n = len(t)
    if n < 3:
        return np.arange(n)
    best = _optimise_concurrent(t, axes, dynamics, start, max_passes, two_opt_limit)
    if costs is None:
        return best
    found: list[tuple[float, np.ndarray]] = []
    for _ in range(MAX_ROUNDS):
        # a move with no route: dearer than any order of routes (finite: sums stay exact)
        c = np.where(np.isfinite(costs.matrix), costs.matrix, NO_ROUTE_S)
        candidates = [np.arange(n), serpentine(t), best, _nearest_by_cost(c)]
        start_order = min(candidates, key=lambda o: path_cost(c, o))
        order = _two_opt_by_cost(c, start_order, max_passes)
        if path_cost(c, order) >= path_cost(c, start_order):
            order = start_order
        changed = costs.price(order)
        found.append((path_cost(np.where(np.isfinite(costs.matrix), costs.matrix,
                                         NO_ROUTE_S), order), order))
        if not changed:
            break
    return min(found, key=lambda f: f[0])[1]


def _optimise_concurrent(t: np.ndarray, axes: Sequence[str],
                         dynamics: Mapping[str, AxisDynamics], start: np.ndarray | None,
                         max_passes: int, two_opt_limit: int) -> np.ndarray:
    n = len(t)
    st = None if start is None else np.asarray(start, float)
    candidates = [np.arange(n), serpentine(t)]
    if n <= 20000:
        candidates.append(_nearest(t, axes, dynamics, st))
    times = [route_time(t[c], axes, dynamics, start=st)[0] for c in candidates]
    best = candidates[int(np.argmin(times))]
    if n <= two_opt_limit:
        improved = _two_opt(t, best, axes, dynamics, st, max_passes)
        if route_time(t[improved], axes, dynamics, start=st)[0] < min(times):
            best = improved
    return best
