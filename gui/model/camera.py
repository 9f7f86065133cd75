"""The live camera picture's data path, without Qt: newest-frame slot, statistics, rates.

A streaming camera fills its own bounded ring (:class:`drivers.base.FrameRing`); the
:class:`FramePump` thread drains it, computes the statistics the view shows (ROI mean and
maximum, DN/µs, saturated fraction, a saturation mask) off the GUI thread, and puts the
result in a :class:`FrameSlot` that holds **one** frame: the newest. The GUI's display
timer takes from the slot at its own rate; a frame replaced before it was shown counts as
skipped. Nothing queues: memory stays at one frame in the slot and the ring's capacity,
whatever the camera's rate and however slow the display.

During a run the engine owns the camera; its frame subscription puts each point's frame
in the same slot (:meth:`FrameSlot.put_array`).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from drivers.base import Camera
from drivers.errors import DeviceError, DeviceTimeout

__all__ = ["DISPLAY_MAX_SIDE", "FramePump", "FrameSlot", "FrameStats", "LiveFrame",
           "RateMeter", "RoiBox", "decimate", "decimation", "frame_stats", "save_frame"]


@dataclass(frozen=True)
class RoiBox:
    """A rectangle of the image in pixels: columns x..x+width, rows y..y+height."""

    x: int
    y: int
    width: int
    height: int

    def clipped(self, shape: tuple[int, ...]) -> RoiBox | None:
        """This box inside an image of ``shape`` (rows, cols); ``None`` if nothing is left."""
        h, w = int(shape[0]), int(shape[1])
        x0, y0 = max(0, int(self.x)), max(0, int(self.y))
        x1, y1 = min(w, int(self.x + self.width)), min(h, int(self.y + self.height))
        if x1 <= x0 or y1 <= y0:
            return None
        return RoiBox(x0, y0, x1 - x0, y1 - y0)


@dataclass(frozen=True)
class FrameStats:
    """Statistics of one frame: over the ROI (the whole frame without one)."""

    mean_dn: float
    max_dn: float
    dn_per_us: float           # ROI mean / exposure (no dark subtracted)
    saturated_fraction: float  # of the whole frame
    roi: RoiBox | None


def frame_stats(data: np.ndarray, exposure_us: float, saturation_dn: float,
                roi: RoiBox | None = None) -> tuple[FrameStats, np.ndarray]:
    """(statistics, saturation mask) of ``data`` (shape (H, W), DN).

    The mask is a uint8 image, 1 where a pixel is at or above ``saturation_dn``.
    """
    box = roi.clipped(data.shape) if roi is not None else None
    part = data if box is None else data[box.y:box.y + box.height, box.x:box.x + box.width]
    mean = float(part.mean(dtype=np.float64))
    peak = float(part.max())
    mask = (data >= saturation_dn).view(np.uint8)
    sat = float(np.count_nonzero(mask)) / mask.size
    per_us = mean / exposure_us if exposure_us and np.isfinite(exposure_us) else float("nan")
    return FrameStats(mean, peak, per_us, sat, box), mask


#: Largest side of the picture the display gets; larger frames are decimated (block
#: maximum for the saturation mask, so no saturated pixel disappears) off the GUI thread.
DISPLAY_MAX_SIDE = 1024


def decimation(shape: tuple[int, ...], max_side: int = DISPLAY_MAX_SIDE) -> int:
    """The integer factor that brings the larger side of ``shape`` to ≤ ``max_side``."""
    return max(1, -(-max(int(shape[0]), int(shape[1])) // max_side))


def decimate(data: np.ndarray, factor: int, *, reduce: str = "sample") -> np.ndarray:
    """``data`` shrunk by ``factor``: every factor-th pixel (``sample``) or the maximum of
    each factor × factor block (``max``, for masks)."""
    if factor == 1:
        return data
    if reduce == "sample":
        return data[::factor, ::factor]
    h, w = (data.shape[0] // factor) * factor, (data.shape[1] // factor) * factor
    blocks = data[:h, :w].reshape(h // factor, factor, w // factor, factor)
    return blocks.max(axis=(1, 3))


@dataclass(frozen=True)
class LiveFrame:
    """A frame ready to show: the data, its statistics and saturation mask.

    ``display`` and ``display_mask`` are what the view paints: the frame and the mask
    decimated to at most :data:`DISPLAY_MAX_SIDE` pixels a side (``scale`` pixels of the
    frame per displayed pixel).
    """

    data: np.ndarray
    index: int
    exposure_us: float
    saturation_dn: float
    timestamp: float
    stats: FrameStats | None  # None until computed (run frames: by the display)
    mask: np.ndarray | None
    source: str  # "stream" | "run"
    display: np.ndarray | None = None
    display_mask: np.ndarray | None = None
    scale: int = 1

    def with_stats(self, roi: RoiBox | None) -> LiveFrame:
        """This frame with its statistics and display images (computed now if they were
        not)."""
        if self.stats is not None:
            return self
        stats, mask = frame_stats(self.data, self.exposure_us, self.saturation_dn, roi)
        k = decimation(self.data.shape)
        return replace(self, stats=stats, mask=mask, display=decimate(self.data, k),
                       display_mask=decimate(mask, k, reduce="max"), scale=k)


class RateMeter:
    """Events per second over a sliding window of the last ``window_s`` seconds."""

    def __init__(self, window_s: float = 2.0, *, clock: Callable[[], float] = time.monotonic,
                 maxlen: int = 4096) -> None:
        self.window_s = float(window_s)
        self._clock = clock
        self._t: deque[float] = deque(maxlen=maxlen)  # bounded whatever the rate
        self._lock = threading.Lock()

    def tick(self, n: int = 1) -> None:
        now = self._clock()
        with self._lock:
            for _ in range(n):
                self._t.append(now)

    def rate(self) -> float:
        now = self._clock()
        with self._lock:
            while self._t and now - self._t[0] > self.window_s:
                self._t.popleft()
            if len(self._t) < 2:
                return 0.0
            span = max(now - self._t[0], 1e-9)
            return (len(self._t) - 1) / span if span < self.window_s else len(self._t) / span


class FrameSlot:
    """Holds the newest :class:`LiveFrame` and counts frames in, shown and skipped."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._frame: LiveFrame | None = None
        self._fresh = False
        self.received = 0
        self.taken = 0
        self.skipped = 0
        self._roi: RoiBox | None = None
        self.in_rate = RateMeter()
        self.shown_rate = RateMeter()

    # the ROI the statistics use (set by the view, read by the pump)
    @property
    def roi(self) -> RoiBox | None:
        with self._lock:
            return self._roi

    @roi.setter
    def roi(self, box: RoiBox | None) -> None:
        with self._lock:
            self._roi = box

    def put(self, frame: LiveFrame) -> None:
        with self._lock:
            if self._fresh:
                self.skipped += 1
            self._frame = frame
            self._fresh = True
            self.received += 1
        self.in_rate.tick()

    def put_array(self, data: np.ndarray, *, exposure_us: float, saturation_dn: float,
                  index: int = -1, timestamp: float | None = None, source: str = "run",
                  compute: bool = True) -> None:
        """Put ``data``; with ``compute``, its statistics are computed first (on the
        calling thread), else when it is taken."""
        frame = LiveFrame(data, index, float(exposure_us), float(saturation_dn),
                          time.time() if timestamp is None else timestamp, None, None, source)
        self.put(frame.with_stats(self.roi) if compute else frame)

    def take(self) -> LiveFrame | None:
        """The newest frame, with its statistics, if it has not been taken yet, else
        ``None``."""
        with self._lock:
            if not self._fresh:
                return None
            self._fresh = False
            self.taken += 1
            frame = self._frame
            roi = self._roi
        self.shown_rate.tick()
        return frame.with_stats(roi) if frame is not None else None

    def latest(self) -> LiveFrame | None:
        """The newest frame, taken or not (snapshots)."""
        with self._lock:
            return self._frame

    def counts(self) -> tuple[int, int, int, bool]:
        """(received, taken, skipped, whether a frame waits), read together."""
        with self._lock:
            return self.received, self.taken, self.skipped, self._fresh

    def reset_counts(self) -> None:
        with self._lock:
            self.received = self.taken = self.skipped = 0


