"""Child process for the disk-full test: the kernel refuses writes past a file-size limit.

``python -m tests.instrument.run.full_disk_run RUNS_DIR EXTRA_BYTES [unreserved]``:
RLIMIT_FSIZE makes every write that grows a file past its starting size + EXTRA_BYTES fail
with EFBIG (SIGXFSZ ignored), a real write error from the operating system mid-run.
Prints the path, then each fault and the end.
"""

from __future__ import annotations

import resource
import signal
import sys

from instrument.plans import build_plan, parse_plan
from instrument.run.events import Fault, Paused, RunFinished
from instrument.run.runner import start_run
from instrument.run.storage import RunStore
from tests.instrument.helpers import ideal_bench, inplane_plan


def main() -> None:
    runs_dir, extra = sys.argv[1], int(sys.argv[2])
    if "unreserved" in sys.argv[3:]:
        # Take away the space reservation to exercise the fallback: a write that fails
        # inside HDF5 itself.
        RunStore._reserve = lambda self, nbytes: None
    bench = ideal_bench(shape=(64, 64), noise_dn=300.0)
    plan = build_plan(parse_plan(inplane_plan(step=2.0)), bench.profile)
    engine = start_run(plan, bench, runs_dir=runs_dir, fsync=False, catalog=False,
                       min_free_bytes=0)
    print(engine.store.path, flush=True)
    limit = engine.store.path.stat().st_size + extra
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    def on(ev) -> None:
        if isinstance(ev, Fault):
            print(f"FAULT {ev.device}: {ev.cause} -> {ev.action}", flush=True)
        elif isinstance(ev, Paused):
            print(f"PAUSED {ev.reason}", flush=True)
            print(f"LIGHT {bench.source._on}", flush=True)
            engine.stop_when_paused()
        elif isinstance(ev, RunFinished):
            print(f"END {ev.status} {ev.n_done}/{ev.n_total}", flush=True)

    engine.subscribe(on)
    engine.run()


if __name__ == "__main__":
    main()
