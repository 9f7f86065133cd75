"""The camera view under a streaming simulated camera."""

from __future__ import annotations

import numpy as np
import pytest

from gui.model.session import SetSetting
from tests.gui.conftest import connect


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    import os

    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def _streaming(qtbot, w):
    cam = w.camera
    qtbot.waitUntil(lambda: cam.role == "camera", timeout=60000)
    cam.stream.click()
    qtbot.waitUntil(lambda: cam.shown >= 3, timeout=60000)
    return cam


def test_five_seconds_of_streaming_grow_nothing_without_bound(qtbot, make_window,
                                                              fast_bench_file):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    w.docks["camera"].raise_()
    cam = _streaming(qtbot, w)
    camera = w.session._bench.camera
    qtbot.wait(1000)
    rss0, shown0, received0 = _rss_mb(), cam.shown, cam.slot.received
    # Stream until 40 frames have reached the display's slot and more than 10 are shown:
    # counted in frames, not seconds, so a loaded machine (fewer frames a second) streams
    # longer instead of failing. 40 frames of 1024² pixels queued would be > 80 MB.
    qtbot.waitUntil(lambda: cam.slot.received - received0 >= 40 and cam.shown - shown0 > 10,
                    timeout=120_000)
    rss1 = _rss_mb()
    shown, received = cam.shown - shown0, cam.slot.received - received0
    # the two counters are read one after the other: a frame may arrive in between
    assert shown > 10 and received >= shown - 1
    # what the display skipped is counted, not queued: the slot holds one frame
    received, taken, skipped, waiting = cam.slot.counts()
    assert received == taken + skipped + int(waiting)
    assert camera.buffered_frames <= camera.ring_capacity
    # the frames received, had they been queued, would have grown it by > 80 MB
    assert rss1 - rss0 < 60, f"memory grew {rss1 - rss0:.0f} MB while streaming"
    assert w.camera.last_frame.data.shape == (1024, 1024)
    text = cam.rates.text()
    assert "frames/s" in text and "skipped by the display" in text
    cam.stream.click()
    qtbot.waitUntil(lambda: not w.session.states()["camera"].value("streaming"),
                    timeout=60000)


def test_roi_statistics_saturation_and_snapshot(qtbot, make_window, fast_bench_file,
                                                tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    cam = _streaming(qtbot, w)
    cam.roi.setPos((100, 200))
    cam.roi.setSize((50, 40))
    cam._roi_moved()
    qtbot.waitUntil(lambda: cam.last_frame is not None and cam.last_frame.stats.roi
                    is not None and cam.last_frame.stats.roi.x == 100, timeout=60000)
    f = cam.last_frame
    part = f.data[200:240, 100:150]
    assert f.stats.mean_dn == pytest.approx(part.mean())
    assert f.stats.max_dn == part.max()
    assert f.stats.dn_per_us == pytest.approx(part.mean() / f.exposure_us)
    assert f.stats.saturated_fraction == pytest.approx(np.mean(f.data >= f.saturation_dn))
    assert "DN/µs" in cam.stats.text()
    path = tmp_path / "snap.npy"
    with qtbot.waitSignal(cam.snapshotSaved, timeout=60000):
        cam.save_snapshot(path)
    saved = np.load(path)
    assert saved.shape == (1024, 1024) and saved.dtype == f.data.dtype


def test_a_rejected_exposure_shows_the_drivers_error(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    cam = w.camera
    qtbot.waitUntil(lambda: cam.role == "camera", timeout=60000)
    cam.exposure.setValue(2.0)  # the simulated camera takes 10 µs to 10 s
    cam.set_exposure.click()
    qtbot.waitUntil(lambda: "outside [10 µs, 10 s]" in cam.error.text(), timeout=60000)
    cam.exposure.setValue(2500.0)
    cam.set_exposure.click()
    qtbot.waitUntil(lambda: w.session.states()["camera"].value("exposure_us") == 2500.0,
                    timeout=60000)
    # The state poll can show the new exposure before the command's own result reaches the
    # view; the error clears when that result arrives, so wait for it rather than race it.
    qtbot.waitUntil(lambda: cam.error.text() == "", timeout=60000)
    assert w.session.states()["camera"].value("exposure_us") == 2500.0


def test_a_refused_exposure_does_not_stay_in_the_field(qtbot, make_window, fast_bench_file):
    """The exposure field shows the camera's setting: a refused value is replaced by the
    value the camera kept, and a setting changed elsewhere is followed."""
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    cam = w.camera
    qtbot.waitUntil(lambda: cam.role == "camera", timeout=60000)
    kept = w.session.states()["camera"].value("exposure_us")
    qtbot.waitUntil(lambda: cam.exposure.value() == kept, timeout=60000)
    cam.exposure.setValue(99999999.0)  # typed: pending until its result
    assert cam.exposure_field.pending
    cam.set_exposure.click()
    qtbot.waitUntil(lambda: "100 s outside [10 µs, 10 s]" in cam.error.text(), timeout=60000)
    qtbot.waitUntil(lambda: cam.exposure.value() == kept, timeout=60000)
    assert not cam.exposure_field.pending
    # a new setting (from the session, as a run or another control would) is shown
    w.session.submit(SetSetting("camera", "exposure_us", 4321.0))
    qtbot.waitUntil(lambda: cam.exposure.value() == 4321.0, timeout=60000)
