"""A GenICam camera driven through the standard feature names (SFNC), over a small transport.

GenICam cameras (Basler, FLIR, Allied Vision, IDS, …) describe themselves in an XML node
map whose feature names follow the *Standard Features Naming Convention* (EMVA GenICam
SFNC 2.x): ``PixelFormat``, ``ExposureTime`` (µs), ``Gain`` (dB), ``BlackLevel``,
``OffsetX``/``OffsetY``/``Width``/``Height`` (in binned pixels), ``BinningHorizontal``/
``BinningVertical``, ``TriggerSelector``/``TriggerMode``/``TriggerSource``/
``TriggerActivation``/``TriggerSoftware``, ``SensorWidth``/``SensorHeight``. This module
speaks only those names. Everything a vendor's SDK does differently — how a camera is
found and opened, how its exceptions read, how a grab result hands over its buffer,
legacy feature names — lives behind :class:`GenICamTransport`; the Basler/pylon one is
:mod:`drivers.pylon_transport` (ADR 0096). Another SDK (harvesters with a vendor's GenTL
producer) is one more transport of the same few methods.

Acquisition model
-----------------
The camera grabs continuously into a few driver buffers (``buffers``, default 8) and each
frame is copied out of its buffer once and the buffer handed back at once, so nothing
accumulates however many frames are taken.

* ``software`` trigger (the default): every frame :meth:`~drivers.base.Camera.acquire`
  needs is one ``TriggerSoftware``, sent when the camera reports it is ready for a frame
  trigger, so the exposure of an acquired frame always starts after the call.
  :meth:`~drivers.base.Camera.trigger` sends one and collects its frame before it returns
  (like the other cameras of the project); the next ``acquire`` returns that frame.
* ``hardware`` trigger: ``TriggerSource`` is the input line (``hardware_line``, default
  ``Line1``, rising edge); a frame comes when the pulse comes, and an ``acquire`` with no
  pulse within its timeout raises :class:`~drivers.errors.DeviceTimeout` naming the line.
  A software trigger is refused in this mode.
* ``free_run``: ``TriggerMode = Off``; the camera exposes frame after frame.

Stale frames: :meth:`~drivers.base.Camera.invalidate` (after every settings change and
every move) stops and restarts the grab, which discards every queued buffer and any
exposure in flight; the next frame starts after the call in every mode.

Device loss: a camera that disappears (unplugged, powered off) raises
:class:`~drivers.errors.ConnectionFailed` — the engine's retry policy retries the
operation — and the next operation reconnects to the camera with the same serial number,
reapplies every setting (format, binning, ROI, exposure, gain, black level, trigger) and
goes on; :meth:`GenICamCamera.reconnect` does it on demand.

Frame metadata: ``Frame.timestamp`` is the host's clock when the frame was handed over
(seconds since the epoch), ``metadata`` holds the camera's own frame id (``frame_id``,
the GenTL block id), its timestamp in device ticks (``device_timestamp``; 0 where the
camera has none), the exposure actually used (``Frame.exposure_us``: the camera's chunk
data where it sends them, else the exposure read back from the camera, which may be
rounded to the camera's step) and where it came from (``exposure_source``).
"""

from __future__ import annotations

import enum
import math
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from drivers.base import Camera, DeviceIdentity, Frame, PixelFormat, Roi
from drivers.errors import (
    ConnectionFailed,
    DeviceError,
    DeviceTimeout,
    StateError,
    UnsupportedFeature,
)

__all__ = ["GenICamCamera", "GenICamTransport", "GrabbedBuffer", "TriggerMode"]

#: SFNC pixel-format names of the monochrome formats the project handles (unpacked:
#: 10/12-bit values arrive LSB-aligned in 16-bit words).
SFNC_PIXEL_FORMATS = {PixelFormat.MONO8: "Mono8", PixelFormat.MONO10: "Mono10",
                      PixelFormat.MONO12: "Mono12", PixelFormat.MONO16: "Mono16"}
#: Chunks asked for where the camera has them (SFNC ``ChunkSelector`` entries).
WANTED_CHUNKS = ("Timestamp", "ExposureTime", "FrameID")
#: Seconds to wait for the camera to be ready for a software trigger, beyond the exposure.
TRIGGER_READY_S = 2.0


class TriggerMode(enum.Enum):
    """What starts an exposure."""

    SOFTWARE = "software"
    HARDWARE = "hardware"
    FREE_RUN = "free_run"


