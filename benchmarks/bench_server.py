"""The bench server under load: request latency, event fan-out, Stop-all latency.

The server runs in this process as ``scatterlab serve`` runs it (uvicorn on a loopback
socket, the service and its engine on their own threads); the clients run in a separate
process, as they would on other machines.

1. **Request latency**: ``GET /api/v1/status`` and ``POST /api/v1/queue/stop`` (audited),
   one after the other from one client (httpx), idle server: p50 and p99.
2. **Fan-out**: an N-point in-plane scan (power meter only) on the ideal, zero-latency
   bench of tests/instrument/helpers.py, run through the queue with no client, then with
   50 observer clients on the event stream: the engine's points/s (from its own
   ``run_finished`` elapsed time) in both, and whether every client received every
   lifecycle message (started, finished) and how many display messages it was told it
   missed. Then the same on the emulated sim bench (stages at 20× real time), where
   points take motion time as on a real bench.
3. **Stop all**: on the emulated sim bench (real drivers, firmware emulators at real
   speed), a manual move of the sample stage is under way; the time from sending
   ``POST /api/v1/bench/stop-all`` until the server answers (the stop written to every
   axis's controller) and until the emulated stage stands still, against a stop called
   on the driver directly.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_server.py          # 10,000 points
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_server.py --quick  # 2,000 points
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402
import numpy as np  # noqa: E402
import uvicorn  # noqa: E402

from benchmarks.power_meter_scan import power_meter_scan  # noqa: E402
from instrument.bench.profile import load_profile, parse_profile  # noqa: E402
from instrument.protocol import API_PREFIX  # noqa: E402
from instrument.server.app import create_app  # noqa: E402
from instrument.server.main import WS_OPTIONS  # noqa: E402
from instrument.server.service import BenchService  # noqa: E402
from tests.instrument.helpers import ideal_bench  # noqa: E402

N_CLIENTS = 50


def scan_plan(n_target: int) -> str:
    return power_meter_scan(n_target, "server benchmark")


#: A power-meter scan on the emulated sim bench (the detector arm's moves set the pace).
SIM_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "server benchmark, sim bench"
[sample]
name = "sim-grey"
[scan]
theta_i = [20.0]
theta_r = {{ start = -80.0, stop = 80.0, step = {step} }}
skip_beam_points = true
[acquisition]
mode = "fixed"
exposure_us = 1000
detectors = ["power_meter"]
"""


class Served:
    """A service and its uvicorn server on a random loopback port, on a thread."""

    def __init__(self, service: BenchService) -> None:
        self.service = service
        sock = socket.socket()
        sock.bind(("127.0.0.1", 0))
        sock.listen(2048)
        self.url = f"http://127.0.0.1:{sock.getsockname()[1]}"
        config = uvicorn.Config(create_app(service), log_level="warning", lifespan="on",
                                **WS_OPTIONS)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [sock]},
                                       name="uvicorn", daemon=True)
        self.thread.start()
        while not self.server.started:
            time.sleep(0.01)

    def close(self) -> None:
        self.server.should_exit = True
        self.thread.join(60)


