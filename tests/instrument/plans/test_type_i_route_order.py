"""The travel-optimised order on a type (i) bench prices the arms' routes (ADR 0099): a
move costs what the engine's route takes, so the order avoids detours where a cheaper
order exists; the bound that spares most paths their sampling agrees with the sampling."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from instrument.bench.arms import BOUND_SEGMENTS, path_bounds, path_clear, safe_route
from instrument.bench.dynamics import dynamics_of, move_progress, moves_progress
from instrument.bench.kinematics import TYPE_I_AXES
from instrument.bench.profile import load_profile
from instrument.plans.build import build_plan
from instrument.plans.order import _two_opt_by_cost, optimise_order, path_cost
from instrument.plans.planfile import load_plan
from instrument.plans.route_costs import RouteCosts

ROOT = Path(__file__).resolve().parents[3]
TYPE_I = load_profile("sim-type-i")
DYN = dynamics_of(TYPE_I, TYPE_I_AXES)
LIMITS = {r: d.limits for r, d in TYPE_I.axes.items()}


def _routed(points: list[dict[str, float]]) -> tuple[int, float]:
    """(split moves, seconds) of the routes the engine runs between the points."""
    split, total = 0, 0.0
    for here, there in itertools.pairwise(points):
        route = safe_route(TYPE_I.geometry, DYN, here, there, limits=LIMITS)
        assert route is not None
        split += route.split
        total += route.seconds(here, DYN)
    return split, total


def test_the_readme_plan_needs_fewer_detours_than_with_the_concurrent_cost():
    plan = build_plan(load_plan(ROOT / "examples" / "brdf_inplane.toml"), TYPE_I)
    body = [p for p in plan.points if p.targets]
    t = np.array([[p.target_dict()[r] for r in plan.axes] for p in body])
    dyn = dynamics_of(TYPE_I, plan.axes)
    # the order of the same points by the concurrent cost alone (the earlier planner)
    concurrent = optimise_order(t, plan.axes, dyn)
    before = _routed([dict(zip(plan.axes, t[j], strict=True)) for j in concurrent])
    after = _routed([p.target_dict() for p in body])
    assert after[0] < before[0]
    assert after[1] < before[1] - 5.0  # seconds of motion won back (BENCHMARKS.md)
    assert plan.estimate().motion_s == pytest.approx(after[1], rel=1e-9)


def test_priced_moves_are_the_engine_routes_times():
    plan = build_plan(load_plan(ROOT / "examples" / "brdf_lobe.toml"), TYPE_I)
    body = [p.target_dict() for p in plan.points if p.targets]
    t = np.array([[p[r] for r in plan.axes] for p in body])
    dyn = dynamics_of(TYPE_I, plan.axes)
    costs = RouteCosts.of(TYPE_I, t, plan.axes, dyn)
    assert costs is not None
    order = np.arange(len(t))
    costs.price(order)
    assert path_cost(costs.matrix, order) == pytest.approx(plan.estimate().motion_s,
                                                           rel=1e-9)


def test_no_costs_on_a_type_ii_bench():
    t = np.zeros((3, 2))
    assert RouteCosts.of(load_profile("sim"), t, ("sample_theta", "detector_theta"),
                         dynamics_of(load_profile("sim"), ("sample_theta",
                                                           "detector_theta"))) is None


def test_two_opt_on_an_asymmetric_matrix_prices_reversals_exactly():
    rng = np.random.default_rng(7)
    n = 12
    costs = rng.uniform(1.0, 10.0, (n + 1, n + 1))
    costs[:, n] = 0.0
    start = rng.permutation(n)
    out = _two_opt_by_cost(costs, start, max_passes=50)
    assert sorted(out) == list(range(n))
    assert path_cost(costs, out) <= path_cost(costs, start)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=8, max_size=8))
def test_the_bound_agrees_with_the_sampled_path(u):
    """Proven clear: the sampled check passes; proven blocked: it fails."""
    lo = np.array([LIMITS[r][0] for r in TYPE_I_AXES])
    hi = np.array([LIMITS[r][1] for r in TYPE_I_AXES])
    here = lo + (hi - lo) * (np.array(u[:4]) + 1) / 2
    there = lo + (hi - lo) * (np.array(u[4:]) + 1) / 2
    clear, blocked = path_bounds(TYPE_I.geometry, here[None, :], there[None, :], DYN,
                                 segments=BOUND_SEGMENTS)
    sampled = path_clear(TYPE_I.geometry, DYN, dict(zip(TYPE_I_AXES, here, strict=True)),
                         dict(zip(TYPE_I_AXES, there, strict=True))).clear
    assert not (clear[0] and blocked[0])
    if clear[0]:
        assert sampled
    if blocked[0]:
        assert not sampled


def test_many_moves_progress_as_each_alone():
    dyn = DYN["source_arc"]
    t = np.linspace(0.0, 20.0, 41)
    for d in (-170.0, -0.3, 0.0, 0.5, 30.0):
        assert np.array_equal(moves_progress(np.full(t.shape, d), dyn, t),
                              move_progress(d, dyn, t))