@dataclass(frozen=True)
class GrabbedBuffer:
    """One frame copied out of a transport buffer (the buffer is already given back).

    ``data`` has shape (height, width), uint8 or uint16, the camera's values unchanged;
    ``device_timestamp`` in the camera's ticks (0 where it has no clock);
    ``chunks`` the chunk data the camera sent with the frame (SFNC names without the
    ``Chunk`` prefix, e.g. ``ExposureTime``), empty where it sends none.
    """

    data: np.ndarray
    frame_id: int
    device_timestamp: int
    pixel_format: str
    chunks: dict[str, float] = field(default_factory=dict)


class GenICamTransport(ABC):
    """What :class:`GenICamCamera` needs from a vendor SDK: features by SFNC name and a grab.

    Every method raises :mod:`drivers.errors` types, never the SDK's own: a feature the
    camera lacks → :class:`~drivers.errors.UnsupportedFeature`, a value it refuses →
    :class:`~drivers.errors.LimitError` (out of range) or
    :class:`~drivers.errors.StateError` (not writable now), a camera that is gone →
    :class:`~drivers.errors.ConnectionFailed`, a grab timeout →
    :class:`~drivers.errors.DeviceTimeout`, anything else the camera reports →
    :class:`~drivers.errors.ControllerError`.
    """

    serial: str

    @abstractmethod
    def identity(self) -> DeviceIdentity: ...

    @abstractmethod
    def has(self, feature: str) -> bool:
        """Whether the camera has ``feature`` and it is readable now."""

    @abstractmethod
    def get(self, feature: str) -> Any:
        """Value of a feature: int, float, bool or str (enumerations by symbolic name)."""

    @abstractmethod
    def set(self, feature: str, value: Any) -> None: ...

    @abstractmethod
    def execute(self, feature: str) -> None:
        """Run a command feature (``TriggerSoftware``)."""

    @abstractmethod
    def limits(self, feature: str) -> tuple[float, float, float]:
        """(min, max, increment) of a numeric feature as the camera states it now
        (increment 0 where it states none)."""

    @abstractmethod
    def choices(self, feature: str) -> tuple[str, ...]:
        """Symbolic names an enumeration feature accepts now."""

    @abstractmethod
    def start(self, buffers: int) -> None:
        """Start grabbing into ``buffers`` buffers (idempotent)."""

    @abstractmethod
    def stop(self) -> None:
        """Stop grabbing; discards every queued buffer and any frame in flight."""

    @abstractmethod
    def wait_trigger_ready(self, timeout: float) -> None:
        """Wait until the camera accepts a frame trigger (DeviceTimeout otherwise)."""

    @abstractmethod
    def retrieve(self, timeout: float) -> GrabbedBuffer:
        """The next frame, waiting up to ``timeout`` s (DeviceTimeout if none came)."""

    @abstractmethod
    def buffer_counts(self) -> dict[str, int]:
        """How many buffers are queued for the camera, ready for the driver, and in all."""

    @abstractmethod
    def is_removed(self) -> bool:
        """Whether the SDK has seen the camera disappear."""

    @abstractmethod
    def reconnect(self) -> None:
        """Drop the lost device and open the camera with the same serial number again
        (ConnectionFailed when it is not there)."""

    @abstractmethod
    def close(self) -> None: ...


