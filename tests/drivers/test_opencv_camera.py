"""OpenCVCamera through the real cv2.VideoCapture on sources the tests generate: a numbered
16-bit PNG sequence (CAP_IMAGES) and a lossless grey video (FFMPEG, FFV1)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from drivers.base import PixelFormat, Roi
from drivers.errors import ConnectionFailed, DeviceTimeout, UnsupportedFeature
from drivers.opencv_camera import OpenCVCamera
from tests.drivers.camera_contract import CameraContract

H, W = 48, 64
N_FRAMES = 120


def png_value(i: int) -> np.ndarray:
    """Frame i of the sequence: distinct 16-bit values well above 255."""
    base = (np.arange(H * W, dtype=np.uint32).reshape(H, W) * 7 + 300 * i) % 60000
    return (base + 1000).astype(np.uint16)


@pytest.fixture(scope="module")
def png_sequence(tmp_path_factory) -> str:
    folder = tmp_path_factory.mktemp("png16")
    for i in range(N_FRAMES):
        assert cv2.imwrite(str(folder / f"frame_{i:04d}.png"), png_value(i))
    return str(folder / "frame_%04d.png")


@pytest.fixture(scope="module")
def grey_video(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("video") / "grey.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 25.0, (W, H),
                             isColor=False)
    assert writer.isOpened()
    for i in range(N_FRAMES):
        writer.write(np.full((H, W), (2 * i) % 256, np.uint8))
    writer.release()
    return str(path)


def open_png(path: str, **kw) -> OpenCVCamera:
    return OpenCVCamera(path, api_preference=cv2.CAP_IMAGES, **kw)


def play_to_end(camera: OpenCVCamera) -> None:
    """Read a recording until it has no frame left."""
    for _ in range(N_FRAMES + 1):
        try:
            camera.acquire(1)
        except DeviceTimeout:
            return


class TestPngSequenceContract(CameraContract):
    finite_source = True

    def stop_frames(self, camera):
        play_to_end(camera)

    @pytest.fixture
    def camera_factory(self, png_sequence):
        return lambda: open_png(png_sequence, ring_capacity=4)


class TestVideoContract(CameraContract):
    finite_source = True

    def stop_frames(self, camera):
        play_to_end(camera)

    @pytest.fixture
    def camera_factory(self, grey_video):
        return lambda: OpenCVCamera(grey_video, api_preference=cv2.CAP_FFMPEG,
                                    ring_capacity=4)


def test_sixteen_bit_frames_are_kept_exactly(png_sequence):
    with open_png(png_sequence) as cam:
        assert cam.pixel_format is PixelFormat.MONO16
        assert cam.sensor_shape == (H, W)
        frames = cam.acquire(3)
        for i, frame in enumerate(frames):  # the probe at open cost no file frame
            np.testing.assert_array_equal(frame.data, png_value(i))
        assert frames[0].data.max() > 255
        assert frames[0].saturation_dn == 65535
        assert math.isnan(frames[0].exposure_us) and math.isnan(frames[0].gain)
        assert frames[0].metadata["backend"] == "CV_IMAGES"


def test_settings_the_backend_ignores_raise_unsupported(png_sequence):
    with open_png(png_sequence, nominal_exposure_us=2500.0) as cam:
        assert cam.exposure_us == 2500.0  # as recorded, reported per frame
        with pytest.raises(UnsupportedFeature, match="exposure"):
            cam.exposure_us = 1000.0
        assert cam.exposure_us == 2500.0
        with pytest.raises(UnsupportedFeature):
            cam.gain = 0.0
        with pytest.raises(UnsupportedFeature):
            cam.pixel_format = PixelFormat.MONO8
        with pytest.raises(UnsupportedFeature):
            cam.binning = 2
        assert cam.acquire(1)[0].exposure_us == 2500.0


def test_stale_frames_are_discarded_after_changes(png_sequence):
    with open_png(png_sequence, stale_frames=3) as cam:
        assert cam.acquire(1)[0].data[0, 0] == png_value(0)[0, 0]
        cam.invalidate()  # a move happened: frames 1-3 were buffered before it
        np.testing.assert_array_equal(cam.acquire(1)[0].data, png_value(4))
        cam.roi = Roi(8, 4, 16, 8)  # any settings change discards too
        frame = cam.acquire(1)[0]
        np.testing.assert_array_equal(frame.data, png_value(8)[4:12, 8:24])
        assert frame.roi == Roi(8, 4, 16, 8)


def test_trigger_then_acquire_returns_the_triggered_frame(png_sequence):
    with open_png(png_sequence) as cam:
        cam.trigger()
        cam.trigger()
        a, b = cam.acquire(2)
        np.testing.assert_array_equal(a.data, png_value(0))
        np.testing.assert_array_equal(b.data, png_value(1))


def test_bit_depth_for_twelve_bit_data(tmp_path):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), np.full((8, 8), 4000 + i, np.uint16))
    with OpenCVCamera(str(tmp_path / "f%d.png"), api_preference=cv2.CAP_IMAGES,
                      bit_depth=12) as cam:
        frame = cam.acquire(1)[0]
        assert cam.pixel_format is PixelFormat.MONO12 and frame.bit_depth == 12
        assert frame.saturation_dn == 4095 and frame.data.dtype == np.uint16
    with pytest.raises(ValueError):
        OpenCVCamera(str(tmp_path / "f%d.png"), api_preference=cv2.CAP_IMAGES, bit_depth=8)


def test_end_of_source_is_a_timeout(tmp_path):
    for i in range(2):
        cv2.imwrite(str(tmp_path / f"g{i}.png"), np.zeros((4, 4), np.uint16))
    with OpenCVCamera(str(tmp_path / "g%d.png"), api_preference=cv2.CAP_IMAGES) as cam:
        cam.acquire(2)
        with pytest.raises(DeviceTimeout):
            cam.acquire(1)


def test_video_frames(grey_video):
    with OpenCVCamera(grey_video, api_preference=cv2.CAP_FFMPEG) as cam:
        assert cam.pixel_format is PixelFormat.MONO8
        frames = cam.acquire(5)
        assert [int(f.data.mean()) for f in frames] == [0, 2, 4, 6, 8]
        assert frames[0].data.dtype == np.uint8 and frames[0].saturation_dn == 255
        assert "pos_msec" in frames[1].metadata
        with pytest.raises(UnsupportedFeature):
            cam.exposure_us = 1000.0


def test_missing_source_fails_to_connect(tmp_path):
    with pytest.raises(ConnectionFailed):
        OpenCVCamera(str(tmp_path / "none_%03d.png"), api_preference=cv2.CAP_IMAGES)


# ------------------------------------------------------------------ V4L2 semantics
class V4l2CaptureEmulator:
    """Device-side model of a UVC camera as OpenCV's V4L2 backend presents it.

    Behaviour (V4L2 UVC controls; opencv/opencv#9738): ``exposure_time_absolute`` in 100 µs
    integer units
    (1…5000, out-of-range values clamped with ``set`` still returning True), auto exposure
    as a menu (1 manual, 3 aperture priority; exposure writes are ignored in auto mode),
    integer gain 0…100 (clamped), FOURCC ``YUYV``/``GREY`` (8-bit) or ``Y16`` (16-bit),
    and a queue of ``buffers`` frames filled at capture time, so a frame read after a
    change was exposed before it. Pixel (0, 0) holds the exposure level at capture.
    ``manual_locked`` models cameras whose auto-exposure menu will not leave auto.
    """

    def __init__(self, *, buffers=4, manual_locked=False, y16_shape=(24, 32),
                 fourccs=("YUYV", "GREY", "Y16 ")):
        self.props = {
            cv2.CAP_PROP_AUTO_EXPOSURE: 3.0,
            cv2.CAP_PROP_EXPOSURE: 100.0,
            cv2.CAP_PROP_GAIN: 0.0,
            cv2.CAP_PROP_CONVERT_RGB: 1.0,
            cv2.CAP_PROP_FOURCC: float(cv2.VideoWriter_fourcc(*"YUYV")),
            cv2.CAP_PROP_BUFFERSIZE: float(buffers),
            cv2.CAP_PROP_FRAME_WIDTH: 32.0,
            cv2.CAP_PROP_FRAME_HEIGHT: 24.0,
        }
        self.manual_locked = manual_locked
        self.y16_shape = y16_shape  # some cameras offer Y16 only at another resolution
        self.fourccs = fourccs  # others ignore a FOURCC they lack, set() still True
        self.queue: list[np.ndarray] = []
        self.released = False

    def isOpened(self):  # the cv2.VideoCapture method names
        return not self.released

    def getBackendName(self):
        return "V4L2"

    def get(self, prop):
        return self.props.get(prop, -1.0)

    def set(self, prop, value):
        if prop == cv2.CAP_PROP_AUTO_EXPOSURE:
            if value not in (1.0, 3.0):
                return False
            if not self.manual_locked:
                self.props[prop] = value
            return True
        if prop == cv2.CAP_PROP_EXPOSURE:
            if self.props[cv2.CAP_PROP_AUTO_EXPOSURE] == 1.0:
                self.props[prop] = float(min(max(round(value), 1), 5000))
            return True
        if prop == cv2.CAP_PROP_GAIN:
            self.props[prop] = float(min(max(round(value), 0), 100))
            return True
        if prop == cv2.CAP_PROP_FOURCC:
            codes = {cv2.VideoWriter_fourcc(*c) for c in self.fourccs}
            if int(value) in codes:
                self.props[prop] = float(value)
                self.queue.clear()  # a format change restarts streaming
            return True
        if prop == cv2.CAP_PROP_BUFFERSIZE:
            if not 1 <= value <= 32:
                return False
            self.props[prop] = float(value)
            return True
        if prop == cv2.CAP_PROP_CONVERT_RGB:
            self.props[prop] = float(value)
            return True
        return False

    def _capture(self):
        level = self.props[cv2.CAP_PROP_EXPOSURE] * (1.0 + self.props[cv2.CAP_PROP_GAIN] / 100)
        sixteen = int(self.props[cv2.CAP_PROP_FOURCC]) == cv2.VideoWriter_fourcc(*"Y16 ")
        dtype = np.uint16 if sixteen else np.uint8
        top = 65535 if sixteen else 255
        return np.full(self.y16_shape if sixteen else (24, 32), min(level, top), dtype)

    def _fill(self):
        while len(self.queue) < int(self.props[cv2.CAP_PROP_BUFFERSIZE]):
            self.queue.append(self._capture())

    def grab(self):
        self._fill()
        self.queue.pop(0)
        self.queue.append(self._capture())
        return True

    def read(self):
        self._fill()
        frame = self.queue.pop(0)
        self.queue.append(self._capture())
        if self.props[cv2.CAP_PROP_CONVERT_RGB] == 1.0 and frame.dtype == np.uint8:
            return True, cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        return True, frame

    def release(self):
        self.released = True


def open_v4l2(**kw) -> tuple[OpenCVCamera, V4l2CaptureEmulator]:
    options = ("manual_locked", "y16_shape", "fourccs")
    emulator = V4l2CaptureEmulator(**{k: kw.pop(k) for k in options if k in kw})
    return OpenCVCamera(0, capture=emulator, **kw), emulator


def test_v4l2_exposure_in_100_us_units_with_manual_mode_and_stale_discard():
    cam, emu = open_v4l2()
    with cam:
        assert cam.stale_frames == 4  # V4L2 default: the driver's buffer count
        assert cam.exposure_us == 100.0 * 100.0
        cam.exposure_us = 2000.0
        assert emu.props[cv2.CAP_PROP_AUTO_EXPOSURE] == 1.0  # switched to manual first
        assert emu.props[cv2.CAP_PROP_EXPOSURE] == 20.0
        frame = cam.acquire(1)[0]
        assert frame.exposure_us == 2000.0
        assert frame.data[0, 0] == 20  # exposed after the change: the stale four are gone
        assert frame.data.ndim == 2  # BGR conversion undone losslessly


def test_v4l2_stream_delivers_no_frame_exposed_before_a_change():
    """While streaming, the driver's queued buffers and the frame being read during a
    change are discarded: the next streamed frame was exposed at the new setting."""
    cam, _ = open_v4l2(ring_capacity=4)
    with cam:
        cam.start_streaming()
        try:
            for k in range(40):
                units = 10 + k % 3
                cam.exposure_us = units * 100.0
                frame = cam.next_frame(timeout=60.0)
                assert frame.data[0, 0] == units, f"stale frame after change {k}"
                assert frame.exposure_us == units * 100.0
        finally:
            cam.stop_streaming()


def test_v4l2_without_discard_returns_frames_exposed_before_the_change():
    cam, _ = open_v4l2(stale_frames=0)
    with cam:
        cam.exposure_us = 2000.0
        assert cam.acquire(1)[0].data[0, 0] == 100  # the old exposure: why we discard


def test_v4l2_clamped_or_ignored_settings_raise():
    cam, _ = open_v4l2()
    with cam:
        with pytest.raises(UnsupportedFeature, match="exposure"):
            cam.exposure_us = 600_000.0  # 6000 units: the camera clamps to 5000
        cam.gain = 50.0
        assert cam.gain == 50.0 and cam.acquire(1)[0].gain == 50.0
        with pytest.raises(UnsupportedFeature, match="gain"):
            cam.gain = 150.0  # clamped to 100 by the camera
    locked, _ = open_v4l2(manual_locked=True)
    with locked, pytest.raises(UnsupportedFeature, match="manual exposure"):
        locked.exposure_us = 2000.0


def test_v4l2_pixel_format_by_fourcc():
    cam, emu = open_v4l2()
    with cam:
        assert cam.pixel_format is PixelFormat.MONO8
        cam.pixel_format = PixelFormat.MONO16
        assert int(emu.props[cv2.CAP_PROP_FOURCC]) == cv2.VideoWriter_fourcc(*"Y16 ")
        frame = cam.acquire(1)[0]
        assert frame.data.dtype == np.uint16 and frame.saturation_dn == 65535
        with pytest.raises(UnsupportedFeature):
            cam.pixel_format = PixelFormat.MONO12
    assert emu.released


def test_v4l2_ignored_fourcc_raises_and_the_format_stays():
    cam, _ = open_v4l2(fourccs=("YUYV", "GREY"))
    with cam:
        with pytest.raises(UnsupportedFeature, match="pixel format"):
            cam.pixel_format = PixelFormat.MONO16
        assert cam.pixel_format is PixelFormat.MONO8
        assert cam.acquire(1)[0].data.dtype == np.uint8


def test_v4l2_format_change_to_another_resolution_resets_the_roi():
    cam, _ = open_v4l2(y16_shape=(12, 16))
    with cam:
        cam.roi = Roi(8, 8, 20, 12)
        cam.pixel_format = PixelFormat.MONO16
        assert cam.sensor_shape == (12, 16) and cam.roi == Roi(0, 0, 16, 12)
        frame = cam.acquire(1)[0]
        assert frame.data.shape == (12, 16) and frame.roi == cam.roi


class TestV4l2Contract(CameraContract):
    @pytest.fixture
    def camera_factory(self):
        return lambda: open_v4l2(ring_capacity=4)[0]


def test_v4l2_buffer_size_is_set_and_checked():
    cam, emu = open_v4l2(buffer_size=2)
    with cam:
        assert emu.props[cv2.CAP_PROP_BUFFERSIZE] == 2.0
    refused = V4l2CaptureEmulator()
    with pytest.raises(UnsupportedFeature):
        OpenCVCamera(0, capture=refused, buffer_size=64)
    assert refused.released  # a failed constructor leaves nothing open
    with pytest.raises(ValueError):
        OpenCVCamera(0, capture=V4l2CaptureEmulator(), buffer_size=0)
