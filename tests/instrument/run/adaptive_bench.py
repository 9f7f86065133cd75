"""An ideal bench whose camera sees a sharp specular lobe, for adaptive-plan tests.

The camera's level follows the sharp-lobe model (:func:`instrument.plans.adaptive_lobe.
lobe_model`, α = 0.05) at the angles the axes stand at, plus a ripple that is a fixed
function of the detector angle: readings scatter like noise, yet a run measured again
at the same angles reads the same values (an interrupted and resumed run can be compared
with an uninterrupted one).

``python -m tests.instrument.run.adaptive_bench RUNS_DIR KILL_AT`` runs the sharp-lobe
refinement in a child process, prints the run file's path, and kills itself (SIGKILL)
when point ``KILL_AT`` is completed: a crash at a chosen point, not at a chosen time.
"""

from __future__ import annotations

import math
import os
import signal
import sys

import numpy as np

from instrument.bench.kinematics import kinematics_for
from instrument.plans.adaptive_lobe import SharpLobe, lobe_model
from instrument.plans.build import build_plan
from instrument.run.events import PointCompleted
from instrument.run.runner import start_run
from tests.instrument.helpers import ideal_bench

ALPHA = 0.05
SHAPE = (8, 8)


def lobe_bench():
    holder: dict = {}

    def brightness() -> float:
        bench = holder["bench"]
        pos = {r: bench.axes[r].status().position for r in ("sample_theta", "detector_theta")}
        a = holder["kin"].angles(pos)
        tr = a.theta_r if abs(a.phi_r - a.phi_i) > 90 else -a.theta_r
        y = float(lobe_model(np.array([tr]), a.theta_i, (0.3, 3.0, 0.0, ALPHA))[0])
        return y * (1.0 + 0.02 * math.sin(977.0 * math.radians(tr)))

    bench = ideal_bench(shape=SHAPE, brightness=brightness)
    holder["bench"] = bench
    holder["kin"] = kinematics_for(bench.profile.geometry.kind,
                                   source_theta_deg=bench.profile.geometry.source_theta_deg)
    return bench


def lobe_plan(**kw) -> SharpLobe:
    opts = {"theta_r": (-60.0, 80.0, 20.0), "search_half_width_deg": 4.0,
            "search_step_deg": 1.0, "target_sigma_alpha": 1e-9, "budget_s": 60.0,
            "batch": 4, "acquisition": {"mode": "fixed", "exposure_us": 1000,
                                        "detectors": ["camera"]}}
    opts.update(kw)
    return SharpLobe(30.0, **opts)


def start(runs_dir, plan: SharpLobe, bench=None):
    bench = bench or lobe_bench()
    base = build_plan(plan.base, bench.profile)
    return start_run(base, bench, runs_dir=runs_dir, fsync=False, catalog=False,
                     adaptive=plan)


def main() -> None:
    runs_dir, kill_at = sys.argv[1], int(sys.argv[2])
    engine = start(runs_dir, lobe_plan())

    def on_event(ev) -> None:
        if isinstance(ev, PointCompleted) and ev.index == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)

    engine.subscribe(on_event)
    print(engine.store.path, flush=True)
    engine.run()
    print("finished", flush=True)


if __name__ == "__main__":
    main()
