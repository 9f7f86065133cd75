"""The speed/accuracy planner's options of ``scatterlab plan`` (``--target-uncertainty``).

The search itself is :mod:`instrument.plans.tradeoff`; this module turns its options and
its answer into command-line text. ``--workers N`` / ``--scheduler ADDRESS`` run the sweep
over the candidate scans on a Dask cluster (same answer as here, in the same order).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from instrument.cli._cluster import ClusterUnavailable, add_cluster_options, mapper, open_cluster

if TYPE_CHECKING:  # the search and the models load SciPy: only when asked for
    from instrument.bench.profile import BenchProfile
    from instrument.plans.planfile import PlanSpec
    from instrument.plans.tradeoff import Prior

__all__ = ["add_arguments", "run_from_args"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``scatterlab plan`` for the speed/accuracy search."""
    p.add_argument("--target-uncertainty", type=float, default=None, metavar="X",
                   help="find the fastest scan (θr step, exposure cap, frames) whose "
                   "predicted σ of --target-param is ≤ X")
    p.add_argument("--target-param", default=None,
                   help="parameter name (default: the prior model's last, e.g. ggx.alpha)")
    p.add_argument("--prior", default=None, metavar="MODEL:P1,P2,...",
                   help="expected BRDF (default: the simulated scene of the bench)")
    p.add_argument("--readout-s", type=float, default=None,
                   help="per-frame readout overhead for the estimate (default: the plan's)")
    add_cluster_options(p, local_by_default=False)


def _parse_prior(text: str) -> Prior:
    from analysis.brdf import get_model
    from instrument.plans.tradeoff import Prior

    name, _, values = text.partition(":")
    model = get_model(name.strip())
    try:
        params = tuple(float(v) for v in values.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"--prior {text!r}: the values after ':' must be numbers, e.g. "
                         f"--prior lambert+ggx:0.5,0.2,0.2") from None
    if len(params) != model.n_params:
        raise ValueError(f"--prior: {model.name} takes {model.n_params} parameters "
                         f"{', '.join(model.param_names)}, got {len(params)}")
    return Prior(model.name, params)


def run_from_args(args: argparse.Namespace, spec: PlanSpec, profile: BenchProfile) -> int:
    """Answer ``--target-uncertainty``: print the Pareto front and the fastest scan."""
    from analysis.brdf import get_model
    from instrument.plans.tradeoff import (
        default_options,
        fastest_for_target,
        pareto_front,
        setup_from_profile,
        sweep,
    )

    prior = _parse_prior(args.prior) if args.prior else None
    prior, det = setup_from_profile(profile, spec, prior=prior, readout_s=args.readout_s)
    names = get_model(prior.model).param_names
    param = args.target_param or names[-1]
    if param not in names:
        print(f"error: {prior.model} has no parameter {param!r}; it has {', '.join(names)}")
        return 2
    try:
        with open_cluster(args, local_by_default=False) as client:
            results = sweep(spec, profile, default_options(), prior=prior, det=det,
                            mapper=mapper(client))
    except ClusterUnavailable as err:
        print(f"error: {err}")
        return 2
    where = "--prior" if args.prior else "the bench profile's simulated sample"
    values = ", ".join(f"{n} = {v:g}" for n, v in zip(names, prior.params, strict=True))
    print(f"expected BRDF: {prior.model} with {values} (from {where})")
    print(f"target: standard uncertainty of {param} ≤ {args.target_uncertainty:g}")
    print("fastest scan for each reachable uncertainty (the Pareto front):")
    print(f"  {'duration':>9}  {'σ(' + param + ')':>16}  points  θr step  exposure cap  frames")
    for r in pareto_front(results, param):
        o = r.option
        print(f"  {r.duration_s:7.1f} s  {r.sigma[param]:16.3g}  {r.n_points:6d}  "
              f"{o.theta_r_step_deg:6g}°  {o.max_exposure_us:9g} µs  {o.frames:6d}")
    best = fastest_for_target(results, param, args.target_uncertainty)
    if best is None:
        reach = min(r.sigma[param] for r in results)
        print(f"no candidate reaches σ({param}) ≤ {args.target_uncertainty:g} "
              f"(best {reach:.3g}); add incidence angles or raise the exposure caps")
        return 1
    o = best.option
    print(f"fastest: θr step {o.theta_r_step_deg:g}°, exposure cap {o.max_exposure_us:g} µs, "
          f"{o.frames} frame(s) — {best.n_points} points, {best.duration_s:.1f} s (of which "
          f"motion {best.motion_s:.1f} s), predicted σ({param}) = {best.sigma[param]:.3g}")
    print(f"  in the plan file: theta_r step = {o.theta_r_step_deg:g}, "
          f"[acquisition] max_exposure_us = {o.max_exposure_us:g}, frames = {o.frames}")
    return 0
