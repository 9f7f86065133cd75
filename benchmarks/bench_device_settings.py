"""Device settings through the bench server: how long a client waits for its answer, how
long the change takes, and how long Stop all takes while a wheel move is in progress.

The sim bench's filter wheel at real speed (an FW102C turns half a circle in 3 s): each
round moves it to the slot opposite, through ``POST /api/v1/bench/devices/filter_wheel/
settings`` on the app in this process (FastAPI's test client; the service, its settings
worker and the emulators on their own threads). Measured per round: the time until the
request is answered (202), until its ``device_settings`` done event is published, and —
sent once the settings worker is inside the move — the time until ``POST /bench/stop-all``
is answered (its axes stopped), which must not wait for the wheel.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_device_settings.py [--rounds N]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from instrument.bench.profile import load_profile, parse_profile  # noqa: E402
from instrument.protocol import API_PREFIX  # noqa: E402
from instrument.server.app import create_app  # noqa: E402
from instrument.server.service import BenchService  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=6)
    args = ap.parse_args()
    text = load_profile("sim").source_text.replace(
        "simfw102c://filter_wheel?world=sim&speed=20", "simfw102c://filter_wheel?world=sim")
    ended: dict[int, float] = {}
    done = threading.Condition()

    def on_message(m) -> None:
        if m.type == "device_settings" and m.data["state"] != "applying":
            with done:
                ended[m.data["request_id"]] = time.perf_counter()
                done.notify_all()

    answer, change, stop = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        service = BenchService(parse_profile(text, source="sim, wheel at real speed"),
                               Path(tmp) / "runs", fsync=False)
        service.hub.listen(on_message)
        with TestClient(create_app(service)) as http:
            while "filter_wheel" not in service._state_info:  # its slot count, read once
                time.sleep(0.05)
            for k in range(args.rounds):
                slot = 4 if k % 2 == 0 else 1
                t0 = time.perf_counter()
                r = http.post(f"{API_PREFIX}/bench/devices/filter_wheel/settings",
                              json={"changes": {"position": slot}})
                t1 = time.perf_counter()
                assert r.status_code == 202, r.text
                rid = r.json()["request_id"]
                while service._applying is None and rid not in ended:
                    time.sleep(0.001)  # the worker has taken it
                t2 = time.perf_counter()
                assert http.post(f"{API_PREFIX}/bench/stop-all").status_code == 200
                t3 = time.perf_counter()
                with done:
                    done.wait_for(lambda rid=rid: rid in ended, 60)
                answer.append(t1 - t0)
                change.append(ended[rid] - t0)
                stop.append(t3 - t2)
                print(f"round {k + 1}: slot {slot}: answered in {1e3 * (t1 - t0):.1f} ms, "
                      f"done after {ended[rid] - t0:.2f} s; Stop all during the move "
                      f"answered in {1e3 * (t3 - t2):.1f} ms", flush=True)
        service.close()
    for name, xs, unit in (("answer (202)", answer, 1e3), ("change done", change, 1.0),
                           ("Stop all during a move", stop, 1e3)):
        a = np.asarray(xs) * unit
        print(f"{name}: median {np.median(a):.3g} {'ms' if unit > 1 else 's'}, "
              f"max {a.max():.3g}")


if __name__ == "__main__":
    main()
