"""The null distribution of the localiser's detection statistic behind a wall, measured.

Scene: the validation matrix's one-object scene (a 3 mm disc at (0, −200) mm,
``bench_lightfield_validation.py``), which opens the Wiener filter as a real scan does.
Each seed adds independent noise to the same noise-free render and is reconstructed; the
reconstruction's *noise* is the seed's field minus the mean over the seeds (scaled by
``√(S/(S−1))``), so the disc and its model mismatch drop out and only noise passed through
the whole pipeline (curves, interpolation, coefficients, filter) remains.

Measured on it, per wall:

* the point statistic ``Z(x) = ⟨K_x, n⟩ / √(K_xᵀ C K_x)`` on the search grid (the
  single-point significance of :func:`analysis.lightfield.significance.amplitude_fit`; its
  C is the reconstruction's noise model) — its spread at each point (1 if σ is right) and
  its maximum over the grid per seed;
* the per-scan exceedance ``P(max Z > u)`` against the Bonferroni bound of the
  resolution cells (``N_cells Q(u)``, ADR 0032) and the expected Euler characteristic of
  the excursion set with the field's own smoothness
  (:func:`analysis.lightfield.excursion.expected_euler`; Worsley et al. 1996);
* the deterministic part the point model leaves at points away from the disc (the mean
  over seeds of the joint disc + point significance at 40 fixed points), which noise
  alone cannot produce.

Run: ``python benchmarks/bench_lightfield_null.py --walls coated_paper_matte
coated_paper_glossy brushed_metal --seeds 300 --cache DIR`` (``DIR`` the validation
benchmark's render cache).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import bench_lightfield_validation as val
import numpy as np
from scipy.special import ndtr

from analysis.lightfield import effective_p_max, reconstruct, theoretical_resolution
from analysis.lightfield.excursion import expected_euler, statistic_metric
from analysis.lightfield.ray_fit import ray_model
from analysis.lightfield.significance import amplitude_fit


def run_wall(wname: str, seeds: int, cache: Path | None) -> None:
    brdf = val.walls()[wname]
    lf = val.render(brdf, val.scenes(10.0)["one"], cache, f"{wname}__one")
    t0 = time.process_time()
    gs = []
    rec = None
    for seed in range(1, seeds + 1):
        rng = np.random.default_rng(seed)
        noisy = lf.with_radiance(lf.radiance + rng.normal(0.0, val.NOISE, lf.shape))
        rec = reconstruct(noisy, brdf, d2_mm=val.D2, points_mm=val.WALL_POINTS)
        f = rec.incident_field
        a, b = rec.solvable_domain_rad
        use = (f.theta_rad >= a) & (f.theta_rad <= b)
        gs.append((np.asarray(f.radiance, float) * np.cos(f.theta_rad)[None, :])[:, use])
    assert rec is not None
    g = np.asarray(gs)
    n = (g - g.mean(axis=0)) * np.sqrt(seeds / (seeds - 1.0))
    f = rec.incident_field
    a, b = rec.solvable_domain_rad
    use = (f.theta_rad >= a) & (f.theta_rad <= b)
    phi = np.atleast_2d(np.asarray(rec.regularization.filter_factors, float)).mean(0)
    noise = np.broadcast_to(np.asarray(rec.regularization.noise_power, float), phi.shape)
    p_hat = effective_p_max(rec.regularization.filter_factors, rec.orders)
    y, zs = val.Y_GRID, val.Z_GRID
    aperture = float(f.y_mm[-1] - f.y_mm[0])
    z_field = np.empty((zs.size, y.size, seeds))
    n_cells = 0.0
    step_y, step_z = float(y[1] - y[0]), float(zs[1] - zs[0])
    for i, z in enumerate(zs):
        pos = np.column_stack([y, np.full(y.size, z)])
        r, _, _ = ray_model(f, use, phi, pos)
        metric = statistic_metric(f, use, phi, noise, pos)
        kn = r.reshape(y.size, -1) @ n.reshape(seeds, -1).T
        z_field[i] = kn / metric.sigma[:, None]
        res = theoretical_resolution(p_hat, domain_rad=f.domain_rad, distance_mm=abs(z),
                                     aperture_mm=aperture, solvable_domain_rad=(a, b))
        n_cells += y.size * step_y * step_z / (res.transverse_mm * res.depth_mm)
    euler = expected_euler(f, use, phi, noise, y, zs, np.ones((zs.size, y.size), bool))
    zmax = z_field.reshape(-1, seeds).max(axis=0)
    spread = z_field.std(axis=2)
    # the field standardised by its own spread at each point: the tail of its maximum
    # tests the smoothness part (L₁, L₂) apart from the scale of σ
    std_max = (z_field / spread[..., None]).reshape(-1, seeds).max(axis=0)
    print(f"{wname}: p̂ {p_hat:g}, {seeds} seeds, {time.process_time() - t0:.0f} s CPU")
    print(f"  pull spread over the grid: median {np.median(spread):.3f}, "
          f"5–95 % {np.percentile(spread, 5):.3f}–{np.percentile(spread, 95):.3f}")
    print(f"  N_cells (Bonferroni) {n_cells:.0f}; Lipschitz–Killing L1 {euler.l1:.1f}, "
          f"L2 {euler.l2:.1f}")
    print("  u    P(max Z > u)   P(max Z/spread > u)   Bonferroni   E[EC]")
    for u in (2.5, 3.0, 3.5, 4.0, 4.5):
        emp = float(np.mean(zmax > u))
        print(f"  {u:.1f}  {emp:8.3f}      {float(np.mean(std_max > u)):8.3f}             "
              f"{min(1.0, n_cells * ndtr(-u)):8.3f}   {euler.probability(u):8.3f}")
    print(f"  thresholds at 0.01: Bonferroni {val_threshold(n_cells):.2f}σ, "
          f"E[EC] {euler.threshold(0.01):.2f}σ; empirical 99th pct of max "
          f"{np.percentile(zmax, 99):.2f}σ (standardised: {np.percentile(std_max, 99):.2f}σ)")
    # the deterministic part at points away from the disc: the mean significance there
    rng0 = np.random.default_rng(12345)
    pts = np.column_stack([rng0.choice([-1, 1], 40) * rng0.uniform(40, 90, 40),
                           rng0.uniform(-380, -80, 40)])
    r, _, _ = ray_model(f, use, phi, np.vstack([[0.0, -200.0], pts]))
    mean_s = np.zeros(len(pts))
    for k in range(len(pts)):
        fits = [amplitude_fit(gi, r[[0, k + 1]], use, phi, noise).significance[1]
                for gi in g[: min(seeds, 100)]]
        mean_s[k] = float(np.mean(fits))
    print(f"  mean joint significance at 40 points away from the disc (100 seeds): "
          f"{mean_s.min():.2f} … {mean_s.max():.2f}σ, spread {mean_s.std():.2f}")


def val_threshold(n_cells: float) -> float:
    from analysis.lightfield.significance import snr_threshold

    return snr_threshold(0.01, n_cells)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--walls", nargs="+", default=["coated_paper_matte",
                                                   "coated_paper_glossy", "brushed_metal"])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--cache", type=Path, default=None)
    args = ap.parse_args()
    for w in args.walls:
        run_wall(w, args.seeds, args.cache)


if __name__ == "__main__":
    main()