class GenICamCamera(Camera):
    """A monochrome GenICam camera, controlled through SFNC features of a transport.

    Parameters
    ----------
    transport
        An opened :class:`GenICamTransport`; the camera owns and closes it.
    name
        Role name.
    pixel_format
        Initial format (default: keep the camera's, if it is one of Mono8/10/12/16,
        else Mono8).
    trigger_mode
        Initial :class:`TriggerMode` (default software).
    hardware_line
        The input line a hardware trigger comes on (SFNC ``TriggerSource`` entry).
    buffers
        Driver buffers the camera grabs into.
    ring_capacity
        Capacity of the streaming ring buffer.
    """

    def __init__(
        self,
        transport: GenICamTransport,
        *,
        name: str = "camera",
        pixel_format: PixelFormat | None = None,
        trigger_mode: TriggerMode | str = TriggerMode.SOFTWARE,
        hardware_line: str = "Line1",
        buffers: int = 8,
        ring_capacity: int = 16,
    ) -> None:
        super().__init__(name, ring_capacity=ring_capacity)
        if isinstance(buffers, bool) or int(buffers) != buffers or buffers < 1:
            transport.close()  # the camera owns it from here: nothing stays open
            raise ValueError(f"{name}: buffers must be a positive integer, got {buffers}")
        self._t = transport
        self._lock = threading.RLock()
        self._buffers = int(buffers)
        self._hardware_line = str(hardware_line)
        self._index = 0
        self._pending: deque[Frame] = deque()  # software-triggered frames
        self._lost: ConnectionFailed | None = None
        self._loss_reported = True
        try:
            self._configure_fixed()
            fmt = pixel_format or self._format_from_camera()
            self._set_format(fmt)
            self._set_trigger(TriggerMode(trigger_mode))
            self._snapshot = self._read_settings()
            self._t.start(self._buffers)
        except BaseException:
            transport.close()
            raise

    # ------------------------------------------------------------------ public extras
    @property
    def genicam(self) -> GenICamTransport:
        """The transport: other SFNC features for expert use (``camera.genicam.get(...)``).
        Settings changed through it are not re-applied after a reconnect."""
        return self._t

    @property
    def trigger_mode(self) -> TriggerMode:
        self._check_open("trigger_mode")
        return cast(TriggerMode, self._snapshot["trigger"])

    @trigger_mode.setter
    def trigger_mode(self, mode: TriggerMode | str) -> None:
        self._check_open("set trigger_mode")
        try:
            mode = TriggerMode(mode)
        except ValueError:
            raise ValueError(f"{self.name}: trigger mode must be one of "
                             f"{[m.value for m in TriggerMode]}, got {mode!r}") from None
        with self._device("set trigger_mode"), self._grab_paused():
            self._set_trigger(mode)
            self._snapshot["trigger"] = mode
        self.invalidate()

    @property
    def hardware_line(self) -> str:
        """The input line a hardware trigger comes on."""
        return self._hardware_line

    @property
    def black_level_range(self) -> tuple[float, float]:
        self._check_open("black_level_range")
        with self._device("black_level_range"):
            low, high, _ = self._t.limits("BlackLevel")
        return low, high

    @property
    def black_level(self) -> float:
        """Offset added to every pixel, in the camera's units (SFNC ``BlackLevel``; DN at
        the present pixel format on most cameras)."""
        self._check_open("black_level")
        return cast(float, self._snapshot["black_level"])

    @black_level.setter
    def black_level(self, value: float) -> None:
        self._check_open("set black_level")
        value = float(value)
        low, high = self.black_level_range
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{self.name}: black level {value:g} outside [{low:g}, {high:g}]")
        with self._device("set black_level"):
            self._t.set("BlackLevel", value)
            self._snapshot["black_level"] = float(self._t.get("BlackLevel"))
        self.invalidate()

    @property
    def pixel_formats(self) -> tuple[PixelFormat, ...]:
        """The formats of :class:`~drivers.base.PixelFormat` this camera offers."""
        self._check_open("pixel_formats")
        with self._device("pixel_formats"):
            offered = set(self._t.choices("PixelFormat"))
        return tuple(f for f, sfnc in SFNC_PIXEL_FORMATS.items() if sfnc in offered)

    def buffer_counts(self) -> dict[str, int]:
        """The transport's buffers: queued for the camera, ready for the driver, in all."""
        self._check_open("buffer_counts")
        with self._device("buffer_counts"):
            return self._t.buffer_counts()

    def reconnect(self) -> None:
        """Open the camera with the same serial number again and reapply the settings."""
        self._check_open("reconnect")
        with self._lock:
            self._reconnect()

    # ------------------------------------------------------------------ internals
    @contextmanager
    def _device(self, command: str) -> Iterator[None]:
        """Serialise access; reconnect first after a loss; mark the camera lost when the
        transport says it is gone."""
        with self._lock:
            if self._lost is not None:
                if not self._loss_reported:  # noticed by invalidate(): say so once
                    self._loss_reported = True
                    raise ConnectionFailed(self._lost.message, device=self.name,
                                           command=command, hint=self._lost.hint)
                self._reconnect()
            try:
                yield
            except ConnectionFailed as err:
                self._lost, self._loss_reported = err, True
                raise
            except DeviceError as err:
                if self._t.is_removed():
                    self._lost, self._loss_reported = ConnectionFailed(
                        "the camera was removed", device=self.name, command=command,
                        hint=f"plug it back in (s/n {self._t.serial}); the next operation "
                        "reopens it"), True
                    raise self._lost from err
                raise

    def _reconnect(self) -> None:
        """Reopen by serial and reapply the settings; the camera counts as lost until all
        of it succeeded (a failure midway is retried whole by the next operation)."""
        self._t.reconnect()
        self._pending.clear()
        snap = self._snapshot
        self._configure_fixed()
        self._set_format(snap["format"])
        self._apply_binning_roi(snap["binning"], snap["roi"])
        self._t.set("ExposureTime", snap["exposure_us"])
        if self._t.has("Gain"):
            self._t.set("Gain", snap["gain"])
        if self._t.has("BlackLevel"):
            self._t.set("BlackLevel", snap["black_level"])
        self._set_trigger(snap["trigger"])
        self._snapshot = self._read_settings()
        self._t.start(self._buffers)
        self._lost = None

    @contextmanager
    def _grab_paused(self) -> Iterator[None]:
        """Format, ROI, binning and trigger features are locked while the camera grabs."""
        self._t.stop()
        self._pending.clear()
        try:
            yield
        finally:
            self._t.start(self._buffers)

    def _configure_fixed(self) -> None:
        """Settings a measurement camera must hold: no automatic exposure or gain, frame
        start as the trigger being configured."""
        for feature in ("ExposureAuto", "GainAuto"):
            if self._t.has(feature) and "Off" in self._t.choices(feature):
                self._t.set(feature, "Off")
        if self._t.has("ExposureMode") and "Timed" in self._t.choices("ExposureMode"):
            self._t.set("ExposureMode", "Timed")
        self._t.set("TriggerSelector", "FrameStart")
        self._chunks: tuple[str, ...] = ()
        if self._t.has("ChunkModeActive") and self._t.has("ChunkSelector"):
            offered = self._t.choices("ChunkSelector")
            self._t.set("ChunkModeActive", True)
            chunks = []
            for chunk in WANTED_CHUNKS:
                if chunk in offered:
                    self._t.set("ChunkSelector", chunk)
                    self._t.set("ChunkEnable", True)
                    chunks.append(chunk)
            self._chunks = tuple(chunks)

    def _format_from_camera(self) -> PixelFormat:
        now = self._t.get("PixelFormat")
        for fmt, sfnc in SFNC_PIXEL_FORMATS.items():
            if sfnc == now:
                return fmt
        return PixelFormat.MONO8

    def _set_format(self, fmt: PixelFormat) -> None:
        sfnc = SFNC_PIXEL_FORMATS[fmt]
        offered = self._t.choices("PixelFormat")
        if sfnc not in offered:
            mono = [s for s in offered if s in SFNC_PIXEL_FORMATS.values()]
            raise UnsupportedFeature(
                f"the camera does not offer {sfnc}", device=self.name,
                command="set pixel_format", hint=f"it offers {', '.join(mono) or 'no mono'} "
                "format(s)")
        self._t.set("PixelFormat", sfnc)

    def _set_trigger(self, mode: TriggerMode) -> None:
        if mode is TriggerMode.FREE_RUN:
            self._t.set("TriggerMode", "Off")
            return
        source = "Software" if mode is TriggerMode.SOFTWARE else self._hardware_line
        if source not in self._t.choices("TriggerSource"):
            raise UnsupportedFeature(
                f"the camera has no trigger source {source!r}", device=self.name,
                command="set trigger_mode",
                hint=f"its sources: {', '.join(self._t.choices('TriggerSource'))}")
        self._t.set("TriggerSource", source)
        if mode is TriggerMode.HARDWARE and self._t.has("TriggerActivation"):
            self._t.set("TriggerActivation", "RisingEdge")
        self._t.set("TriggerMode", "On")

    def _binning_now(self) -> int:
        if not self._t.has("BinningHorizontal"):
            return 1
        return int(self._t.get("BinningHorizontal"))

    def _roi_now(self, b: int) -> Roi:
        g = self._t.get
        return Roi(int(g("OffsetX")) * b, int(g("OffsetY")) * b, int(g("Width")) * b,
                   int(g("Height")) * b)

    def _read_settings(self) -> dict[str, Any]:
        b = self._binning_now()
        self.exposure_range_us = self._t.limits("ExposureTime")[:2]
        if self._t.has("Gain"):
            self.gain_range = self._t.limits("Gain")[:2]
        trigger = (TriggerMode.FREE_RUN if self._t.get("TriggerMode") == "Off"
                   else TriggerMode.SOFTWARE if self._t.get("TriggerSource") == "Software"
                   else TriggerMode.HARDWARE)
        return {
            "format": self._format_from_camera(),
            "binning": b,
            "roi": self._roi_now(b),
            "exposure_us": float(self._t.get("ExposureTime")),
            "gain": float(self._t.get("Gain")) if self._t.has("Gain") else 0.0,
            "black_level": (float(self._t.get("BlackLevel")) if self._t.has("BlackLevel")
                            else 0.0),
            "trigger": trigger,
        }

    def _apply_binning_roi(self, b: int, roi: Roi) -> None:
        """Binning first (it rescales the size features), then the region in binned
        pixels: offsets to 0, size, then offsets, so that no intermediate step exceeds
        the sensor."""
        for feature in ("BinningHorizontal", "BinningVertical"):
            if self._t.has(feature):
                self._t.set(feature, b)
            elif b != 1:
                raise UnsupportedFeature(f"the camera has no {feature}", device=self.name,
                                         command="set binning")
        self._t.set("OffsetX", 0)
        self._t.set("OffsetY", 0)
        for feature, value in (("Width", roi.width // b), ("Height", roi.height // b),
                               ("OffsetX", roi.x // b), ("OffsetY", roi.y // b)):
            low, _high, inc = self._t.limits(feature)
            if inc > 1 and (value - low) % inc:
                raise UnsupportedFeature(
                    f"{feature} {value} (binned px) is not on the camera's {inc:g}-pixel grid",
                    device=self.name, command="set roi",
                    hint=f"use multiples of {inc * b:g} unbinned pixels")
            self._t.set(feature, value)

    def _check_roi_fits_binning(self, roi: Roi, b: int) -> None:
        if any(v % b for v in (roi.x, roi.y, roi.width, roi.height)):
            raise ValueError(f"{self.name}: ROI {roi} is not a multiple of the binning {b}")

    # ------------------------------------------------------------------ hooks
    def _do_identity(self) -> DeviceIdentity:
        with self._device("identity"):
            return self._t.identity()

    def _do_sensor_shape(self) -> tuple[int, int]:
        with self._device("sensor_shape"):
            if self._t.has("SensorHeight"):
                return int(self._t.get("SensorHeight")), int(self._t.get("SensorWidth"))
            b = self._binning_now()
            return int(self._t.get("HeightMax")) * b, int(self._t.get("WidthMax")) * b

    def _do_get_exposure_us(self) -> float:
        return cast(float, self._snapshot["exposure_us"])

    def _do_set_exposure_us(self, value: float) -> None:
        with self._device("set exposure_us"):
            self._t.set("ExposureTime", value)
            # cameras round to their own step (a line time, a clock tick): keep what it took
            self._snapshot["exposure_us"] = float(self._t.get("ExposureTime"))

    def _do_get_gain(self) -> float:
        return cast(float, self._snapshot["gain"])

    def _do_set_gain(self, value: float) -> None:
        with self._device("set gain"):
            if not self._t.has("Gain"):
                raise UnsupportedFeature("the camera has no Gain feature", device=self.name,
                                         command="set gain")
            self._t.set("Gain", value)
            self._snapshot["gain"] = float(self._t.get("Gain"))

    def _do_get_roi(self) -> Roi:
        return cast(Roi, self._snapshot["roi"])

    def _do_set_roi(self, roi: Roi) -> None:
        b = self._snapshot["binning"]
        self._check_roi_fits_binning(roi, b)
        with self._device("set roi"), self._grab_paused():
            try:
                self._apply_binning_roi(b, roi)
            finally:
                self._snapshot = self._read_settings()

    def _do_get_binning(self) -> int:
        return cast(int, self._snapshot["binning"])

    def _do_set_binning(self, value: int) -> None:
        with self._device("set binning"):
            if value != 1 and not self._t.has("BinningHorizontal"):
                raise UnsupportedFeature("the camera has no binning", device=self.name,
                                         command="set binning")
            low, high, _ = self._t.limits("BinningHorizontal") if value != 1 else (1, 1, 0)
            if not low <= value <= high:
                raise UnsupportedFeature(
                    f"binning {value} is not supported ({low:g} to {high:g})",
                    device=self.name, command="set binning")
            roi = self._snapshot["roi"]
            # keep the region: its edges snap inwards to the new binning's grid
            x, y = -(-roi.x // value) * value, -(-roi.y // value) * value
            w = (roi.x + roi.width - x) // value * value
            h = (roi.y + roi.height - y) // value * value
            with self._grab_paused():
                try:
                    self._apply_binning_roi(value, Roi(x, y, max(w, value), max(h, value)))
                finally:
                    self._snapshot = self._read_settings()

    def _do_get_pixel_format(self) -> PixelFormat:
        return cast(PixelFormat, self._snapshot["format"])

    def _do_set_pixel_format(self, fmt: PixelFormat) -> None:
        with self._device("set pixel_format"), self._grab_paused():
            try:
                self._set_format(fmt)
            finally:
                # limits (exposure, black level) may depend on the format
                self._snapshot = self._read_settings()

    def _do_invalidate(self) -> None:
        # Restarting the grab discards queued buffers and the exposure in flight; cheap
        # (well under a millisecond on pylon) next to a move.
        try:
            with self._device("invalidate"):
                self._t.stop()
                self._pending.clear()
                self._t.start(self._buffers)
        except ConnectionFailed:
            # A camera that is gone holds no stale frame, and the reconnect starts a fresh
            # grab. The engine invalidates after every move, outside its retry policy: the
            # loss is reported by the next operation that needs the camera (an acquire,
            # inside the retry policy), and the one after it reopens the camera.
            self._pending.clear()
            self._loss_reported = False

    def _do_trigger(self) -> None:
        with self._device("trigger"):
            mode = self._snapshot["trigger"]
            if mode is not TriggerMode.SOFTWARE:
                raise StateError(
                    f"a software trigger is refused in {mode.value} mode", device=self.name,
                    command="trigger", hint="set trigger_mode = 'software' first")
            self._send_trigger()
            self._pending.append(self._grab("trigger", 2.0 + 2.0 * self._exposure_s()))

    def _send_trigger(self) -> None:
        self._t.wait_trigger_ready(TRIGGER_READY_S + self._snapshot["exposure_us"] * 1e-6)
        self._t.execute("TriggerSoftware")

    def _exposure_s(self) -> float:
        return cast(float, self._snapshot["exposure_us"]) * 1e-6

    def _do_acquire_one(self, timeout: float) -> Frame:
        with self._device("acquire"):
            if self._pending:
                return self._pending.popleft()
            if self._snapshot["trigger"] is TriggerMode.SOFTWARE:
                self._send_trigger()
            return self._grab("acquire", timeout)

    def _grab(self, command: str, timeout: float) -> Frame:
        """The next frame from the transport as a :class:`Frame` (lock held)."""
        snap = self._snapshot
        mode = snap["trigger"]
        try:
            grabbed = self._t.retrieve(timeout)
        except DeviceTimeout as err:
            if mode is TriggerMode.HARDWARE:
                raise DeviceTimeout(
                    f"no frame within {timeout:g} s: no trigger pulse on "
                    f"{self._hardware_line}?", device=self.name, command=command,
                    hint="check the trigger cable and the pulse source, or use "
                    "trigger_mode 'software'") from err
            raise DeviceTimeout(f"no frame within {timeout:g} s", device=self.name,
                                command=command, hint=err.hint) from err
        stamp = time.time()
        index = self._index
        self._index += 1
        fmt, b = snap["format"], snap["binning"]
        chunks = grabbed.chunks
        exposure = chunks.get("ExposureTime", snap["exposure_us"])
        return Frame(
            data=grabbed.data, index=index, timestamp=stamp, exposure_us=float(exposure),
            gain=snap["gain"], saturation_dn=float(2**fmt.bit_depth - 1),
            bit_depth=fmt.bit_depth, roi=snap["roi"], binning=b,
            metadata={
                "frame_id": int(chunks.get("FrameID", grabbed.frame_id)),
                "device_timestamp": int(chunks.get("Timestamp", grabbed.device_timestamp)),
                "exposure_source": "chunk" if "ExposureTime" in chunks else "camera setting",
                "pixel_format": grabbed.pixel_format,
                "black_level": snap["black_level"],
                "trigger": mode.value,
                "serial": self._t.serial,
            },
        )

    def _do_close_camera(self) -> None:
        with self._lock:
            self._t.close()
