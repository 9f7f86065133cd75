"""Sphere capture end to end on the emulated sphere bench.

For each procedural environment (``[simulation.scene] environment = { seed = n }`` of the
sim-spheres profile) the example plan ``examples/sphere_capture.toml`` runs through
``scatterlab run`` (firmware emulators under the real drivers, simulated camera with its
EMVA 1288 sensor, auto-exposure HDR brackets and darks), then the analysis of
:mod:`instrument.pipelines.spheres`: the L1 error of the fourth image rendered from the
other three
(BRDF transfer), the consistency statistic of the untampered capture against its
threshold, and the same for a spliced capture (top half of the last image from the other
lighting).

    python benchmarks/bench_sphere_capture.py            # environments 1..8
    python benchmarks/bench_sphere_capture.py --quick    # environment 1 only
    python benchmarks/bench_sphere_capture.py --seeds 1-16
    python benchmarks/bench_sphere_capture.py --calibrate 17-116   # the bench's factor q

``--calibrate`` captures consistent (untampered) environments only and prints the conformal
factor q on T/threshold (:func:`analysis.sh.consistency.threshold_factor`, α = 0.01), the
value behind :data:`instrument.pipelines.spheres.analyse.SIM_SPHERES_THRESHOLD_SCALE`;
the table's last
columns judge the (held-out) environments at that factor.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.sh.consistency import threshold_factor  # noqa: E402
from hw_mocks import registry  # noqa: E402
from hw_mocks.sim.world import reset_worlds  # noqa: E402
from instrument.cli import main  # noqa: E402
from instrument.pipelines.spheres.analyse import SIM_SPHERES_THRESHOLD_SCALE, analyse_capture  # noqa: E402
from instrument.pipelines.spheres.pipeline import analyse_run  # noqa: E402

PROFILE = ROOT / "instrument" / "bench" / "profiles" / "sim-spheres.toml"
PLAN = ROOT / "examples" / "sphere_capture.toml"


def capture(seed: int, folder: Path) -> tuple[Path, float]:
    """Run the example plan on the profile with environment ``seed``: (run file, seconds)."""
    text = re.sub(r"environment = \{ seed = \d+ \}", f"environment = {{ seed = {seed} }}",
                  PROFILE.read_text())
    prof = folder / f"sim-spheres-{seed}.toml"
    prof.write_text(text)
    out = folder / f"runs-{seed}"
    registry.reset()
    reset_worlds()
    t0 = time.perf_counter()
    rc = main(["run", str(PLAN), "--bench", str(prof), "--out", str(out), "--no-fsync",
               "--quiet"])
    t_run = time.perf_counter() - t0
    if rc != 0:
        raise RuntimeError(f"scatterlab run failed ({rc}) for environment {seed}")
    (path,) = out.glob("*.h5")
    return path, t_run


def one(seed: int, folder: Path) -> dict[str, float]:
    path, t_run = capture(seed, folder)
    t0 = time.perf_counter()
    cap, res = analyse_run(path, write=False)
    t_ana = time.perf_counter() - t0
    rad = cap.radiance.copy()
    half = rad.shape[2] // 2
    rad[-1, -1, :half] = rad[0, -1, :half]
    tam = analyse_capture(dataclasses.replace(cap, radiance=rad))
    return {
        "seed": seed, "l1": res.relight_l1, "t": res.consistency.statistic,
        "thr": res.consistency.threshold, "flag": res.consistency.inconsistent,
        "t_tam": tam.consistency.statistic, "thr_tam": tam.consistency.threshold,
        "flag_tam": tam.consistency.inconsistent, "run_s": t_run, "ana_s": t_ana,
        "radius": res.radius,
    }


def run(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="environment 1 only")
    ap.add_argument("--seeds", default="1-8", help="environments A-B (default 1-8)")
    ap.add_argument("--calibrate", metavar="A-B", default=None,
                    help="consistent captures of environments A-B → the factor q")
    args = ap.parse_args(argv)
    if args.calibrate:
        return calibrate(_seed_range(args.calibrate))
    seeds = [1] if args.quick else _seed_range(args.seeds)
    q = SIM_SPHERES_THRESHOLD_SCALE
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in seeds:
            rows.append(one(s, Path(tmp)))
    print("| env seed | relight L1 | T (untampered) | threshold | flagged | T (spliced) "
          "| threshold | flagged | capture [s] | analysis [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['seed']} | {100 * r['l1']:.2f} % | {r['t']:.3g} | {r['thr']:.3g} | "
              f"{'yes' if r['flag'] else 'no'} | {r['t_tam']:.3g} | {r['thr_tam']:.3g} | "
              f"{'yes' if r['flag_tam'] else 'no'} | {r['run_s']:.1f} | {r['ana_s']:.2f} |")
    l1 = [r["l1"] for r in rows]
    print(f"\nrelight L1: max {100 * max(l1):.2f} %, mean {100 * sum(l1) / len(l1):.2f} % "
          f"over {len(rows)} environment(s); untampered flagged "
          f"{sum(r['flag'] for r in rows)}/{len(rows)}, spliced flagged "
          f"{sum(r['flag_tam'] for r in rows)}/{len(rows)}")
    fa = sum(r["t"] > q * r["thr"] for r in rows)
    det = sum(r["t_tam"] > q * r["thr_tam"] for r in rows)
    print(f"at the bench's threshold scale q = {q:g}: untampered flagged {fa}/{len(rows)}, "
          f"spliced flagged {det}/{len(rows)}")
    return 0


def _seed_range(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def calibrate(seeds: list[int], false_alarm: float = 0.01) -> int:
    """Print u = T/threshold of consistent captures and the conformal factor q."""
    need = int(np.ceil(1.0 / false_alarm)) - 1
    if len(seeds) < need:
        raise SystemExit(f"--calibrate needs ≥ {need} environments for α = {false_alarm:g} "
                         f"(got {len(seeds)})")
    u = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in seeds:
            path, _ = capture(s, Path(tmp))
            rep = analyse_run(path, write=False)[1].consistency
            u.append(rep.statistic / rep.threshold)
            print(f"environment {s}: T/threshold = {u[-1]:.3f}", flush=True)
    q = threshold_factor(u, false_alarm=false_alarm)
    print(f"\n{len(u)} consistent captures: u > 1 in {sum(x > 1 for x in u)}; "
          f"largest {max(u):.3f}; conformal factor q at α = {false_alarm:g}: {q:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(run())
