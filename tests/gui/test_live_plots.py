"""Live plots of the other plan kinds: the light field grows row by row; the hemisphere
map fills with directions."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from instrument.run.runfile import read_run
from tests.gui.conftest import connect
from tests.gui.test_run_control import wait_end

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

HEMISPHERE = """
[plan]
kind = "brdf_hemisphere"
name = "small hemisphere"
[sample]
name = "hemi"
[scan]
theta_i = [30.0]
n_directions = 8
theta_max_deg = 60.0
skip_beam_points = true
[acquisition]
mode = "fixed"
exposure_us = 1000
detectors = ["camera"]
"""


def _run_plan(qtbot, w, path):
    editor = w.plan_editor
    assert editor.open_plan(path)
    qtbot.waitUntil(editor.start.isEnabled, timeout=60000)
    editor.start.click()
    qtbot.waitUntil(lambda: w.current_run is not None, timeout=60000)
    return w.current_run, wait_end(qtbot, w, timeout=120000)


def test_the_light_field_image_grows_row_by_row(qtbot, make_window, fast_bench_file,
                                                tmp_path):
    w = make_window(fast_bench_file("sim-lightfield"))
    connect(qtbot, w)
    text = (EXAMPLES / "lightfield_scan.toml").read_text().replace(
        "start = -50.0, stop = 50.0, step = 1.0", "start = -20.0, stop = 20.0, step = 2.0")
    plan = tmp_path / "lf.toml"
    plan.write_text(text)
    run, ev = _run_plan(qtbot, w, plan)
    assert ev.status == "finished"
    data = read_run(run.path)
    light = int((data.label == "lightfield").sum())
    assert light == 21
    qtbot.waitUntil(lambda: w.live_plot.n_plotted == light, timeout=60000)
    assert w.live_plot.kind == "lightfield"
    img = w.live_plot.field_image.image
    assert img.shape == (len(run.plan.points), 1024)
    snap = run.live.snapshot()
    order = np.argsort(np.where(np.isfinite(snap.field_y), snap.field_y, np.inf))
    assert np.all(np.diff(snap.field_y[order][:light]) > 0)  # rows in camera_z order


def test_the_hemisphere_map_fills(qtbot, make_window, fast_bench_file, tmp_path):
    w = make_window(fast_bench_file("sim_out_of_plane"))
    connect(qtbot, w)
    plan = tmp_path / "hemi.toml"
    plan.write_text(HEMISPHERE)
    run, ev = _run_plan(qtbot, w, plan)
    assert ev.status == "finished"
    qtbot.waitUntil(lambda: w.live_plot.n_plotted == ev.n_done, timeout=60000)
    assert w.live_plot.kind == "hemisphere"
    x, y = w.live_plot.polar_points.getData()
    theta = np.hypot(x, y)
    data = read_run(run.path)
    assert np.allclose(np.sort(theta), np.sort(data.theta_r), atol=1e-3)


def test_in_plane_legend_beside_the_data_and_log_labels_with_decades(qtbot):
    from gui.model.live import LiveData
    from gui.qt.live_plot import LivePlot
    from instrument.run.events import PointCompleted

    plot = LivePlot()
    qtbot.addWidget(plot)
    plot.resize(800, 500)
    plot.show()
    plot.start("brdf_in_plane")
    axis = plot.in_plane.getAxis("left")
    # empty: the labels still name a decade (not a bare 2 … 9)
    vb = plot.in_plane.getViewBox()
    lo, hi = vb.viewRange()[1]
    labels = axis.tickStrings([v for _, vs in axis.tickValues(lo, hi, 400) for v in vs],
                              1.0, 1.0)
    assert labels and all("10" in t for t in labels)
    angles = np.array([(20.0 if k < 10 else 40.0, 180.0, -60 + 10 * (k % 10), 0.0)
                       for k in range(20)])
    live = LiveData("brdf_in_plane", 20, planned_angles=angles)
    for k in range(20):
        live.on_event(PointCompleted(k, "", "ok", {}, tuple(angles[k]), 1000.0,
                                     float("nan"), 2e-3 * (1 + k % 10), 0))
    plot.update_from(live.snapshot())
    assert plot.n_plotted == 20 and len(plot._curves) == 2
    # the legend is beside the plot, never over its data
    legend = plot.in_plane_legend
    assert "θi = -20°" in legend.text() and "θi = -40°" in legend.text()  # φi = 180°
    qtbot.waitUntil(lambda: legend.isVisible() and legend.width() > 0, timeout=60000)
    assert legend.geometry().left() >= plot.in_plane.geometry().right()
    qtbot.waitUntil(lambda: vb.viewRange()[1][1] < -1.0, timeout=60000)  # auto-ranged
    lo, hi = vb.viewRange()[1]  # 2e-3 … 2e-2: about one decade
    labels = axis.tickStrings([v for _, vs in axis.tickValues(lo, hi, 400) for v in vs],
                              1.0, 1.0)
    assert "10⁻²" in labels and all("×10" in t or t.startswith("10") for t in labels)


@pytest.mark.parametrize("n_total", [20, 2000])
def test_a_large_in_plane_plot_is_drawn_thin_without_markers_or_grid(qtbot, n_total):
    """Above MARKERS_UP_TO points the curves are 1-px lines without markers and the plot
    has no grid: what each redraw of a fast scan repaints (BENCHMARKS.md gui)."""
    from gui.model.live import LiveData
    from gui.qt.live_plot import MARKERS_UP_TO, LivePlot
    from instrument.run.events import PointCompleted

    plot = LivePlot()
    qtbot.addWidget(plot)
    plot.start("brdf_in_plane")
    angles = np.array([(20.0, 180.0, -60 + k, 0.0) for k in range(n_total)])
    live = LiveData("brdf_in_plane", n_total, planned_angles=angles)
    for k in range(20):
        live.on_event(PointCompleted(k, "", "ok", {}, tuple(angles[k]), 1000.0,
                                     float("nan"), 2e-3 * (1 + k), 0))
    plot.update_from(live.snapshot())
    (curve,) = plot._curves.values()
    large = n_total > MARKERS_UP_TO
    assert curve.opts["pen"].width() == (1 if large else 2)
    assert (curve.opts["symbol"] is None) == large
    grid = plot.in_plane.getAxis("bottom").grid
    assert (grid is False or grid == 0) == large


def test_a_fast_in_plane_scan_ends_with_every_point_plotted_and_in_view(qtbot):
    """The in-plane view grows only when a point falls outside it (not pyqtgraph's
    auto-range at every redraw, which repaints both axes and every curve): at the end of
    a scan every point is on its curve and inside the view, and the view changed a few
    times, not at every redraw."""
    from gui.model.live import LiveData
    from gui.qt.live_plot import LivePlot
    from instrument.run.events import PointCompleted

    plot = LivePlot()
    qtbot.addWidget(plot)
    plot.resize(800, 500)
    plot.show()
    plot.start("brdf_in_plane")
    vb = plot.in_plane.getViewBox()
    theta_r = np.arange(-85.0, 86.0)
    angles = np.array([(ti, 180.0, tr, 0.0) for ti in (10.0, 30.0, 50.0, 70.0)
                       for tr in theta_r])
    n = len(angles)
    rng = np.random.default_rng(5)
    # a lobe over three decades, with noise: new extremes keep arriving during the scan
    signal = 1e-4 * (1 + 1e3 * np.exp(-((angles[:, 2] - angles[:, 0]) / 8) ** 2)) \
        * rng.uniform(0.8, 1.2, n)
    live = LiveData("brdf_in_plane", n, planned_angles=angles)
    views = []
    for k in range(n):
        live.on_event(PointCompleted(k, "", "ok", {}, tuple(angles[k]), 1000.0,
                                     float("nan"), float(signal[k]), 0))
        if k % 25 == 24 or k == n - 1:  # a redraw every 25 points
            plot.update_from(live.snapshot())
            views.append(plot._view)
    assert plot.n_plotted == n
    assert sum(len(c.getData()[0]) for c in plot._curves.values()) == n
    (x0, x1), (y0, y1) = vb.viewRange()
    assert x0 <= theta_r.min() and theta_r.max() <= x1
    assert y0 <= np.log10(signal.min()) and np.log10(signal.max()) <= y1
    changes = sum(a != b for a, b in itertools.pairwise(views))
    assert changes <= len(views) // 3, (changes, len(views))
    # a new run starts from an empty view again
    plot.start("brdf_in_plane")
    assert plot._view is None and plot.n_plotted == 0
