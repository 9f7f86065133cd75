"""Child process for the kill -9 test: runs a scan on the ideal bench until killed.

``python -m tests.instrument.run.killed_run RUNS_DIR N_POINTS`` prints the run file path on
its first line, then runs (frames of 48×64 px, fsync off: a killed *process* loses nothing
the kernel already has).
"""

from __future__ import annotations

import sys

from instrument.plans import build_plan, parse_plan
from instrument.run.runner import start_run
from tests.instrument.helpers import ideal_bench, inplane_plan

SHAPE = (48, 64)


def plan_text(n_points: int) -> str:
    step = 120.0 / max(1, n_points // 2 - 1)
    return inplane_plan(step=step, dark="per_point")


def main() -> None:
    runs_dir, n = sys.argv[1], int(sys.argv[2])
    bench = ideal_bench(shape=SHAPE)
    plan = build_plan(parse_plan(plan_text(n)), bench.profile)
    engine = start_run(plan, bench, runs_dir=runs_dir, fsync=False, catalog=False)
    print(engine.store.path, flush=True)
    engine.run()
    print("finished", flush=True)


if __name__ == "__main__":
    main()
