"""Move costs on a type (i) bench that price the arms' routes (ADR 0099).

The engine moves both arms at once where their timed path keeps the heads apart and
otherwise runs the legs of :func:`instrument.bench.arms.safe_route` one after the other.
The travel-optimised order (:mod:`instrument.plans.order`) therefore costs a move as the
engine will run it: the concurrent move of every axis (the slowest axis), plus, for a
move the arms cannot make together, what the route's legs take beyond the one concurrent
arm move (the same account as :meth:`instrument.plans.build.Plan.estimate`).

Which moves the arms can make together is decided for every ordered pair of points: most
are proven clear by :func:`instrument.bench.arms.path_bounds` (vectorised), the rest
have their timed path sampled (:func:`instrument.bench.arms.path_clear`). Searching a route
is the dear part (tens of sampled legs), so it is done lazily: a move that needs one is
first priced as its arms one after the other (the cheapest split), and
:meth:`RouteCosts.price` replaces that by the searched route's time for the moves an order
actually uses; the order is then optimised again (``optimise_order`` of
``instrument.plans.order``) until the moves it uses are all priced exactly. The matrix holds every
ordered pair, so it is built for at most :data:`MAX_POINTS` points; a larger plan is
ordered with the concurrent cost, as before, and its moves are routed as they come.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence

import numpy as np

from instrument.bench.arms import BOUND_SEGMENTS, path_bounds, path_clear, safe_route
from instrument.bench.dynamics import AxisDynamics, move_times, step_time
from instrument.bench.kinematics import TYPE_I_AXES
from instrument.bench.profile import BenchProfile

__all__ = ["MAX_POINTS", "RouteCosts"]

#: Largest plan (points that move) whose order prices routes: the matrix holds every
#: ordered pair, and the pairs the bound cannot clear cost a sampled path each.
MAX_POINTS = 400


class RouteCosts:
    """Seconds of the move from each point to each other, as the engine runs it.

    ``matrix`` has shape (N + 1, N + 1) for ``targets`` of shape (N, A) (columns
    ``axes``): ``matrix[i, j]`` the move from row i to row j, ``matrix[N, j]`` from
    ``start`` (0 without one), ``matrix[:, N]`` unused (0). A move with no collision-free
    route costs ``inf``. Entries of moves that need a route are provisional until
    :meth:`price` has searched it (``exact``).
    """

    def __init__(self, profile: BenchProfile, targets: np.ndarray, axes: Sequence[str],
                 dynamics: Mapping[str, AxisDynamics], *,
                 start: np.ndarray | None = None) -> None:
        t = np.asarray(targets, float)
        n = len(t)
        self._profile, self._dyn, self._n = profile, dynamics, n
        rows = t if start is None else np.vstack([t, np.asarray(start, float)[None, :]])
        m = len(rows)
        cost = np.zeros((n + 1, n + 1))
        for k, r in enumerate(axes):  # every axis started together: the slowest one
            np.maximum(cost[:m, :n], move_times(rows[:, None, k] - t[None, :, k],
                                                dynamics[r]), out=cost[:m, :n])
        col = [list(axes).index(r) for r in TYPE_I_AXES]
        self._arms = rows[:, col]
        self.exact = np.ones((n + 1, n + 1), bool)
        i, j = np.nonzero(~np.eye(m, n, dtype=bool))
        clear, blocked = path_bounds(profile.geometry, self._arms[i], self._arms[j], dynamics,
                                     segments=BOUND_SEGMENTS)
        for a, b, sure in zip(i[~clear], j[~clear], blocked[~clear], strict=True):
            if sure or not path_clear(profile.geometry, dynamics, self._pose(a),
                                      self._pose(b)).clear:
                # provisional: one arm, then the other
                cost[a, b] += self._provisional(self._pose(a), self._pose(b))
                self.exact[a, b] = False
        if start is None:
            cost[n, :] = 0.0
            self.exact[n, :] = True
        cost[:, n] = 0.0
        self.matrix = cost

    @classmethod
    def of(cls, profile: BenchProfile, targets: np.ndarray, axes: Sequence[str],
           dynamics: Mapping[str, AxisDynamics], *, start: np.ndarray | None = None
           ) -> RouteCosts | None:
        """The costs, or None when the bench is not type (i), the plan does not move
        every arm axis, or it has more than :data:`MAX_POINTS` points."""
        if (not profile.geometry.is_type_i or len(targets) > MAX_POINTS
                or not all(r in axes for r in TYPE_I_AXES)):
            return None
        return cls(profile, targets, axes, dynamics, start=start)

    def _pose(self, row: int) -> dict[str, float]:
        return dict(zip(TYPE_I_AXES, (float(v) for v in self._arms[row]), strict=True))

    def price(self, order: np.ndarray) -> bool:
        """Search the routes of the moves of ``order`` (from the start) still priced
        provisionally; return whether any price changed."""
        path = np.concatenate([[self._n], np.asarray(order, int)])
        limits = {r: d.limits for r, d in self._profile.axes.items()}
        changed = False
        for a, b in itertools.pairwise(path):
            if self.exact[a, b]:
                continue
            here, there = self._pose(a), self._pose(b)
            route = safe_route(self._profile.geometry, self._dyn, here, there, limits=limits)
            base = self.matrix[a, b] - self._provisional(here, there)
            new = (np.inf if route is None else
                   base + route.seconds(here, self._dyn) - step_time(here, there, self._dyn))
            changed |= bool(new != self.matrix[a, b])
            self.matrix[a, b] = new
            self.exact[a, b] = True
        return changed

    def _provisional(self, here: dict[str, float], there: dict[str, float]) -> float:
        """What the arms one after the other add to their concurrent move."""
        arm_s = step_time(here, {r: there[r] for r in TYPE_I_AXES[:2]}, self._dyn)
        arm_d = step_time(here, {r: there[r] for r in TYPE_I_AXES[2:]}, self._dyn)
        return min(arm_s, arm_d)
