"""A camera on OpenCV's ``cv2.VideoCapture`` (V4L2/UVC devices, image sequences, videos).

OpenCV is a convenience path, not a scientific camera API (OpenCV ``VideoCapture``
documentation; opencv/opencv#14494, #9738, #13145): property
support and units depend on the backend, ``set()`` may return success and change nothing,
frames arrive without per-frame metadata, and V4L2 keeps about four buffers, so a frame read
after a move may have been exposed before it. This driver therefore

* reads **every** setting back after ``set`` and raises
  :class:`~drivers.errors.UnsupportedFeature` when the backend refused or ignored it (it
  never continues silently);
* converts exposure units per backend: V4L2 counts ``exposure_time_absolute`` in 100 µs
  units; DirectShow/MSMF use log₂ seconds (opencv/opencv#9738); other backends (image
  sequences, video files) have no exposure control and report ``NaN`` (or the
  ``nominal_exposure_us`` given to the constructor);
* switches V4L2 auto exposure to manual (value 1) before setting an exposure, and checks it;
* discards ``stale_frames`` buffered frames (``grab()`` without decoding) on
  :meth:`~drivers.base.Camera.invalidate`, which runs after every settings change and which
  the engine calls after every move (default 4 on V4L2, the driver's buffer count; 0 for
  sources without a live queue);
* keeps 16-bit data: it asks the backend not to convert to BGR (``CAP_PROP_CONVERT_RGB=0``;
  image sequences already decode with ``IMREAD_UNCHANGED`` semantics and refuse the
  property, which is fine because their frames arrive single-channel). A three-channel
  frame whose channels are equal is reduced to one channel losslessly; a true colour frame
  is converted to luminance and marked ``metadata["converted_from"] = "BGR"``;
* implements the ROI by cropping in software (OpenCV has no sensor ROI: the readout is not
  faster), and refuses binning;
* maps the pixel format from the delivered frames (uint8 → MONO8, uint16 → MONO16, or the
  ``bit_depth`` given for 10/12-bit data in 16-bit words); on V4L2 a format change requests
  the ``GREY``/``Y16`` FOURCC and checks it, elsewhere any other format is refused.

Opening reads one probe frame to learn the frame size and data type; file sources are
rewound afterwards (``CAP_PROP_POS_FRAMES = 0``) so no file frame is lost.

Timeouts: ``VideoCapture.read()`` cannot be interrupted from Python. A read that blocks
returns only when the backend's own wait ends (V4L2 waits on ``select()`` with its own
limit); :meth:`~drivers.base.Camera.acquire` checks its timeout between frames, and a read
that fails is a :class:`~drivers.errors.DeviceTimeout`.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from typing import Any, cast

import cv2
import numpy as np

from drivers.base import Camera, DeviceIdentity, Frame, PixelFormat, Roi
from drivers.errors import ConnectionFailed, DeviceTimeout, UnsupportedFeature

__all__ = ["OpenCVCamera"]

#: V4L2 counts exposure_time_absolute in units of 100 µs.
_V4L2_EXPOSURE_UNIT_US = 100.0
#: V4L2 auto-exposure menu: 1 = manual, 3 = aperture priority (opencv/opencv#9738).
_V4L2_MANUAL_EXPOSURE = 1.0
_FOURCC = {PixelFormat.MONO8: "GREY", PixelFormat.MONO16: "Y16 "}


class OpenCVCamera(Camera):
    """A monochrome camera behind ``cv2.VideoCapture``.

    Parameters
    ----------
    source
        Device index (``0`` → ``/dev/video0``), device path, image-sequence pattern
        (``"frames/img_%04d.png"`` with ``api_preference=cv2.CAP_IMAGES``) or video file.
    name
        Role name.
    api_preference
        An OpenCV ``CAP_*`` backend id; force ``cv2.CAP_V4L2`` for cameras (the maintainers'
        advice, opencv/opencv#14494).
    stale_frames
        Frames discarded by :meth:`invalidate`; default 4 on V4L2, else 0.
    bit_depth
        Significant bits of 16-bit data (10, 12 or 16); default from the dtype.
    nominal_exposure_us
        Exposure to report when the backend cannot (e.g. for a recorded sequence whose
        exposure is known); default NaN (unknown).
    buffer_size
        If given, ask the backend for this many buffers (``CAP_PROP_BUFFERSIZE``, read back).
    ring_capacity
        Capacity of the streaming ring buffer.
    capture
        An already opened ``cv2.VideoCapture`` (or an object with its interface:
        ``isOpened``, ``getBackendName``, ``set``, ``get``, ``read``, ``grab``, ``release``)
        to adopt instead of opening ``source``; the camera owns and releases it.
    """

    def __init__(
        self,
        source: int | str,
        *,
        name: str = "camera",
        api_preference: int = cv2.CAP_ANY,
        stale_frames: int | None = None,
        bit_depth: int | None = None,
        nominal_exposure_us: float = math.nan,
        buffer_size: int | None = None,
        ring_capacity: int = 16,
        capture: Any = None,
    ) -> None:
        super().__init__(name, ring_capacity=ring_capacity)
        self._source = source
        self._lock = threading.RLock()
        self._pending: deque[Frame] = deque()
        self._index = 0
        cap = capture if capture is not None else cv2.VideoCapture(source, api_preference)
        if not cap.isOpened():
            cap.release()
            raise ConnectionFailed(
                f"OpenCV could not open {source!r}", device=name, command="open",
                hint="check the device index or path and that no other program holds it",
            )
        self._cap = cap
        try:
            self._backend = cap.getBackendName()
            self.stale_frames = (
                int(stale_frames) if stale_frames is not None
                else (4 if self._backend == "V4L2" else 0)
            )
            if self.stale_frames < 0:
                raise ValueError("stale_frames must be >= 0")
            # Ask for unconverted (possibly 16-bit) frames. A backend may refuse; the frames
            # are checked one by one in _to_mono, so a refusal is not silently trusted.
            self._raw_frames = bool(cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)) and (
                cap.get(cv2.CAP_PROP_CONVERT_RGB) == 0
            )
            if buffer_size is not None:
                if int(buffer_size) != buffer_size or buffer_size < 1:
                    raise ValueError(f"buffer_size must be a positive integer, got {buffer_size}")
                self._set_checked(cv2.CAP_PROP_BUFFERSIZE, float(buffer_size), "buffer_size",
                                  tolerance=0.0)
            self._nominal_exposure_us = float(nominal_exposure_us)
            self._exposure_us = self._read_exposure_us()
            gain = cap.get(cv2.CAP_PROP_GAIN)
            self._gain = float(gain) if gain >= 0 and self._backend == "V4L2" else math.nan
            if math.isfinite(self._gain):
                self.gain_range = (0.0, max(255.0, self._gain))
            probe = self._probe()
            self._frame_shape = probe.shape
            if bit_depth is None:
                bit_depth = 8 if probe.dtype == np.uint8 else 16
            if (probe.dtype == np.uint8) != (bit_depth == 8) or bit_depth not in (8, 10, 12, 16):
                raise ValueError(
                    f"bit_depth {bit_depth} does not fit {probe.dtype} frames from {source!r}"
                )
            self._format = PixelFormat(bit_depth)
            height, width = self._frame_shape
            self._roi = Roi(0, 0, width, height)
        except BaseException:
            cap.release()
            raise

    # ------------------------------------------------------------------ internals
    def _probe(self) -> np.ndarray:
        ok, img = self._cap.read()
        if not ok or img is None:
            raise ConnectionFailed(f"{self._source!r} opened but delivers no frames",
                                   device=self.name, command="open")
        mono, _ = self._to_mono(img)
        if isinstance(self._source, str) and self._backend in ("CV_IMAGES", "FFMPEG"):
            # File sources: rewind so that the probe costs no frame of the recording.
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        return mono

    def _to_mono(self, img: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        if img.ndim == 2:
            return img, {}
        if img.ndim == 3 and img.shape[2] == 1:
            return img[:, :, 0], {}
        if img.ndim == 3 and img.shape[2] in (3, 4):
            bgr = img[:, :, :3]
            if np.array_equal(bgr[:, :, 0], bgr[:, :, 1]) and np.array_equal(
                bgr[:, :, 0], bgr[:, :, 2]
            ):
                return np.ascontiguousarray(bgr[:, :, 0]), {}
            return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), {"converted_from": "BGR"}
        raise UnsupportedFeature(f"frames of shape {img.shape} are not supported",
                                 device=self.name, command="read")

    def _set_checked(self, prop: int, value: float, what: str, *, tolerance: float) -> float:
        """``set`` then ``get``; raise UnsupportedFeature unless the readback matches."""
        accepted = bool(self._cap.set(prop, value))
        readback = float(self._cap.get(prop))
        if not accepted or abs(readback - value) > tolerance:
            raise UnsupportedFeature(
                f"the {self._backend} backend did not honour {what} = {value:g} "
                f"(set returned {accepted}, reads back {readback:g})",
                device=self.name, command=f"set {what}",
                hint="this camera or backend cannot control it through OpenCV; "
                "use a vendor SDK/GenICam driver for scientific control",
            )
        return readback

    def _read_exposure_us(self) -> float:
        raw = float(self._cap.get(cv2.CAP_PROP_EXPOSURE))
        if self._backend == "V4L2" and raw > 0:
            return raw * _V4L2_EXPOSURE_UNIT_US
        if self._backend in ("MSMF", "DSHOW") and raw != -1:
            return cast(float, 2.0**raw * 1e6)  # float ** float is Any in typeshed
        return self._nominal_exposure_us

    def _read_frame(self, img: np.ndarray, timestamp: float) -> Frame:
        mono, meta = self._to_mono(img)
        if mono.shape != self._frame_shape:
            raise UnsupportedFeature(
                f"frame size changed from {self._frame_shape} to {mono.shape}",
                device=self.name, command="read", hint="reopen the camera",
            )
        if mono.dtype != self._format.dtype:
            raise UnsupportedFeature(
                f"the backend delivered {mono.dtype} frames, expected {self._format.dtype}",
                device=self.name, command="read",
            )
        r = self._roi
        if (r.height, r.width) == mono.shape:
            data = mono
        else:  # software ROI: a copy, so the full frame is not kept alive
            data = mono[r.y:r.y + r.height, r.x:r.x + r.width].copy()
        pos_ms = float(self._cap.get(cv2.CAP_PROP_POS_MSEC))
        meta.update(backend=self._backend)
        if pos_ms >= 0:
            meta["pos_msec"] = pos_ms
        with self._lock:
            index = self._index
            self._index += 1
        return Frame(
            data=data, index=index, timestamp=timestamp, exposure_us=self._exposure_us,
            gain=self._gain, saturation_dn=float(2**self._format.bit_depth - 1),
            bit_depth=self._format.bit_depth, roi=r, binning=1, metadata=meta,
        )

    # ------------------------------------------------------------------ hooks
    def _do_identity(self) -> DeviceIdentity:
        return DeviceIdentity(
            vendor="OpenCV", model=f"VideoCapture/{self._backend}", serial=str(self._source),
            firmware=cv2.__version__,
        )

    def _do_sensor_shape(self) -> tuple[int, int]:
        return self._frame_shape

    def _do_get_exposure_us(self) -> float:
        return self._exposure_us

    def _do_set_exposure_us(self, value: float) -> None:
        with self._lock:
            if self._backend == "V4L2":
                self._set_checked(cv2.CAP_PROP_AUTO_EXPOSURE, _V4L2_MANUAL_EXPOSURE,
                                  "manual exposure", tolerance=0.0)
                units = value / _V4L2_EXPOSURE_UNIT_US
                # The control is an integer: accept the nearest step, nothing further off.
                got = self._set_checked(cv2.CAP_PROP_EXPOSURE, float(round(units)),
                                        "exposure", tolerance=0.0)
                if abs(got * _V4L2_EXPOSURE_UNIT_US - value) > 0.5 * _V4L2_EXPOSURE_UNIT_US:
                    raise UnsupportedFeature(
                        f"exposure {value:g} µs is not representable (100 µs steps)",
                        device=self.name, command="set exposure",
                    )
                self._exposure_us = got * _V4L2_EXPOSURE_UNIT_US
            elif self._backend in ("MSMF", "DSHOW"):
                log2_s = float(round(math.log2(value * 1e-6)))
                got = self._set_checked(cv2.CAP_PROP_EXPOSURE, log2_s, "exposure",
                                        tolerance=0.0)
                self._exposure_us = 2.0**got * 1e6
            else:
                # Unknown units: try only to learn whether the backend has the control.
                accepted = bool(self._cap.set(cv2.CAP_PROP_EXPOSURE, value))
                raise UnsupportedFeature(
                    f"the {self._backend} backend has no exposure control in known units "
                    f"(set returned {accepted})",
                    device=self.name, command="set exposure",
                    hint="use CAP_V4L2 for UVC cameras",
                )

    def _do_get_gain(self) -> float:
        return self._gain

    def _do_set_gain(self, value: float) -> None:
        with self._lock:
            if not math.isfinite(self._gain):
                accepted = bool(self._cap.set(cv2.CAP_PROP_GAIN, value))
                raise UnsupportedFeature(
                    f"the {self._backend} backend has no gain control (set returned "
                    f"{accepted})", device=self.name, command="set gain",
                )
            self._gain = self._set_checked(cv2.CAP_PROP_GAIN, value, "gain",
                                           tolerance=max(0.5, 0.01 * abs(value)))

    def _do_get_roi(self) -> Roi:
        return self._roi

    def _do_set_roi(self, roi: Roi) -> None:
        with self._lock:
            self._roi = roi

    def _do_get_pixel_format(self) -> PixelFormat:
        return self._format

    def _do_set_pixel_format(self, fmt: PixelFormat) -> None:
        if fmt is self._format:
            return
        with self._lock:
            code = _FOURCC.get(fmt)
            if self._backend != "V4L2" or code is None:
                raise UnsupportedFeature(
                    f"pixel format {fmt.name} is not available from {self._backend} "
                    f"(frames are {self._format.name})",
                    device=self.name, command="set pixel_format",
                )
            self._set_checked(cv2.CAP_PROP_FOURCC, float(cv2.VideoWriter_fourcc(*code)),  # type: ignore[attr-defined]  # in cv2 at run time; its stubs omit it
                              "pixel format", tolerance=0.0)
            probe = self._probe()
            if probe.dtype != fmt.dtype:
                raise UnsupportedFeature(
                    f"FOURCC {code!r} accepted but frames arrive as {probe.dtype}",
                    device=self.name, command="set pixel_format",
                )
            if probe.shape != self._frame_shape:  # a new mode: the old ROI may not fit
                self._roi = Roi(0, 0, probe.shape[1], probe.shape[0])
            self._frame_shape = probe.shape
            self._format = fmt

    def _do_invalidate(self) -> None:
        with self._lock:
            self._pending.clear()
            for _ in range(self.stale_frames):
                if not self._cap.grab():  # grab without decoding: cheap
                    break

    def _do_trigger(self) -> None:
        with self._lock:
            ok, img = self._cap.read()
            stamp = time.time()
            if not ok or img is None:
                raise DeviceTimeout("no frame for the software trigger", device=self.name,
                                    command="trigger", hint="end of a file source?")
            self._pending.append(self._read_frame(img, stamp))

    def _do_acquire_one(self, timeout: float) -> Frame:
        with self._lock:
            if self._pending:
                return self._pending.popleft()
            started = time.monotonic()
            ok, img = self._cap.read()
            stamp = time.time()
            if not ok or img is None:
                raise DeviceTimeout(
                    f"the {self._backend} backend delivered no frame "
                    f"(after {time.monotonic() - started:.3g} s)",
                    device=self.name, command="acquire",
                    hint="end of a file source, or the camera stopped streaming",
                )
            return self._read_frame(img, stamp)

    def _do_close_camera(self) -> None:
        with self._lock:
            self._pending.clear()
            self._cap.release()
