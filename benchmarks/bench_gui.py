"""The GUI stays responsive: event-loop latency during a long scan and a fit; camera rates.

Measured on the real main window (offscreen, ``QT_QPA_PLATFORM=offscreen``):

1. **Scan.** A 10,000-point in-plane scan on the ideal (zero-latency) bench of
   tests/instrument/helpers.py, started from the GUI, power meter only (scalar points:
   the engine's fastest path, so the most events per second the GUI must take): the
   live plot, goniometer and progress redraw from the live arrays.
2. **Fit.** ``scatterlab fit`` of a simulated glossy run, launched from the run browser.
3. **Camera.** The simulated camera streaming at 1024² and at 2048² px: the camera's own
   frame rate (frames into the view's slot) against frames displayed per second.

With ``--server`` the scan runs in a bench server process of its own (the ideal bench
behind ``scatterlab serve``'s service and app, started by this script as a child) and the
GUI is the client window (docs/decisions/0084): its plot is fed by the event stream. The
child runs at the niceness of the local server ``scatterlab gui`` starts
(:data:`instrument.client.local.LOCAL_NICE`, set as ``scatterlab serve --nice`` sets it);
``--server-nice N`` measures another (0: the priority of a standalone server).

Latency is measured by a heartbeat: a 5 ms precise ``QTimer`` on the GUI thread records
when it fires; a beat's delay beyond its period is how long the GUI thread was unable to
react just before it. The worst is the longest of these. The p99 is taken over *time*, not
over beats (:func:`time_p99`): the delay that an event (a click, a key) arriving at a random
moment of the scan exceeds with probability 1 %. Over beats, a 40 ms stall is one beat
against the eight that fire in 40 ms of an idle loop, so the per-beat p99 (printed too, for
comparison with the earlier rows of BENCHMARKS.md) understates how often an operator meets
a stall. Target: worst ≤ 50 ms, p99 ≤ 16 ms.

    python benchmarks/bench_gui.py                 # everything
    python benchmarks/bench_gui.py --quick         # 2,000 scan points, 3 s of camera
    python benchmarks/bench_gui.py --server        # the scan only, engine in a server process
    python benchmarks/bench_gui.py --scan-only     # the scan only, engine in this process
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from PySide6.QtCore import QSettings, Qt, QTimer  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

from benchmarks.power_meter_scan import power_meter_scan  # noqa: E402
from gui.app import create_window  # noqa: E402
from gui.model.session import StartRun  # noqa: E402
from instrument.bench.profile import load_profile, parse_profile  # noqa: E402
from instrument.client.local import LOCAL_NICE  # noqa: E402
from instrument.plans import build_plan, parse_plan  # noqa: E402
from instrument.run.catalog import Catalog, RunRow  # noqa: E402
from tests.instrument.helpers import ideal_bench  # noqa: E402

HEARTBEAT_MS = 5


def time_p99(delays: np.ndarray, duration_s: float, q: float = 0.99) -> float:
    """The delay (s) that an event arriving at a uniformly random moment of ``duration_s``
    exceeds with probability ``1 − q``, from the heartbeat's delays: a beat ``d`` late
    means the GUI thread was busy for the last ``d`` before it, so an event arriving in
    that stretch waits between ``d`` and 0 (uniformly), and the time during which the wait
    exceeds ``x`` is ``Σ max(d − x, 0)``. Solved for ``x`` by bisection."""
    d = np.asarray(delays, float)
    d = d[d > 0]
    budget = (1.0 - q) * duration_s
    if d.size == 0 or d.sum() <= budget:
        return 0.0
    lo, hi = 0.0, float(d.max())
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if np.maximum(d - mid, 0.0).sum() > budget:
            lo = mid
        else:
            hi = mid
    return hi


class Heartbeat:
    """Records the GUI thread's delays beyond a fixed timer period."""

    def __init__(self, period_ms: int = HEARTBEAT_MS) -> None:
        self.period = period_ms / 1000.0
        self.timer = QTimer()
        # precise: a coarse timer may fire up to 5 % of its period off its schedule
        self.timer.setTimerType(Qt.TimerType.PreciseTimer)
        self.timer.setInterval(period_ms)
        self.timer.timeout.connect(self._beat)
        self.t: list[float] = []

    def _beat(self) -> None:
        self.t.append(time.perf_counter())

    def start(self) -> None:
        self.t = [time.perf_counter()]
        self.timer.start()

    def stop(self, *, settle_s: float = 0.0) -> dict[str, float]:
        """Worst delay, its 99th percentile over time (:func:`time_p99`) and over beats;
        ``steady_max_ms`` leaves out the first ``settle_s`` seconds (the run's start)."""
        self.timer.stop()
        t = np.array(self.t)
        gaps = np.diff(t) - self.period if len(t) > 1 else np.zeros(1)
        late = t[1:] > t[0] + settle_s if len(t) > 1 else np.ones(1, bool)
        steady = gaps[late] if late.any() else gaps
        duration = float(t[-1] - t[0]) if len(t) > 1 else 0.0
        return {"max_ms": 1e3 * float(gaps.max()),
                "p99_ms": 1e3 * time_p99(gaps, duration),
                "beat_p99_ms": 1e3 * float(np.percentile(gaps, 99)),
                "steady_max_ms": 1e3 * float(steady.max()), "beats": len(t)}