class FramePump:
    """Drains a streaming camera's ring into a :class:`FrameSlot` on its own thread.

    The camera's stream thread produces; this thread consumes the ring (the camera's
    :meth:`~drivers.base.Camera.next_frame`, a read of its buffer, not a device command)
    and computes statistics, so the GUI thread only paints. ``on_error`` is called once
    with the stream's error if it fails (the pump then stops).
    """

    def __init__(self, camera: Camera, slot: FrameSlot, *,
                 on_error: Callable[[BaseException], None] | None = None) -> None:
        self.camera = camera
        self.slot = slot
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="frame-pump", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.camera.next_frame(timeout=0.2)
            except DeviceTimeout:
                if not self.camera.is_streaming and not self._stop.is_set():
                    # the stream ended by itself (an error surfaced as the timeout)
                    if self._on_error is not None:
                        self._on_error(DeviceTimeout("the camera stream stopped",
                                                     device=self.camera.name,
                                                     command="next_frame"))
                    return
                continue
            except (DeviceError, OSError, ValueError) as err:
                if self._on_error is not None:
                    self._on_error(err)
                return
            self.slot.put_array(frame.data, exposure_us=frame.exposure_us,
                                saturation_dn=frame.saturation_dn, index=frame.index,
                                timestamp=frame.timestamp, source="stream")


def save_frame(data: np.ndarray, path: str | Path) -> Path:
    """Write a frame to ``path``: ``.npy`` (exact), or ``.png``/``.tif`` (16-bit, through
    OpenCV). Raises OSError naming the file when it cannot be written."""
    import cv2

    path = Path(path)
    suffix = path.suffix.lower()
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".npy":
        np.save(path, np.asarray(data))
        return path
    if suffix not in (".png", ".tif", ".tiff"):
        raise OSError(f"snapshot {path}: use a .png, .tif or .npy name")
    arr = np.asarray(data)
    if arr.dtype not in (np.uint8, np.uint16):
        arr = np.clip(np.rint(arr), 0, 65535).astype(np.uint16)
    try:
        ok = cv2.imwrite(str(path), arr)
    except cv2.error as err:
        raise OSError(f"could not write the snapshot {path}: {err}") from err
    if not ok:
        raise OSError(f"could not write the snapshot {path} (is the folder writable?)")
    return path
