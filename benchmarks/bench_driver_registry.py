"""What reading the driver registry costs (ADR 0092): scanning the installed
distributions' ``scatterlab.drivers`` entry points and importing their entries, once per
process, the first time a profile is validated.

Each measurement runs in a fresh interpreter (the registry is read once per process):
importing the profile module, ``load_profile("sim")`` first (the registry read with it)
and again, and one more ``load_registry()`` (the entry-point scan alone: the entries are
imported already). Reported: the median, minimum and maximum over ``--runs`` processes,
the number of installed distributions scanned and whether validating imported NumPy.
``--tree DIR`` runs another checkout (``DIR`` first on the path), to compare before and
after a change.

    python benchmarks/bench_driver_registry.py --runs 7
    python benchmarks/bench_driver_registry.py --runs 7 --tree /path/to/other/checkout
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PROBE = r"""
import importlib.util, json, sys, time
t0 = time.perf_counter()
from instrument.bench.profile import load_profile
t1 = time.perf_counter(); load_profile("sim"); t2 = time.perf_counter(); load_profile("sim")
t3 = time.perf_counter()
out = {"import instrument.bench.profile": t1 - t0, "load_profile('sim'), first": t2 - t1,
       "load_profile('sim'), again": t3 - t2}
numpy = "numpy" in sys.modules
if importlib.util.find_spec("instrument.bench.driver_registry") is not None:
    # (absent from a checkout from before the registry, --tree)
    from instrument.bench.driver_registry import load_registry
    t4 = time.perf_counter(); load_registry(); t5 = time.perf_counter()
    out["load_registry() again (the scan, entries imported)"] = t5 - t4
from importlib import metadata
out["distributions"] = len(list(metadata.distributions()))
out["numpy"] = numpy
print(json.dumps(out))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout to run (default: this)")
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": str(args.tree)}
    samples: dict[str, list[float]] = {}
    dists, numpy = 0, False
    for _ in range(args.runs):
        out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                             check=True, cwd=args.tree, env=env).stdout
        result = json.loads(out)
        dists, numpy = result.pop("distributions"), result.pop("numpy")
        for key, value in result.items():
            samples.setdefault(key, []).append(value * 1e3)
    print(f"| step | median ms | min ms | max ms |   (tree {args.tree}, {args.runs} "
          f"processes, {dists} distributions installed, NumPy imported: {numpy}, load "
          f"{os.getloadavg()[0]:.1f})")
    print("|---|---:|---:|---:|")
    for key, values in samples.items():
        print(f"| {key} | {statistics.median(values):.1f} | {min(values):.1f} | "
              f"{max(values):.1f} |")


if __name__ == "__main__":
    main()
