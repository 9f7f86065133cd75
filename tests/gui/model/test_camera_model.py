"""The camera data path without Qt: newest-frame slot, statistics, rates, pump."""

from __future__ import annotations

import numpy as np
import pytest

from gui.model.camera import FramePump, FrameSlot, RateMeter, RoiBox, frame_stats, save_frame
from hw_mocks.sim.ideal import IdealCamera
from tests.waiting import wait_for


def test_stats_over_the_roi_and_the_saturation_mask():
    data = np.arange(100, dtype=np.uint16).reshape(10, 10)
    stats, mask = frame_stats(data, 50.0, 95.0, RoiBox(2, 3, 4, 2))
    part = data[3:5, 2:6]
    assert stats.mean_dn == pytest.approx(part.mean()) and stats.max_dn == part.max()
    assert stats.dn_per_us == pytest.approx(part.mean() / 50.0)
    assert stats.saturated_fraction == pytest.approx(0.05) and mask.sum() == 5
    assert RoiBox(8, 8, 10, 10).clipped((10, 10)) == RoiBox(8, 8, 2, 2)
    assert RoiBox(20, 0, 5, 5).clipped((10, 10)) is None
    whole, _ = frame_stats(data, 50.0, 1e9, RoiBox(20, 0, 5, 5))
    assert whole.roi is None and whole.mean_dn == pytest.approx(data.mean())


def test_the_slot_keeps_the_newest_frame_and_counts_the_skipped():
    slot = FrameSlot()
    for k in range(5):
        slot.put_array(np.full((4, 4), k, np.uint16), exposure_us=10, saturation_dn=4095,
                       index=k, compute=k % 2 == 0)
    frame = slot.take()
    assert frame.index == 4 and frame.stats.mean_dn == 4.0
    assert slot.take() is None
    assert slot.counts() == (5, 1, 4, False)
    slot.put_array(np.zeros((4, 4)), exposure_us=10, saturation_dn=1, index=5, compute=False)
    assert slot.take().stats.saturated_fraction == 0.0


def test_rate_meter_counts_over_its_window():
    now = [0.0]
    meter = RateMeter(2.0, clock=lambda: now[0])
    for _ in range(21):
        meter.tick()
        now[0] += 0.1
    assert meter.rate() == pytest.approx(10.0, rel=0.06)
    now[0] += 5
    assert meter.rate() == 0.0


def test_the_pump_drains_a_streaming_camera_into_the_slot():
    cam = IdealCamera("camera", shape=(16, 16))
    slot = FrameSlot()
    errors = []
    pump = FramePump(cam, slot, on_error=errors.append)
    cam.start_streaming()
    pump.start()
    wait_for(lambda: slot.received > 20, 60, "frames")
    cam.stop_streaming()
    pump.stop()
    assert not pump.alive and not errors
    assert slot.latest().stats.mean_dn == pytest.approx(1010.0)
    assert cam.buffered_frames <= cam.ring_capacity


def test_save_frame_formats(tmp_path):
    data = (np.arange(64, dtype=np.uint16) * 1000).reshape(8, 8)
    assert np.array_equal(np.load(save_frame(data, tmp_path / "a.npy")), data)
    import cv2

    png = cv2.imread(str(save_frame(data, tmp_path / "a.png")), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(png, data)
    with pytest.raises(OSError, match=r"use a \.png"):
        save_frame(data, tmp_path / "a.jpg")
