"""Child process of the browser's resume test: a scan on a simulated bench, killed mid-run.

``python -m tests.gui.interrupted_run PROFILE RUNS_DIR PLAN`` prints the run file's path,
then runs (fsync off) until the test kills it with SIGKILL.
"""

from __future__ import annotations

import sys

from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile
from instrument.plans import build_plan, load_plan
from instrument.run.runner import start_run


def main() -> None:
    profile_path, runs_dir, plan_path = sys.argv[1:4]
    profile = load_profile(profile_path)
    plan = build_plan(load_plan(plan_path), profile)
    with open_bench(profile) as bench:
        engine = start_run(plan, bench, runs_dir=runs_dir, fsync=False)
        print(engine.store.path, flush=True)
        engine.run()


if __name__ == "__main__":
    main()
