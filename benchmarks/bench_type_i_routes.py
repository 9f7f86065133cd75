"""Type (i) routes: what guarding the arms' paths costs the planner, and what split moves
cost the scan (ADR 0099).

For each example plan on ``sim-type-i`` (and on its type (ii) twin for comparison):

* the CPU seconds of ``build_plan`` (the guard, the order and, on type (i), the route check
  of every move between points);
* how many of the moves between points the arms cannot make together, and so run as a
  route of several legs;
* the motion time the plan's estimate gives (every move with both arms together, the
  slowest axis per step: ``Plan.estimate().motion_s``) and the motion time of the routes
  the engine will run (each leg's slowest axis, legs one after the other), both in the
  instrument's own time (the profile's velocities, not the emulators' speed-up);
* on type (i), the same for the order the concurrent cost alone gives (every move both
  arms together: the planner before the order priced routes), built in the same process.

    python benchmarks/bench_type_i_routes.py
"""

from __future__ import annotations

import itertools
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from instrument.bench.arms import safe_route  # noqa: E402
from instrument.bench.dynamics import dynamics_of  # noqa: E402
from instrument.bench.kinematics import TYPE_I_AXES  # noqa: E402
from instrument.bench.profile import load_profile  # noqa: E402
from instrument.plans.build import build_plan  # noqa: E402
from instrument.plans.planfile import load_plan  # noqa: E402
from instrument.plans.route_costs import RouteCosts  # noqa: E402

PLANS = (("brdf_inplane.toml", "sim"), ("brdf_hemisphere.toml", "sim-out-of-plane"),
         ("brdf_lobe.toml", "sim"))


def routed_motion_s(plan) -> tuple[int, int, float]:
    """(moves, split moves, seconds) of the routes between the plan's points."""
    profile = plan.profile
    dyn = dynamics_of(profile, TYPE_I_AXES)
    limits = {r: d.limits for r, d in profile.axes.items()}
    pts = [p.target_dict() for p in plan.points if p.targets]
    moves = split = 0
    total = 0.0
    for here, there in itertools.pairwise(pts):
        route = safe_route(profile.geometry, dyn, here, there, limits=limits)
        assert route is not None, "build_plan checked every move"
        moves += 1
        split += route.split
        total += route.seconds(here, dyn)
    return moves, split, total


def build(spec, profile, *, price_routes: bool = True):
    """(plan, CPU seconds of build_plan); without ``price_routes`` the order costs every
    move as both arms together (the planner before the order priced routes)."""
    of = RouteCosts.of
    if not price_routes:
        RouteCosts.of = classmethod(lambda cls, *a, **k: None)  # type: ignore[method-assign]
    try:
        t0 = time.process_time()
        plan = build_plan(spec, profile)
        return plan, time.process_time() - t0
    finally:
        RouteCosts.of = of  # type: ignore[method-assign]


def main() -> None:
    print("| plan | bench | points | build CPU s | moves | split | estimate motion s | "
          "routed motion s | concurrent-cost order: build CPU s, split, routed s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for example, twin in PLANS:
        spec = load_plan(ROOT / "examples" / example)
        for bench in ("sim-type-i", twin):
            profile = load_profile(bench)
            plan, cpu = build(spec, profile)
            est = plan.estimate().motion_s
            if profile.geometry.is_type_i:
                moves, split, routed = routed_motion_s(plan)
                before, cpu_b = build(spec, profile, price_routes=False)
                _, split_b, routed_b = routed_motion_s(before)
                tail = (f"{moves} | {split} | {est:.1f} | {routed:.1f} | {cpu_b:.2f}, "
                        f"{split_b}, {routed_b:.1f}")
            else:
                tail = f"{len(plan.points) - 1} | – | {est:.1f} | {est:.1f} | –"
            print(f"| {example} | {bench} | {len(plan.points)} | {cpu:.2f} | {tail} |")


if __name__ == "__main__":
    main()
