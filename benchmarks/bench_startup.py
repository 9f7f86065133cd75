"""Start-up time of the ``scatterlab`` command: ``--help`` and a ``plan`` dry run.

Each command is run ``--runs`` times in a fresh interpreter (as a user types it) after one
warm-up run; reported are the median, minimum and maximum wall times, like hyperfine. With
``--tree DIR`` the same commands run against another checkout (``python -m instrument.cli``
with ``DIR`` first on the path), to compare before and after a change.

    python benchmarks/bench_startup.py
    python benchmarks/bench_startup.py --runs 30 --tree /path/to/other/checkout
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def timed(argv: list[str], cwd: Path, runs: int) -> list[float]:
    env = {**os.environ, "PYTHONPATH": str(cwd)}
    subprocess.run(argv, cwd=cwd, env=env, capture_output=True, check=True)  # warm-up
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        subprocess.run(argv, cwd=cwd, env=env, capture_output=True, check=True)
        out.append(time.perf_counter() - t)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout to run (default: this)")
    args = ap.parse_args()
    cli = [sys.executable, "-m", "instrument.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        cases = {
            "scatterlab --help": [*cli, "--help"],
            "scatterlab plan examples/brdf_inplane.toml": [
                *cli, "plan", "examples/brdf_inplane.toml", "--png", f"{tmp}/c.png"],
            "scatterlab plan examples/lightfield_scan.toml --bench sim-lightfield": [
                *cli, "plan", "examples/lightfield_scan.toml", "--bench", "sim-lightfield"],
        }
        print(f"| command | median s | min s | max s | runs |   (tree {args.tree}, load "
              f"{os.getloadavg()[0]:.1f})")
        print("|---|---:|---:|---:|---:|")
        for name, argv in cases.items():
            t = timed(argv, args.tree, args.runs)
            print(f"| `{name}` | {statistics.median(t):.3f} | {min(t):.3f} | {max(t):.3f} "
                  f"| {len(t)} |", flush=True)


if __name__ == "__main__":
    main()