def spin(app: QApplication, cond, timeout: float, costs: list[float] | None = None
         ) -> None:
    """Run the event loop until ``cond()``; ``costs``: append each event-loop pass's CPU
    time on this thread (``time.thread_time``: its own work, painting included, without
    the waits for a CPU that a loaded machine adds to wall time)."""
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError("benchmark step did not finish")
        if costs is None:
            app.processEvents()
        else:
            t = time.thread_time()
            app.processEvents()
            costs.append(time.thread_time() - t)
        time.sleep(0.001)


def scan_plan(n_target: int) -> str:
    return power_meter_scan(n_target, "gui benchmark")


def bench_scan(app: QApplication, work: Path, n_points: int) -> dict:
    window = create_window(bench="sim", out=work / "runs", opener=lambda p: ideal_bench(),
                           settings=QSettings(str(work / "s.ini"), QSettings.IniFormat),
                           fsync=False)
    window.show()
    window.bench_panel.connect_bench()
    spin(app, lambda: window.session.connected and bool(window.session.states()), 30)
    profile = ideal_bench().profile
    plan = build_plan(parse_plan(scan_plan(n_points)), profile)
    hb = Heartbeat()
    hb.start()
    t0 = time.perf_counter()
    window.session.submit(StartRun(plan, work / "runs"))
    spin(app, lambda: window.current_run is not None, 60)
    spin(app, lambda: window.session.run is None
         and window.run_control.last_finished is not None, 3600)
    elapsed = time.perf_counter() - t0
    out = hb.stop(settle_s=0.5)
    ev = window.run_control.last_finished
    out.update(points=ev.n_done, status=ev.status, seconds=elapsed,
               plotted=window.live_plot.n_plotted)
    _close(app, window)
    return out


def serve_ideal(runs: str, nice: int) -> None:
    """The child of ``--server``: the ideal bench's server on a free loopback port, at
    niceness ``nice`` (as ``scatterlab serve --nice``); prints its address, serves until
    killed."""
    import socket

    from instrument.server.priority import lower_priority

    lower_priority(nice)  # first, as serve() does: every thread inherits it
    import uvicorn

    from instrument.server.app import create_app
    from instrument.server.service import BenchService

    bench = ideal_bench()
    service = BenchService(bench.profile, runs, fsync=False, opener=lambda p: bench)
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(128)
    print(f"serving on http://127.0.0.1:{sock.getsockname()[1]}", flush=True)
    uvicorn.Server(uvicorn.Config(create_app(service), log_level="warning",
                                  ws="websockets-sansio")).run(sockets=[sock])


def _gui_thread_costs(window_cls) -> list[float]:
    """Record the CPU time (``time.thread_time``, not wall time: on a loaded machine the
    wall time includes waiting for a CPU) of each call of the client window's redraw and
    of the link's drain: the work the GUI thread itself does for the scan."""
    from gui.qt.server_link import ServerLink

    costs: list[float] = []

    def timed(f):
        def call(*a, **k):
            t = time.thread_time()
            try:
                return f(*a, **k)
            finally:
                costs.append(time.thread_time() - t)
        return call
    window_cls._redraw = timed(window_cls._redraw)
    ServerLink.drain = timed(ServerLink.drain)
    return costs


