"""The neutral-density filter in use, shown during a run: the bench dock's wheel panel says
which filter is in the beam (the engine's own read-back of the wheel, ADR 0062, no device
call while the engine owns the bench) and the live plot marks the points read through a
filter (ADR 0018). On the emulated bench with the sharp sample, whose peak clips the camera
at its shortest exposure, so the engine reads it behind ND1 (slot 2)."""

from __future__ import annotations

import re

import numpy as np

from gui.model.live import LiveData, signed_theta_r
from gui.qt.live_plot import LivePlot
from instrument.run.events import PointCompleted
from tests.gui.conftest import connect
from tests.gui.helpers import fast_profile
from tests.gui.test_run_control import wait_end

# far from the peak first, then only points on it: once the engine has turned to ND1 it
# stays there for the rest of the run, so a pause after any filtered point finds slot 2 in
# the beam, and there is always a later filtered point to pause at
PLAN = """
[plan]
kind = "brdf_in_plane"
name = "peak behind ND1"
order = "raster"
[sample]
name = "sharp"
[scan]
skip_beam_points = true
theta_i = [20]
theta_r = [-40, -20, 0, 10, 19, 19.5, 20, 20.5, 21, 21.5]
[acquisition]
mode = "auto"
exposure_us = 2000
min_exposure_us = 10
max_exposure_us = 200000
detectors = ["camera"]
"""


def _sharp_bench(tmp_path) -> str:
    text = fast_profile("sim").source_text
    text = text.replace('"lambert.rho" = 0.5, "ggx.ks" = 0.2, "ggx.alpha" = 0.2',
                        '"lambert.rho" = 0.3, "ggx.ks" = 0.5, "ggx.alpha" = 0.05')
    text = text.replace("simcam://camera?world=sim&seed=1",
                        "simcam://camera?world=sim&seed=1&width=128&height=128")
    assert '"ggx.alpha" = 0.05' in text and "width=128" in text
    path = tmp_path / "sharp-fast.toml"
    path.write_text(text, encoding="utf-8")
    return str(path)


def test_the_dock_shows_the_nd_filter_in_the_beam_and_the_plot_marks_its_points(
        qtbot, make_window, tmp_path):
    w = make_window(_sharp_bench(tmp_path))
    connect(qtbot, w)
    wheel = w.bench_panel.panels["filter_wheel"]
    # its slots as the profile describes them: the open one and three ND filters
    qtbot.waitUntil(lambda: wheel.slot.count() == 6, timeout=60000)
    assert [wheel.slot.itemText(k) for k in range(4)] == [
        "slot 1: empty", "slot 2: ND, OD 1 (ND1)", "slot 3: ND, OD 2 (ND2)",
        "slot 4: ND, OD 3 (ND3)"]
    plan = tmp_path / "peak.toml"
    plan.write_text(PLAN, encoding="utf-8")
    assert w.plan_editor.open_plan(plan)
    qtbot.waitUntil(w.plan_editor.start.isEnabled, timeout=60000)
    w.plan_editor.start.click()
    qtbot.waitUntil(lambda: w.session.run is not None, timeout=60000)
    run = w.session.run
    engine = run.engine
    # hold the run at a point boundary, then pause it again after its first filtered point
    engine.pause()
    qtbot.waitUntil(lambda: engine.state.value == "paused", timeout=60000)
    engine.subscribe(lambda ev: engine.pause() if isinstance(ev, PointCompleted)
                     and ev.nd_slot >= 0 else None)
    if not (run.live.snapshot().nd_slot >= 0).any():
        engine.resume()
        qtbot.waitUntil(lambda: engine.state.value == "paused"
                        and (run.live.snapshot().nd_slot >= 0).any(), timeout=120000)
    # the dock: ND1 in the beam, as the engine read or set it
    role, slot, _t = engine.wheel_readback()
    assert (role, slot) == ("filter_wheel", 2)
    qtbot.waitUntil(lambda: wheel.position.text() == "slot 2: ND, OD 1 (ND1)",
                    timeout=60000)
    # the panel's state is the engine's read-back (not an older device poll); its time
    # is not compared: the engine may read the wheel again before the panel is looked at
    assert w.session.states()["filter_wheel"].values["position"] == slot
    # the live plot: the filtered points marked, said in the legend and the caption
    snap = run.live.snapshot()
    behind = int((snap.nd_slot == 2).sum())
    far = np.abs(signed_theta_r(snap.theta_r, snap.phi_i, snap.phi_r) - 20.0) > 5.0
    assert behind >= 1 and far.any() and (snap.nd_slot[far] == -1).all()  # open beam
    plot = w.live_plot
    qtbot.waitUntil(lambda: plot.n_nd >= behind, timeout=60000)
    assert "□ read through an ND filter" in plot.in_plane_legend.text()
    assert re.search(r"\d+ read through an ND filter \(slot 2\)", plot.caption.text())
    engine.abort()
    wait_end(qtbot, w)


def test_the_live_plot_marks_points_read_through_a_filter(qtbot):
    plot = LivePlot()
    qtbot.addWidget(plot)
    plot.start("brdf_in_plane")
    angles = np.array([(20.0, 0.0, t, 180.0) for t in (0.0, 10.0, 20.0, 30.0)])
    live = LiveData("brdf_in_plane", 4, planned_angles=angles)
    for k, nd in enumerate((-1, 2, 2, -1)):
        live.on_event(PointCompleted(k, "", "ok", {}, tuple(angles[k]), 10.0, float("nan"),
                                     1e-2 * (k + 1), 0, nd_slot=nd))
    plot.update_from(live.snapshot())
    assert plot.n_plotted == 4 and plot.n_nd == 2
    x, y = plot.nd_points.getData()
    assert list(x) == [10.0, 20.0] and np.allclose(y, np.log10([2e-2, 3e-2]))  # log axis
    assert "2 read through an ND filter (slot 2)" in plot.caption.text()
    assert "□ read through an ND filter" in plot.in_plane_legend.text()
    # a new run starts with no marks
    plot.start("brdf_in_plane")
    assert plot.n_nd == 0 and "ND filter" not in plot.in_plane_legend.text()
