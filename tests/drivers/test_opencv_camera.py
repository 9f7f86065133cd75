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


class TestPngSequenceContract(CameraContract):
    finite_source = True

    @pytest.fixture
    def camera_factory(self, png_sequence):
        return lambda: open_png(png_sequence, ring_capacity=4)


class TestVideoContract(CameraContract):
    finite_source = True

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
