"""The camera contract: what every :class:`drivers.base.Camera` implementation must do.

A driver's test module subclasses :class:`CameraContract` and provides a fixture
``camera_factory`` returning a *callable* that opens a fresh camera (closed by the fixture
afterwards). The source behind it must deliver at least 100 frames; the suite keeps frames
small and never waits on real exposures longer than a few milliseconds.

Two checks need the test to act on what is in front of the camera, which only the driver's
own test module knows how to do; it overrides :meth:`CameraContract.change_scene` (the
simulated camera turns its light off, the emulated Basler switches its test image) and
:meth:`CameraContract.stop_frames` (no trigger pulse, a recording played to its end).
Where a source offers neither, the check is skipped with the reason.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.base import Camera, PixelFormat, Roi
from drivers.errors import DeviceTimeout, StateError, UnsupportedFeature


def closing_factory(make):
    """A ``camera_factory`` fixture body: ``make`` wrapped so that every camera it opened is
    closed at teardown (``yield from closing_factory(make)``)."""
    opened = []

    def factory():
        cam = make()
        opened.append(cam)
        return cam

    yield factory
    for cam in opened:
        cam.close()


class CameraContract:
    """Mixin of contract tests; needs a ``camera_factory`` fixture.

    Set ``finite_source = True`` for recordings (image sequences, video files), which a
    stream may exhaust.
    """

    finite_source = False

    def change_scene(self, camera: Camera) -> None:
        """Change what ``camera`` sees, so that its next frames differ in their mean."""
        pytest.skip("this source has no scene the test can change")

    def stop_frames(self, camera: Camera) -> None:
        """Put ``camera`` in a state in which no frame comes (no trigger pulse, the end of
        a recording)."""
        pytest.skip("this source cannot be made to stop delivering frames")

    @pytest.fixture
    def camera(self, camera_factory) -> Camera:
        cam = camera_factory()
        yield cam
        cam.close()

    # identity and geometry -------------------------------------------------------------
    def test_identity_and_sensor_shape(self, camera):
        ident = camera.identity
        assert ident.vendor and ident.model and ident.serial
        height, width = camera.sensor_shape
        assert height >= 1 and width >= 1
        roi = camera.roi
        assert roi.x + roi.width <= width and roi.y + roi.height <= height
        assert isinstance(camera.pixel_format, PixelFormat)
        assert camera.bit_depth == camera.pixel_format.bit_depth

    # acquisition ------------------------------------------------------------------------
    def test_acquire_returns_consistent_frames(self, camera):
        frames = camera.acquire(3)
        assert len(frames) == 3
        roi, b, fmt = camera.roi, camera.binning, camera.pixel_format
        for f in frames:
            assert f.data.shape == (roi.height // b, roi.width // b)
            assert f.data.dtype == fmt.dtype
            assert f.bit_depth == fmt.bit_depth
            assert f.roi == roi and f.binning == b
            assert 0 < f.saturation_dn <= 2**f.bit_depth - 1
            assert int(f.data.max()) <= 2**f.bit_depth - 1
        idx = [f.index for f in frames]
        assert idx == sorted(idx) and len(set(idx)) == 3
        stamps = [f.timestamp for f in frames]
        assert stamps == sorted(stamps)
        assert abs(stamps[-1] - time.time()) < 60.0

    @pytest.mark.parametrize("n", [0, -1, 1.5])
    def test_acquire_rejects_bad_counts(self, camera, n):
        with pytest.raises(ValueError):
            camera.acquire(n)

    # settings are honoured or refused, never ignored ------------------------------------
    def test_exposure_is_honoured_or_refused(self, camera):
        low, high = camera.exposure_range_us
        target = float(min(max(2000.0, low), high))
        try:
            camera.exposure_us = target
        except UnsupportedFeature:
            return
        assert camera.exposure_us == pytest.approx(target, rel=0.01)
        assert camera.acquire(1)[0].exposure_us == pytest.approx(target, rel=0.01)

    def test_gain_is_honoured_or_refused(self, camera):
        low, high = camera.gain_range
        target = 0.5 * (low + high)
        try:
            camera.gain = target
        except UnsupportedFeature:
            return
        assert camera.gain == pytest.approx(target, rel=0.01, abs=1e-9)
        assert camera.acquire(1)[0].gain == pytest.approx(target, rel=0.01, abs=1e-9)

    def test_out_of_range_settings_raise_before_anything_changes(self, camera):
        _low, high = camera.exposure_range_us
        before = camera.exposure_us
        with pytest.raises(ValueError):
            camera.exposure_us = high * 10.0 + 1.0
        with pytest.raises(ValueError):
            camera.exposure_us = float("nan")
        assert camera.exposure_us == before or (np.isnan(before) and np.isnan(camera.exposure_us))
        height, width = camera.sensor_shape
        with pytest.raises(ValueError):
            camera.roi = Roi(0, 0, width + 1, height)
        with pytest.raises(ValueError):
            camera.binning = 0
        with pytest.raises(TypeError):
            camera.pixel_format = "MONO8"

    def test_roi_is_honoured_or_refused(self, camera):
        height, width = camera.sensor_shape
        roi = Roi(width // 4, height // 4, max(width // 2, 1), max(height // 2, 1))
        try:
            camera.roi = roi
        except UnsupportedFeature:
            return
        assert camera.roi == roi
        frame = camera.acquire(1)[0]
        assert frame.data.shape == (roi.height, roi.width)
        assert frame.roi == roi

    def test_pixel_format_is_honoured_or_refused(self, camera):
        for fmt in PixelFormat:
            try:
                camera.pixel_format = fmt
            except UnsupportedFeature:
                continue
            assert camera.pixel_format is fmt
            frame = camera.acquire(1)[0]
            assert frame.data.dtype == fmt.dtype and frame.bit_depth == fmt.bit_depth

    # trigger, invalidate ------------------------------------------------------------------
    def test_software_trigger_or_refusal(self, camera):
        try:
            camera.trigger()
        except UnsupportedFeature:
            return
        after_trigger = time.time()
        frame = camera.acquire(1)[0]
        assert frame.timestamp <= after_trigger  # the exposure the trigger started
        camera.trigger()
        camera.invalidate()  # discards the triggered frame; acquiring still works
        assert camera.acquire(1)[0].timestamp > after_trigger

    def test_frames_change_when_the_scene_changes(self, camera):
        """A new scene reaches the next frame: its mean moves by far more than between two
        frames of the unchanged scene (noise, or a moving test pattern)."""
        a1, a2 = (f.data.astype(np.float64).mean() for f in camera.acquire(2))
        self.change_scene(camera)
        camera.invalidate()
        b = camera.acquire(1)[0].data.astype(np.float64).mean()
        assert abs(b - a1) > 10.0 * abs(a2 - a1) and b != a1

    def test_no_frame_within_the_timeout_is_a_device_timeout(self, camera):
        self.stop_frames(camera)
        with pytest.raises(DeviceTimeout) as err:
            camera.acquire(1, timeout=0.3)
        assert err.value.device == camera.name

    # streaming ----------------------------------------------------------------------------
    def test_streaming_fills_a_bounded_ring_and_counts_drops(self, camera):
        camera.start_streaming()
        try:
            first = camera.next_frame(timeout=60.0)
            assert first.data.size > 0
            with pytest.raises(StateError):
                camera.acquire(1)
            deadline = time.monotonic() + 120.0  # returns as soon as it happened
            while camera.dropped_frames == 0 and time.monotonic() < deadline:
                time.sleep(0.02)
            assert camera.dropped_frames > 0  # nobody read: the oldest frames went
            second = camera.next_frame(timeout=60.0)
            assert second.index > first.index
        finally:
            camera.stop_streaming()
        assert not camera.is_streaming
        try:
            assert camera.acquire(1)[0].data.size > 0
        except DeviceTimeout:
            if not self.finite_source:
                raise  # only a recording may have run out of frames

    def test_streaming_ring_accounts_for_every_frame(self, camera):
        """Every frame the stream produced was delivered, is still buffered, or was counted
        as dropped; the buffer never holds more than its capacity."""
        if self.finite_source:
            pytest.skip("a recording may end mid-stream; the count needs an endless source")
        before = camera.acquire(1)[0].index  # stream frames are numbered after this one
        capacity = camera.ring_capacity
        camera.start_streaming()
        try:
            delivered = [camera.next_frame(timeout=60.0)]
            deadline = time.monotonic() + 120.0  # returns as soon as it happened
            while camera.dropped_frames < 3 * capacity and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            camera.stop_streaming()
        assert camera.buffered_frames <= capacity
        while camera.buffered_frames:
            delivered.append(camera.next_frame(timeout=60.0))
        indices = [f.index for f in delivered]
        assert indices == sorted(indices) and len(set(indices)) == len(indices)
        produced = indices[-1] - before
        assert camera.dropped_frames >= 3 * capacity
        assert camera.dropped_frames == produced - len(delivered)

    def test_streamed_frames_after_a_settings_change_have_the_new_settings(self, camera):
        """The stale-frame policy holds while streaming: a frame exposed before a settings
        change never reaches the consumer after it."""
        if self.finite_source:
            pytest.skip("a recording may end mid-stream")
        height, width = camera.sensor_shape
        rois = [Roi(0, 0, width, height), Roi(0, 0, max(width // 2, 1), max(height // 2, 1))]
        try:
            camera.roi = rois[1]
        except UnsupportedFeature:
            pytest.skip("the camera has no ROI to change")
        camera.start_streaming()
        try:
            for k in range(30):
                camera.roi = rois[k % 2]
                frame = camera.next_frame(timeout=60.0)
                assert frame.roi == rois[k % 2], f"stale frame after change {k}"
        finally:
            camera.stop_streaming()

    def test_next_frame_times_out_when_not_streaming(self, camera):
        with pytest.raises(DeviceTimeout):
            camera.next_frame(timeout=0.05)

    # lifecycle -------------------------------------------------------------------------
    def test_close_is_idempotent_and_final(self, camera_factory):
        cam = camera_factory()
        with cam:
            cam.acquire(1)
        assert cam.closed
        cam.close()
        with pytest.raises(StateError):
            cam.acquire(1)
        with pytest.raises(StateError):
            _ = cam.exposure_us
        with pytest.raises(StateError):
            cam.exposure_us = 1000.0
