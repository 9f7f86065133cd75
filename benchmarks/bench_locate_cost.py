"""Where ``scatterlab locate`` spends its time: the near-mirror disc at n_theta 256 … 1024.

The case of ``tests/instrument/pipelines/lightfield/test_near_mirror.py``: the built-in
``sim-lightfield`` bench with its wall made a near mirror (specular width 0.01°, ρ_s = 0.6,
ρ_d = 0.08) and its bar removed, leaving the 3 mm disc at (−8, −200) mm, scanned by
``examples/lightfield_scan.toml`` at 100 µs (no frame saturated).  Then, for each n_theta,
``scatterlab locate RUN --n-theta N --no-figures`` with its default search (it
reconstructs at N first), under cProfile: CPU and wall time, the functions that hold the
time, and the objects found.

Run: ``python benchmarks/bench_locate_cost.py --n-theta 256 512 1024`` (``--run FILE``
reuses a scan; ``--top K`` lines of the profile).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import tempfile
import time
from pathlib import Path

from instrument.cli import main as cli

ROOT = Path(__file__).parents[1]
PROFILE = ROOT / "instrument" / "bench" / "profiles" / "sim-lightfield.toml"
EXAMPLE = ROOT / "examples" / "lightfield_scan.toml"


def near_mirror_run(folder: Path) -> Path:
    """Scan the near-mirror bench (module doc) into ``folder``; the run file."""
    text = PROFILE.read_text().replace(
        'material = "brushed_metal"',
        'brdf = { specular_reflectance = 0.6, specular_width_deg = 0.01, '
        'diffuse_reflectance = 0.08, name = "near_mirror" }')
    bar = next(line for line in text.splitlines() if 'kind = "bar"' in line)
    bench = folder / "near_mirror.toml"
    bench.write_text(text.replace(bar + "\n", ""))
    plan = folder / "plan.toml"
    plan.write_text(EXAMPLE.read_text().replace("exposure_us = 5000", "exposure_us = 100"))
    out = folder / "runs"
    if cli(["run", str(plan), "--bench", str(bench), "--out", str(out), "--no-fsync",
            "--quiet"]) != 0:
        raise RuntimeError("the near-mirror scan failed")
    (run,) = sorted(out.glob("*.h5"))
    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-theta", type=int, nargs="+", default=[256])
    ap.add_argument("--run", type=Path, default=None, help="a near-mirror scan to reuse")
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = args.run or near_mirror_run(Path(tmp))
        for n in args.n_theta:
            prof = cProfile.Profile()
            t0, w0 = time.process_time(), time.perf_counter()
            prof.enable()
            rc = cli(["locate", str(run), "--n-theta", str(n), "--no-figures", "--out",
                      str(Path(tmp) / f"locate_{n}")])
            prof.disable()
            cpu, wall = time.process_time() - t0, time.perf_counter() - w0
            text = io.StringIO()
            pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(args.top)
            print(f"n_theta {n}: exit {rc}, CPU {cpu:.1f} s, wall {wall:.1f} s\n"
                  f"{text.getvalue()}", flush=True)


if __name__ == "__main__":
    main()
