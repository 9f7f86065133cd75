"""The dashboard over an 8-hour run: the browser's memory and the cost of a redraw.

A real server (``scatterlab serve --bench sim``, idle) serves the page to a headless
Chromium (Debian's ``chromium``, driven by Playwright). The run's messages are fed to the
page's own handler (``handle``), as the event stream delivers them: the server sends at
most 10 ``points`` messages a second, so 8 hours are 288,000 messages; here each carries
``--per-message`` points (default 10: a 100-point/s scan, faster than any run of the sim
bench). After each simulated hour: the JavaScript heap after a full garbage collection
(``performance.memory.usedJSHeapSize``; ``--js-flags=--expose-gc``), the points the plot
keeps, and the time of one redraw (``Plot.draw()`` then ``render()``, median of 5).

    .venv/bin/python benchmarks/bench_dashboard.py            # 8 hours
    .venv/bin/python benchmarks/bench_dashboard.py --hours 1  # quicker
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from instrument.server.dashboard.chromium import (  # noqa: E402
    browser,
    chromium_missing,
    sign_in,
)
from instrument.server.dashboard.screenshots import serve_sim  # noqa: E402

MESSAGES_PER_HOUR = 10 * 3600

FEED_HOUR = """([hour, perMessage, perHour]) => {
    if (hour === 0) handle({type: 'run_started', data: {n_total: 8 * perHour * perMessage,
        n_done: 0, estimated_s: 28800, path: '/runs/long.h5', item_id: 1,
        plan_kind: 'brdf_in_plane'}});
    let i = hour * perHour * perMessage;
    const t0 = performance.now();
    for (let m = 0; m < perHour; m++) {
        const items = [];
        for (let k = 0; k < perMessage; k++, i++) {
            const tr = -80 + 160 * ((i * 7919) % 100003) / 100003;
            items.push({index: i, label: 'p' + i, status: 'ok', positions: {},
                        angles: [20 + 5 * (i % 3), 0, tr, 180], exposure_us: 1000,
                        power_w: null, signal: 1 + Math.cos(tr / 60), retries: 0});
        }
        handle({type: 'points', data: {items}});
        if (m % 10 === 0) handle({type: 'progress', data: {n_done: i, n_total: 1e9,
                                   elapsed_s: m / 10, eta_s: 100}});
    }
    return performance.now() - t0;
}"""

MEASURE = """() => {
    gc(); gc();
    const times = [];
    for (let r = 0; r < 5; r++) {
        Plot.version += 1; S.dirty = true;
        const t0 = performance.now();
        Plot.draw(); render();
        times.push(performance.now() - t0);
    }
    times.sort((a, b) => a - b);
    gc();
    return {heap_mb: performance.memory.usedJSHeapSize / 2 ** 20, kept: Plot.kept.length,
            stride: Plot.stride, log: S.log.length, redraw_ms: times[2]};
}"""


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--hours", type=int, default=8)
    p.add_argument("--per-message", type=int, default=10)
    args = p.parse_args()
    if (why := chromium_missing()) is not None:
        print(why, file=sys.stderr)
        return 1
    work = Path(tempfile.mkdtemp(prefix="bench-dashboard-"))
    proc, url = serve_sim(work / "runs")
    rows = []
    try:
        with browser() as new_page:
            page = new_page(work / "profile", args=("--js-flags=--expose-gc",
                                                    "--enable-precise-memory-info"))
            sign_in(page, url, None)
            base = page.evaluate(MEASURE)
            print(f"page loaded, signed in: heap {base['heap_mb']:.1f} MiB")
            print("hour  points fed   feed ms/msg  heap MiB  plot keeps  stride  redraw ms")
            for hour in range(args.hours):
                feed_ms = page.evaluate(FEED_HOUR, [hour, args.per_message,
                                                    MESSAGES_PER_HOUR])
                m = page.evaluate(MEASURE)
                fed = (hour + 1) * MESSAGES_PER_HOUR * args.per_message
                rows.append({"hour": hour + 1, "points": fed,
                             "feed_ms_per_message": feed_ms / MESSAGES_PER_HOUR, **m})
                print(f"{hour + 1:>4}  {fed:>10,}  {feed_ms / MESSAGES_PER_HOUR:>11.4f}  "
                      f"{m['heap_mb']:>8.1f}  {m['kept']:>10}  {m['stride']:>6}  "
                      f"{m['redraw_ms']:>9.1f}")
            assert page.errors == [], page.errors
    finally:
        proc.terminate()
        proc.wait(120)
    print(json.dumps({"baseline_heap_mb": base["heap_mb"], "hours": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