def thread_cpu(pid: int | str = "self") -> dict[str, float]:
    """CPU seconds (user + system) of each thread of a process, summed by thread name
    (Linux /proc; empty elsewhere)."""
    out: dict[str, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    names = {t.native_id: t.name.split(" ")[0] for t in threading.enumerate()} \
        if pid == "self" else {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue
        name = names.get(int(task.name)) or stat[stat.index("(") + 1:stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    # the process as a whole: threads that ended (the run's engine) are counted here only
    with contextlib.suppress(OSError):
        stat = Path(f"/proc/{pid}/stat").read_text()
        fields = stat[stat.rindex(")") + 2:].split()
        out["(process)"] = (int(fields[11]) + int(fields[12])) / tick
    return out


def cpu_since(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    return {k: after[k] - before.get(k, 0.0) for k in after if after[k] > before.get(k, 0.0)}


def percentile_ms(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs) * 1e3, q))


def request_latency(url: str, n: int) -> dict[str, float]:
    out = {}
    with httpx.Client(base_url=url + API_PREFIX) as c:
        for method, path in (("GET", "/status"), ("POST", "/queue/stop")):
            c.request(method, path)  # warm
            ts = []
            for _ in range(n):
                t0 = time.perf_counter()
                r = c.request(method, path)
                ts.append(time.perf_counter() - t0)
                assert r.status_code == 200, r.text
            out[f"{method} {path} p50"] = percentile_ms(ts, 50)
            out[f"{method} {path} p99"] = percentile_ms(ts, 99)
    return out


# the clients' process ------------------------------------------------------------------
CLIENTS_CODE = r"""
import asyncio, json, sys
from websockets.asyncio.client import connect

async def one(url, ready, counts):
    async with connect(url, max_size=None) as ws:
        ready.append(1)
        async for text in ws:
            m = json.loads(text)
            counts[m["type"]] = counts.get(m["type"], 0) + 1
            if m["type"] == "missed":
                for k, v in m["data"]["counts"].items():
                    counts["missed " + k] = counts.get("missed " + k, 0) + v
            if m["type"] == "run_finished":
                return

async def main(url, n):
    ready, counts = [], [dict() for _ in range(n)]
    tasks = [asyncio.create_task(one(url, ready, counts[i])) for i in range(n)]
    while len(ready) < n:
        await asyncio.sleep(0.01)
    print("ready", flush=True)
    await asyncio.gather(*tasks)
    print(json.dumps(counts), flush=True)

asyncio.run(main(sys.argv[1], int(sys.argv[2])))
"""


def run_scan(served: Served, plan: str, n_clients: int) -> dict:
    clients = None
    if n_clients:
        ws_url = "ws" + served.url[4:] + API_PREFIX + "/events"
        clients = subprocess.Popen([sys.executable, "-c", CLIENTS_CODE, ws_url,
                                    str(n_clients)], stdout=subprocess.PIPE, text=True)
        assert clients.stdout.readline().strip() == "ready"
    finished = threading.Event()
    result: dict = {}

    def on(msg) -> None:
        if msg.type == "run_finished":
            result.update(msg.data)
            finished.set()

    served.service.hub.listen(on)
    with httpx.Client(base_url=served.url + API_PREFIX, timeout=60) as c:
        r = c.post("/queue", json={"plan": plan})
        assert r.status_code == 200, r.text
        # CPU from here to the end of the run (the plan's expansion when it was added is
        # before; its expansion again when it starts is in)
        cpu0 = thread_cpu()
        clients_cpu0 = thread_cpu(clients.pid) if clients is not None else {}
        c.post("/queue/start")
    finished.wait(3600)
    cpu = cpu_since(cpu0, thread_cpu())
    out = {"n": result["n_done"], "points_per_s": result["n_done"] / result["elapsed_s"],
           "cpu": cpu}
    if clients is not None:
        out["cpu"]["(clients' process)"] = cpu_since(clients_cpu0, thread_cpu(clients.pid)
                                                     ).get("(process)", 0.0)
        counts = json.loads(clients.stdout.readline())
        clients.wait(120)
        out["clients_with_every_lifecycle"] = sum(
            c.get("run_started", 0) == 1 and c.get("run_finished", 0) == 1 for c in counts)
        out["progress_received_median"] = float(np.median([c.get("progress", 0)
                                                           for c in counts]))
        out["missed_median"] = float(np.median([sum(v for k, v in c.items()
                                                    if k.startswith("missed "))
                                                for c in counts]))
    return out


def stop_all_latency(work: Path, n: int) -> dict[str, list[float]]:
    """Seconds from sending Stop all until the server answered (every axis's stop command
    written and acknowledged by its controller), and until the emulated stage stood still
    (its own deceleration included); and, for comparison, the stage's standstill after a
    stop called directly on the driver."""
    from hw_mocks import registry

    registry.reset()  # the emulators anew, at the speed of this profile
    text = load_profile("sim").source_text.replace("speed=20", "speed=1")
    profile = parse_profile(text, source="sim at real speed")
    service = BenchService(profile, work / "stop-runs", fsync=False)
    served = Served(service)
    stage = registry.get("simapt", "sample_theta").stage
    axis = service.bench.axes["sample_theta"]
    out: dict[str, list[float]] = {"answered": [], "still": [], "direct still": []}

    def moving_then(stop) -> tuple[float, float]:
        while not stage.is_moving():
            time.sleep(0.001)
        time.sleep(0.2)
        t0 = time.perf_counter()
        stop()
        t1 = time.perf_counter()
        while stage.is_moving():
            time.sleep(0.0005)
        return t1 - t0, time.perf_counter() - t0

    try:
        with httpx.Client(base_url=served.url + API_PREFIX, timeout=60) as c:
            c.post("/bench/home", json={"role": "sample_theta"})
            while not axis.status().is_homed:
                time.sleep(0.05)
            target = 60.0
            for _ in range(n):
                c.post("/bench/move", json={"targets": {"sample_theta": target}})
                answered, still = moving_then(lambda: c.post("/bench/stop-all"))
                out["answered"].append(answered)
                out["still"].append(still)
                c.post("/bench/move", json={"targets": {"sample_theta": -target}})
                out["direct still"].append(moving_then(axis.stop)[1])
    finally:
        served.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2,000 points, fewer requests")
    ap.add_argument("--fanout-only", action="store_true",
                    help="only the zero-latency fan-out scan (no latency, sim bench, stop all)")
    ap.add_argument("--points", type=int, default=None, help="points of the fan-out scan")
    ap.add_argument("--repeat", type=int, default=1,
                    help="fan-out: this many pairs of scans (no client, 50 clients)")
    ap.add_argument("--cpu", action="store_true",
                    help="print the CPU seconds of each thread during the fan-out scans")
    args = ap.parse_args()
    n_points = args.points or (2000 if args.quick else 10_000)
    n_req = 200 if args.quick else 1000
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        bench = ideal_bench()
        service = BenchService(bench.profile, work / "runs", fsync=False,
                               opener=lambda p: bench)
        served = Served(service)
        try:
            if not args.fanout_only:
                lat = request_latency(served.url, n_req)
                print("request latency (idle server, one client):")
                for k, v in lat.items():
                    print(f"  {k}: {v:.2f} ms")
            plan = scan_plan(n_points)
            ratios = []
            for _ in range(args.repeat):  # alternated: the box's load drifts
                alone = run_scan(served, plan, 0)
                print(f"scan, no client: {alone['n']} points, {alone['points_per_s']:.0f} "
                      f"points/s (load average {os.getloadavg()[0]:.1f})")
                crowd = run_scan(served, plan, N_CLIENTS)
                ratios.append(crowd['points_per_s'] / alone['points_per_s'])
                print(f"scan, {N_CLIENTS} observer clients: {crowd['n']} points, "
                      f"{crowd['points_per_s']:.0f} points/s ({ratios[-1]:.1%} of no client); "
                      f"{crowd['clients_with_every_lifecycle']}/{N_CLIENTS} clients received "
                      f"every lifecycle message; median per client: "
                      f"{crowd['progress_received_median']:.0f} progress messages received, "
                      f"{crowd['missed_median']:.0f} display messages reported missed")
                if args.cpu:
                    for what, r in (("no client", alone), (f"{N_CLIENTS} clients", crowd)):
                        print(f"  CPU s during the scan, {what}: " + ", ".join(
                            f"{k} {v:.2f}" for k, v in sorted(r["cpu"].items(),
                                                              key=lambda kv: -kv[1])))
            if args.repeat > 1:
                print(f"50 clients / no client, median of {args.repeat}: "
                      f"{np.median(ratios):.1%} (each: "
                      f"{', '.join(f'{r:.0%}' for r in ratios)})")
        finally:
            served.close()
        if args.fanout_only:
            return
        # the same on the emulated sim bench: real drivers and firmware emulators, stages
        # at 20x real time: points take motion time, as on a real bench
        from hw_mocks import registry

        registry.reset()
        text = load_profile("sim").source_text
        service = BenchService(parse_profile(text, source="sim"), work / "sim-runs",
                               fsync=False)
        served = Served(service)
        try:
            plan = SIM_PLAN.format(step=8.0 if args.quick else 2.0)
            alone = run_scan(served, plan, 0)
            crowd = run_scan(served, plan, N_CLIENTS)
            print(f"sim bench scan: {alone['n']} points; no client "
                  f"{alone['points_per_s']:.2f} points/s, {N_CLIENTS} observer clients "
                  f"{crowd['points_per_s']:.2f} points/s "
                  f"({crowd['points_per_s'] / alone['points_per_s']:.1%}); "
                  f"{crowd['clients_with_every_lifecycle']}/{N_CLIENTS} clients received "
                  "every lifecycle message")
        finally:
            served.close()
        stops = stop_all_latency(work, 5 if args.quick else 20)
        print(f"stop all during a manual move (emulated K10CR1 at real speed, "
              f"{len(stops['answered'])} times): answered (stop sent to every axis) median "
              f"{np.median(stops['answered']) * 1e3:.1f} ms, worst "
              f"{max(stops['answered']) * 1e3:.1f} ms; stage still after median "
              f"{np.median(stops['still']) * 1e3:.0f} ms (a stop called on the driver "
              f"directly: {np.median(stops['direct still']) * 1e3:.0f} ms, the stage's "
              "own deceleration)")


if __name__ == "__main__":
    main()