def _run_delay_s() -> float:
    """Seconds this (GUI) thread has spent runnable but waiting for a CPU, from the
    scheduler's own count (``/proc/thread-self/schedstat``, second field, ns; Linux; NaN
    elsewhere): the part of a late heartbeat that is scheduling, not the window's work."""
    try:
        with open("/proc/thread-self/schedstat", encoding="ascii") as f:
            return int(f.read().split()[1]) * 1e-9
    except (OSError, IndexError, ValueError):
        return float("nan")


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (``/proc/PID/stat``; Linux;
    NaN elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def bench_scan_client(app: QApplication, work: Path, n_points: int, *,
                      stalls: bool = False, nice: int) -> dict:
    """The scan in a server process, watched and driven from the client window;
    ``stalls``: also sample where the GUI thread is when its heartbeat is late
    (:mod:`benchmarks.gui_stalls`)."""
    import subprocess

    from benchmarks.gui_stalls import StallSampler
    from gui.qt.client_window import ClientWindow

    busy = _gui_thread_costs(ClientWindow)
    child = subprocess.Popen([sys.executable, __file__, "--serve-ideal", str(work / "srv"),
                              "--server-nice", str(nice)],
                             stdout=subprocess.PIPE, text=True, cwd=ROOT,
                             process_group=0)  # as instrument.client.local starts it
    try:
        url = child.stdout.readline().split()[-1]
        window = ClientWindow(url)
        window.show()
        spin(app, lambda: window.state.stream_up, 60)
        window.add_plan_text(scan_plan(n_points))
        # the window is ready when its controls follow the key's role (its first redraw
        # builds the run browser, a one-off start-up cost that is not the scan's)
        spin(app, window.start_queue_button.isEnabled, 60)
        hb = Heartbeat()
        hb.start()
        sampler = StallSampler(hb.t) if stalls else None
        if sampler is not None:
            sampler.start()
        t0 = time.perf_counter()
        wait0, server_cpu0 = _run_delay_s(), _cpu_s(child.pid)
        window.start_queue_button.click()
        spin(app, lambda: window.state.run is not None and window.state.run.live is not None,
             120)
        passes: list[float] = []
        spin(app, lambda: window.state.run.state == "finished"
             and window.state.run.live.n_received >= window.state.run.n_done, 3600, passes)
        elapsed = time.perf_counter() - t0
        gui_wait, server_cpu = _run_delay_s() - wait0, _cpu_s(child.pid) - server_cpu0
        spin(app, lambda: window.plot.n_plotted >= window.state.run.n_done, 30)
        out = hb.stop(settle_s=0.5)
        if sampler is not None:
            sampler.stop()
            out["stalls"] = sampler.report()
        run = window.state.run
        out.update(points=run.n_done, status=run.state, seconds=elapsed,
                   plotted=window.plot.n_plotted, drains=window.link.n_drains,
                   slot_max_ms=1e3 * max(busy), slot_total_s=sum(busy),
                   slot_p99_ms=1e3 * float(np.percentile(busy, 99)), slots=len(busy),
                   pass_p99_ms=1e3 * float(np.percentile(passes, 99)),
                   pass_max_ms=1e3 * max(passes), pass_total_s=sum(passes),
                   gui_wait_s=gui_wait, server_cpu_s=server_cpu, nice=nice)
        window.close()
        window.deleteLater()
        app.processEvents()
        return out
    finally:
        child.kill()
        child.wait(60)


def bench_fit(app: QApplication, work: Path) -> dict:
    from tests.instrument.sim_scan import SAMPLES, ScanSetup, render, write_run_file

    runs = work / "fit_runs"
    runs.mkdir()
    path = write_run_file(render(ScanSetup(), SAMPLES[1]), 3, runs / "glossy.h5")
    from instrument.run.runfile import read_run

    data = read_run(path)
    with Catalog(runs) as cat:
        cat.add(RunRow(data.run_id, data.sample_name, data.plan_kind, data.plan_name, "sim",
                       "finished", time.time(), time.time(), data.n_points, data.n_points,
                       str(path)))
    window = create_window(bench="sim", out=runs,
                           settings=QSettings(str(work / "s2.ini"), QSettings.IniFormat),
                           fsync=False)
    window.show()
    browser = window.browser
    spin(app, lambda: bool(browser.rows), 30)
    browser.select(data.run_id)
    spin(app, lambda: browser.details is not None, 30)
    hb = Heartbeat()
    hb.start()
    t0 = time.perf_counter()
    browser.start_analysis("fit")
    spin(app, lambda: browser.outcome is not None and not browser.busy.isVisible(), 600)
    out = hb.stop()
    out.update(seconds=time.perf_counter() - t0, summary=browser.outcome.summary)
    _close(app, window)
    return out


def bench_camera(app: QApplication, work: Path, size: int, seconds: float) -> dict:
    text = load_profile("sim").source_text.replace(
        "simcam://camera?world=sim&seed=1", f"simcam://camera?world=sim&seed=1&width={size}"
        f"&height={size}")
    path = work / f"sim-{size}.toml"
    path.write_text(parse_profile(text).source_text)
    window = create_window(bench=str(path), out=work / "runs",
                           settings=QSettings(str(work / f"c{size}.ini"), QSettings.IniFormat),
                           fsync=False)
    window.show()
    window.docks["camera"].raise_()
    window.bench_panel.connect_bench()
    spin(app, lambda: window.camera.role == "camera", 30)
    cam = window.camera
    cam.stream.click()
    spin(app, lambda: cam.shown >= 3, 60)
    slot = window.session.frame_slot
    received0, shown0 = slot.received, cam.shown
    hb = Heartbeat()
    hb.start()
    t0 = time.perf_counter()
    spin(app, lambda: time.perf_counter() - t0 > seconds, seconds + 5)
    dt = time.perf_counter() - t0
    out = hb.stop()
    received, shown = slot.received - received0, cam.shown - shown0
    out.update(size=size, camera_fps=received / dt, displayed_fps=shown / dt,
               skipped=slot.skipped,
               dropped=int(window.session.states()["camera"].value("dropped", 0)))
    cam.stream.click()
    _close(app, window)
    return out


def _close(app: QApplication, window) -> None:
    window.confirm_close_during_run(True)
    window.close()
    spin(app, lambda: window.session.run is None, 60)
    window.deleteLater()
    app.processEvents()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--server", action="store_true",
                   help="only the scan, with the engine in a server process")
    p.add_argument("--scan-only", action="store_true",
                   help="only the scan, with the engine in this process (the baseline)")
    p.add_argument("--stalls", action="store_true",
                   help="with --server: where the GUI thread is when its heartbeat is late")
    p.add_argument("--server-nice", type=int, default=LOCAL_NICE, metavar="N",
                   help="with --server: the server process's niceness (default: "
                   f"{LOCAL_NICE}, as the local server of `scatterlab gui`)")
    p.add_argument("--serve-ideal", default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.serve_ideal:
        serve_ideal(args.serve_ideal, args.server_nice)
        return 0
    app = QApplication.instance() or QApplication([])
    work = Path(tempfile.mkdtemp(prefix="bench-gui-"))
    n = 2000 if args.quick else 10_000
    secs = 3.0 if args.quick else 10.0
    if args.server:
        scan = bench_scan_client(app, work, n, stalls=args.stalls, nice=args.server_nice)
        print(f"scan (engine in a server process, GUI a client): {scan['points']} points "
              f"({scan['status']}) in {scan['seconds']:.1f} s "
              f"({scan['points'] / scan['seconds']:.0f} points/s), live plot "
              f"{scan['plotted']} points, {scan['drains']} drains; GUI-thread work per "
              f"redraw or drain ({scan['slots']} calls) p99 {scan['slot_p99_ms']:.1f} ms, "
              f"at most {scan['slot_max_ms']:.1f} ms CPU, "
              f"{scan['slot_total_s']:.2f} s CPU in all; GUI heartbeat worst "
              f"{scan['max_ms']:.1f} ms (after the first 0.5 s: "
              f"{scan['steady_max_ms']:.1f} ms), p99 {scan['p99_ms']:.1f} ms over time "
              f"({scan['beat_p99_ms']:.1f} ms over {scan['beats']} beats); event-loop "
              f"passes (painting included) p99 "
              f"{scan['pass_p99_ms']:.1f} ms, at most {scan['pass_max_ms']:.1f} ms CPU, "
              f"{scan['pass_total_s']:.2f} s CPU in all; GUI thread waited "
              f"{scan['gui_wait_s']:.2f} s for a CPU; server (niceness +{scan['nice']}) "
              f"{scan['server_cpu_s']:.1f} s CPU")
        if args.stalls:
            print(scan["stalls"])
        return 0
    scan = bench_scan(app, work, n)
    print(f"scan: {scan['points']} points ({scan['status']}) in {scan['seconds']:.1f} s "
          f"({scan['points'] / scan['seconds']:.0f} points/s), live plot {scan['plotted']} "
          f"points; GUI heartbeat worst {scan['max_ms']:.1f} ms (after the first 0.5 s: "
          f"{scan['steady_max_ms']:.1f} ms), p99 {scan['p99_ms']:.1f} ms over time "
          f"({scan['beats']} beats)")
    if args.scan_only:
        return 0
    fit = bench_fit(app, work)
    print(f"fit: {fit['seconds']:.1f} s ({fit['summary']}); GUI heartbeat worst "
          f"{fit['max_ms']:.1f} ms, p99 {fit['p99_ms']:.1f} ms")
    for size in (1024, 2048):
        c = bench_camera(app, work, size, secs)
        print(f"camera {size}²: camera {c['camera_fps']:.1f} frames/s, displayed "
              f"{c['displayed_fps']:.1f} frames/s (skipped {c['skipped']}, ring dropped "
              f"{c['dropped']}); GUI heartbeat worst {c['max_ms']:.1f} ms, p99 "
              f"{c['p99_ms']:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
