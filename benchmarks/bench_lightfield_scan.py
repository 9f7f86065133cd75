"""Simulated light-field scan, end to end: timings and localisation error.

For each sensor seed the built-in ``sim-lightfield`` bench (SMC100 firmware emulator under
the real driver, simulated camera through the EMVA 1288 sensor, continuous-geometry
renderer of a brushed-metal wall with a hidden disc at (y, z) = (−8, −200) mm and a bar)
runs ``examples/lightfield_scan.toml`` through the engine; the run is then reconstructed
and located with :mod:`instrument.pipelines.lightfield`.  Reported per seed: wall-clock
times of the scan, the reconstruction and the localisation; p̂_max; the point object's position
error against the theoretical resolution; the number of detections; and, for comparison,
the number of "objects" simple peak picking finds (local maxima of the conventional focal
stack above the same 0.3 relative threshold, in the same search region, one per
resolution cell) — the reason for the iterative subtraction (ADR 0030).  Then the same
scan (seed 1) behind each of the four thesis walls (``analysis.lightfield.MATERIALS``):
every detection with its quality flag, depth interval and the three depth estimates
(depth filter, matched filter, RP).

Run: ``python benchmarks/bench_lightfield_scan.py`` (5 seeds and the four walls;
``--quick``: seed 1, brushed metal only).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from drivers.transport import add_url_handler_package
from hw_mocks import registry
from hw_mocks.sim.world import reset_worlds
from instrument.cli import main
from instrument.pipelines.lightfield.locate import locate_run
from instrument.pipelines.lightfield.reconstruct import reconstruct_run

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "instrument" / "bench" / "profiles" / "sim-lightfield.toml"
PLAN = ROOT / "examples" / "lightfield_scan.toml"
TRUTH = (-8.0, -200.0)


def peak_count(stack: np.ndarray, enough: np.ndarray, threshold_rel: float,
               size: tuple[int, int]) -> int:
    """Local maxima of the focal stack above ``threshold_rel`` × its maximum, with
    non-maximum suppression over ``size`` = (z, y) samples (the resolution cell)."""
    data = np.where(enough, stack, -np.inf)
    first = float(np.max(data))
    peaks = (data == ndimage.maximum_filter(data, size=size)) & (data >= threshold_rel * first)
    return int(np.count_nonzero(peaks))


def timed_run(plan: Path, profile: Path, out: Path) -> tuple[Path, float]:
    """``scatterlab run PLAN --bench PROFILE --out OUT`` quietly: the run file and the wall
    time (s); RuntimeError if the run fails."""
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["run", str(plan), "--bench", str(profile), "--out", str(out), "--no-fsync",
                   "--quiet"])
    seconds = time.perf_counter() - t0
    if rc != 0:
        raise RuntimeError(f"scan failed: {plan.name} on {profile.name}")
    (run,) = sorted(out.glob("*.h5"))
    return run, seconds


def one(seed: int, folder: Path, material: str = "brushed_metal") -> dict:
    registry.reset()
    reset_worlds()
    profile = folder / f"sim-lightfield-{seed}-{material}.toml"
    profile.write_text(PROFILE.read_text().replace("&seed=1&", f"&seed={seed}&").replace(
        'material = "brushed_metal"', f'material = "{material}"'))
    run, t_scan = timed_run(PLAN, profile, folder / f"runs-{seed}-{material}")
    t0 = time.perf_counter()
    rec = reconstruct_run(run)
    t_rec = time.perf_counter() - t0
    t0 = time.perf_counter()
    loc = locate_run(run)
    t_loc = time.perf_counter() - t0
    det = loc.detection
    pos = det.positions_mm
    # the detection nearest the disc, in units of its own resolution cell
    k = int(np.argmin([np.hypot((pos[i, 0] - TRUTH[0]) / r.transverse_mm,
                                (pos[i, 1] - TRUTH[1]) / r.depth_mm)
                       for i, r in enumerate(det.resolutions)]))
    res = det.resolutions[k]
    st = det.stack
    a, b = st.solvable_domain_rad
    enough = st.measure_rad >= 0.1 * (b - a)
    return {
        "seed": seed, "material": material, "quality": det.quality[k],
        "interval": tuple(det.depth_interval_mm[k]),
        "all": [(tuple(pos[i]), det.quality[i], tuple(det.depth_interval_mm[i]),
                 tuple(det.depth_estimates_mm[i]), det.resolutions[i].transverse_mm,
                 det.resolutions[i].depth_mm) for i in range(det.count)],
        "t_scan": t_scan, "t_rec": t_rec, "t_loc": t_loc, "p_hat": rec.p_hat,
        "dy": pos[k, 0] - TRUTH[0], "dz": pos[k, 1] - TRUTH[1],
        "res_y": res.transverse_mm, "res_z": res.depth_mm, "count": det.count,
        "peaks": peak_count(st.conventional, enough, 0.3, (
            max(3, round(res.depth_mm / (st.z_mm[1] - st.z_mm[0]))),
            max(3, round(res.transverse_mm / (st.y_mm[1] - st.y_mm[0]))))),
        "sigma_ratio": rec.reconstruction.diagnostics.noise.sigma_per_sample
        / rec.measured.sigma_rows,
    }


def run(seeds: list[int], materials: list[str]) -> tuple[list[dict], list[dict]]:
    add_url_handler_package("hw_mocks.urlhandler")
    with tempfile.TemporaryDirectory() as tmp:
        rows = [one(s, Path(tmp)) for s in seeds]
        (Path(tmp) / "walls").mkdir()
        walls = [one(1, Path(tmp) / "walls", m) for m in materials]
    return rows, walls


def report(rows: list[dict]) -> None:
    print("| seed | scan s | reconstruct s | locate s | p̂_max | Δy mm (δy) | Δz mm (δz) "
          "| quality | detections | peak picking | σ_tail/σ_rows |")
    print("|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|")
    for r in rows:
        print(f"| {r['seed']} | {r['t_scan']:.1f} | {r['t_rec']:.2f} | {r['t_loc']:.2f} | "
              f"{r['p_hat']:g} | {r['dy']:+.2f} ({r['res_y']:.1f}) | {r['dz']:+.1f} "
              f"({r['res_z']:.1f}) | {r['quality']} | {r['count']} | {r['peaks']} | "
              f"{r['sigma_ratio']:.2f} |")
    if len(rows) > 1:
        dz = [r["dz"] for r in rows]
        dy = [r["dy"] for r in rows]
        print(f"\nmean Δy {statistics.mean(dy):+.2f} ± {statistics.stdev(dy):.2f} mm, "
              f"mean Δz {statistics.mean(dz):+.1f} ± {statistics.stdev(dz):.1f} mm")


def report_walls(walls: list[dict]) -> None:
    print("\n| wall | p̂_max | detection (y, z) mm | blur δy / δz mm | quality "
          "| depth interval mm | z: depth filter / matched filter / RP |")
    print("|---|---:|---|---|---|---|---|")
    for w in walls:
        for i, (pos, q, iv, est, ry, rz) in enumerate(w["all"]):
            name = w["material"] if i == 0 else ""
            p_hat = f"{w['p_hat']:g}" if i == 0 else ""
            print(f"| {name} | {p_hat} | ({pos[0]:.1f}, {pos[1]:.1f}) | {ry:.1f} / {rz:.1f} "
                  f"| {q} | [{iv[0]:.0f}, {iv[1]:.0f}] | {est[0]:.0f} / {est[1]:.0f} / "
                  f"{est[2]:.0f} |")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed, brushed metal only")
    args = ap.parse_args()
    from analysis.lightfield import MATERIALS

    rows, walls = run([1] if args.quick else [1, 2, 3, 4, 5],
                      [] if args.quick else list(MATERIALS))
    report(rows)
    if walls:
        report_walls(walls)
