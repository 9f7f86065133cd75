"""Abstract base classes, one per device kind.

The pattern: a public method validates its arguments and the device state, then calls
a ``_do_*`` hook that a concrete driver implements. Hooks raise a
:mod:`drivers.errors` exception on failure; they never return an error flag. Out-of-range
targets raise *before* any motion (nothing is clipped silently).

Lifecycle: every device is a context manager, ``close()`` is idempotent, and a device
that failed in its constructor has closed whatever it had opened. No ``__del__``.

Units are part of the names or stated here: rotary axes work in degrees, linear axes in
millimetres, velocities in units/s, accelerations in units/s², exposures in
microseconds, optical power in watts, wavelengths in nanometres.
"""

from __future__ import annotations

import contextlib
import enum
import math
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Self

import numpy as np

from drivers.errors import (
    DeviceError,
    DeviceTimeout,
    LimitError,
    MotionError,
    NotHomedError,
    StateError,
    UnsupportedFeature,
)

__all__ = [
    "AxisKind",
    "AxisStatus",
    "Camera",
    "Device",
    "DeviceIdentity",
    "FilterSpec",
    "FilterWheel",
    "Frame",
    "FrameRing",
    "LightSource",
    "MotionAxis",
    "PixelFormat",
    "PowerMeter",
    "Roi",
    "Shutter",
    "ShutterState",
    "WavelengthSetting",
    "WheelSpeed",
    "check_settings",
    "finite_positive",
    "parse_filters",
    "retry_count",
]


# --------------------------------------------------------------------------- devices


@dataclass(frozen=True)
class DeviceIdentity:
    """Who a device says it is. Stored with every run for provenance."""

    vendor: str
    model: str
    serial: str
    firmware: str = ""
    extra: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "vendor": self.vendor,
            "model": self.model,
            "serial": self.serial,
            "firmware": self.firmware,
            **{f"extra.{k}": v for k, v in self.extra.items()},
        }


class Device(ABC):
    """Common lifecycle of every device.

    Parameters
    ----------
    name
        The role name the bench profile gives the device; every error names it.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._closed = False
        self._identity: DeviceIdentity | None = None

    # lifecycle ----------------------------------------------------------------
    def close(self) -> None:
        """Release the device. Safe to call any number of times."""
        if self._closed:
            return
        self._closed = True
        self._do_close()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _check_open(self, command: str) -> None:
        if self._closed:
            raise StateError(
                "device is closed", device=self.name, command=command,
                hint="open a new connection",
            )

    @property
    def identity(self) -> DeviceIdentity:
        """Vendor, model, serial number and firmware as reported by the device."""
        self._check_open("identity")
        if self._identity is None:
            self._identity = self._do_identity()
        return self._identity

    @abstractmethod
    def _do_identity(self) -> DeviceIdentity: ...

    @abstractmethod
    def _do_close(self) -> None: ...

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<{type(self).__name__} {self.name!r} {state}>"



# --------------------------------------------------------------------------- settings checks
# The checks every driver's constructor makes of its link and device settings, so that a
# bad bench profile value is refused the same way (a ValueError naming the setting)
# whichever driver it reaches.


def finite_positive(value: float, what: str) -> float:
    """``value`` as a float if it is a finite number > 0; else ``ValueError`` naming
    ``what`` (``TypeError`` for a bool, which would pass as 1)."""
    if isinstance(value, bool):
        raise TypeError(f"{what} must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{what} must be a finite number > 0, got {value}")
    return value


def retry_count(retries: int) -> int:
    """``retries`` (extra attempts after a lost or garbled reply) as an int if it is a
    non-negative whole number; else ``ValueError``."""
    if int(retries) != retries or retries < 0:
        raise ValueError(f"retries must be a non-negative integer, got {retries}")
    return int(retries)


def check_settings(**positive: float) -> None:
    """Each keyword's value must be a finite number > 0 (:func:`finite_positive`)."""
    for what, value in positive.items():
        finite_positive(value, what)


# --------------------------------------------------------------------------- motion


class AxisKind(enum.Enum):
    """Rotary axes work in degrees, linear axes in millimetres."""

    ROTARY = "deg"
    LINEAR = "mm"

    @property
    def units(self) -> str:
        return self.value


def exposure_text(us: float) -> str:
    """An exposure in microseconds as an operator reads it: ``1e8`` → ``"100 s"``,
    ``250`` → ``"250 µs"`` (messages; values stay in µs)."""
    if not math.isfinite(us):
        return f"{us} µs"
    mag = abs(us)
    if mag >= 1e6:
        return f"{us / 1e6:.4g} s"
    if mag >= 1e3:
        return f"{us / 1e3:.4g} ms"
    return f"{us:.4g} µs"


@dataclass(frozen=True)
class AxisStatus:
    """A snapshot of an axis, decoded from the controller's status reply."""

    position: float
    is_moving: bool
    is_homed: bool
    is_enabled: bool
    is_homing: bool = False
    at_forward_limit: bool = False
    at_reverse_limit: bool = False
    error: str | None = None


class MotionAxis(Device):
    """One motion axis (rotation or linear stage).

    Motion is non-blocking: :meth:`move_to`, :meth:`move_by` and :meth:`home` start the
    motion and return; :meth:`wait` blocks until it ends or its timeout passes (then the
    axis is stopped and :class:`~drivers.errors.DeviceTimeout` raised). Passing
    ``wait=True`` does both.

    Parameters
    ----------
    name
        Role name (e.g. ``"sample_theta"``).
    kind
        Rotary (degrees) or linear (millimetres).
    soft_limits
        ``(low, high)`` in axis units; targets outside raise :class:`LimitError` before
        anything moves.
    position_tolerance
        How far from its target a finished move may stop and still count as arrived
        (stepper and servo controllers often stop a few counts short).
    poll_interval
        Seconds between status polls while waiting.
    """

    def __init__(
        self,
        name: str,
        *,
        kind: AxisKind,
        soft_limits: tuple[float, float] = (-math.inf, math.inf),
        position_tolerance: float = 0.01,
        poll_interval: float = 0.01,
    ) -> None:
        super().__init__(name)
        self.kind = kind
        self._soft_limits = (-math.inf, math.inf)
        self.soft_limits = soft_limits
        if not position_tolerance > 0:
            raise ValueError("position_tolerance must be > 0")
        self.position_tolerance = float(position_tolerance)
        self.poll_interval = float(poll_interval)
        self._target: float | None = None

    @property
    def units(self) -> str:
        return self.kind.units

    # limits -------------------------------------------------------------------
    @property
    def soft_limits(self) -> tuple[float, float]:
        return self._soft_limits

    @soft_limits.setter
    def soft_limits(self, limits: tuple[float, float]) -> None:
        low, high = (float(v) for v in limits)
        if math.isnan(low) or math.isnan(high) or not low < high:
            raise ValueError(f"soft limits must satisfy low < high, got ({low}, {high})")
        self._soft_limits = (low, high)

    def check_target(self, target: float, command: str = "move") -> float:
        """Return ``target`` as float, or raise :class:`LimitError` if it is out of range."""
        target = float(target)
        low, high = self._soft_limits
        if not math.isfinite(target):
            raise ValueError(f"{self.name}: target must be finite, got {target}")
        if not low <= target <= high:
            raise LimitError(
                f"target {target:g} {self.units} is outside the soft limits "
                f"[{low:g}, {high:g}] {self.units}",
                device=self.name, command=command,
                hint="choose a target inside the limits or change them in the bench profile",
            )
        return target

    # state --------------------------------------------------------------------
    def status(self) -> AxisStatus:
        self._check_open("status")
        return self._do_status()

    @property
    def position(self) -> float:
        """Actual position in axis units."""
        self._check_open("position")
        return self._do_get_position()

    @property
    def is_moving(self) -> bool:
        return self.status().is_moving

    @property
    def is_homed(self) -> bool:
        return self.status().is_homed

    @property
    def is_enabled(self) -> bool:
        return self.status().is_enabled

    @property
    def target(self) -> float | None:
        """The last commanded target, or ``None`` before any move."""
        return self._target

    # commands -----------------------------------------------------------------
    def enable(self) -> None:
        self._check_open("enable")
        self._do_enable()

    def disable(self) -> None:
        self._check_open("disable")
        self._do_disable()

    def home(self, *, wait: bool = True, timeout: float = 120.0) -> None:
        """Find the reference position (the axis's zero). The axis must be enabled."""
        self._check_open("home")
        if not self._do_status().is_enabled:
            raise StateError("axis is disabled", device=self.name, command="home",
                             hint="call enable() first")
        self._target = None
        self._do_home()
        if wait:
            self._wait_for(lambda s: s.is_homed and not s.is_homing and not s.is_moving,
                           timeout, "home")
            self._target = None

    def move_to(self, target: float, *, wait: bool = False, timeout: float = 60.0) -> None:
        """Start a move to an absolute ``target`` in axis units."""
        self._check_open("move_to")
        target = self.check_target(target, "move_to")
        self._require_ready("move_to")
        self._target = target
        self._do_move_absolute(target)
        if wait:
            self.wait(timeout)

    def move_by(self, delta: float, *, wait: bool = False, timeout: float = 60.0) -> None:
        """Start a move by ``delta`` from the present target (or position)."""
        self._check_open("move_by")
        delta = float(delta)
        if not math.isfinite(delta):
            raise ValueError(f"{self.name}: delta must be finite, got {delta}")
        base = self._target if self._target is not None else self._do_get_position()
        target = self.check_target(base + delta, "move_by")
        self._require_ready("move_by")
        self._target = target
        self._do_move_relative(delta, target)
        if wait:
            self.wait(timeout)

    def wait(self, timeout: float = 60.0) -> float:
        """Block until motion ends; return the final position.

        Raises
        ------
        DeviceTimeout
            The axis was still moving after ``timeout`` seconds; it has been stopped.
        MotionError
            It stopped farther than ``position_tolerance`` from the commanded target.
        """
        self._check_open("wait")
        status = self._wait_for(lambda s: not s.is_moving, timeout, "wait")
        if status.at_forward_limit or status.at_reverse_limit:
            raise LimitError(
                f"a limit switch stopped the axis at {status.position:.6g} {self.units}",
                device=self.name, command="wait",
                hint="check the soft limits against the stage travel and re-home",
            )
        if self._target is not None:
            miss = status.position - self._target
            if abs(miss) > self.position_tolerance:
                raise MotionError(
                    f"stopped at {status.position:.6g} {self.units}, "
                    f"{miss:+.3g} {self.units} from the target {self._target:.6g}",
                    device=self.name, command="wait",
                    hint="check for obstruction or following errors; "
                    "raise position_tolerance only if the stage is known to stop short",
                )
        return status.position

    def stop(self) -> None:
        """Stop any motion now. Always allowed, also on a device in error.

        The commanded target is forgotten: a later :meth:`wait` checks no arrival, and a
        :meth:`move_by` counts from where the axis came to rest.
        """
        if self._closed:
            return
        self._target = None
        self._do_stop()

    @property
    def velocity(self) -> float:
        """Maximum move velocity in units/s."""
        self._check_open("velocity")
        return self._do_get_velocity()

    @velocity.setter
    def velocity(self, value: float) -> None:
        self._check_open("set velocity")
        value = finite_positive(value, "velocity")
        self._do_set_velocity(value)

    @property
    def acceleration(self) -> float:
        """Acceleration in units/s²."""
        self._check_open("acceleration")
        return self._do_get_acceleration()

    @acceleration.setter
    def acceleration(self, value: float) -> None:
        self._check_open("set acceleration")
        value = finite_positive(value, "acceleration")
        self._do_set_acceleration(value)

    # helpers ------------------------------------------------------------------
    def _require_ready(self, command: str) -> None:
        status = self._do_status()
        if not status.is_enabled:
            raise StateError("axis is disabled", device=self.name, command=command,
                             hint="call enable() first")
        if not status.is_homed:
            raise NotHomedError("axis is not homed", device=self.name, command=command,
                                hint="call home() first")
        # A controller in an error state may take the move and refuse it later, or carry
        # it out from a position it no longer trusts: refuse here, saying how to clear it.
        if status.error:
            self._raise_status_error(status, command)

    def _wait_for(self, done: Callable[[AxisStatus], bool], timeout: float,
                  command: str) -> AxisStatus:
        if not timeout > 0:
            raise ValueError("timeout must be > 0")
        deadline = time.monotonic() + timeout
        while True:
            try:
                status = self._do_status()
            except DeviceError:
                # Whatever broke the poll, the stage must not keep moving unattended.
                with contextlib.suppress(DeviceError):
                    self.stop()
                raise
            if status.error:
                self.stop()
                self._raise_status_error(status, command)
            if done(status):
                return status
            if time.monotonic() >= deadline:
                self.stop()
                raise DeviceTimeout(
                    f"still not done after {timeout:g} s (position {status.position:.6g} "
                    f"{self.units}); motion stopped",
                    device=self.name, command=command,
                    hint="raise the timeout or check velocity/homing parameters",
                )
            time.sleep(self.poll_interval)

    def _raise_status_error(self, status: AxisStatus, command: str) -> None:
        """Turn a status with ``error`` set into an exception; drivers may refine it."""
        from drivers.errors import ControllerError

        raise ControllerError(status.error or "controller error", device=self.name,
                              command=command,
                              hint="enable() clears the controller's error; home() again "
                                   "if the axis may have lost its position")

    # hooks --------------------------------------------------------------------
    @abstractmethod
    def _do_status(self) -> AxisStatus: ...

    def _do_get_position(self) -> float:
        return self._do_status().position

    @abstractmethod
    def _do_enable(self) -> None: ...

    @abstractmethod
    def _do_disable(self) -> None: ...

    @abstractmethod
    def _do_home(self) -> None: ...

    @abstractmethod
    def _do_move_absolute(self, target: float) -> None: ...

    def _do_move_relative(self, delta: float, target: float) -> None:
        """Default: an absolute move to the validated ``target``."""
        self._do_move_absolute(target)

    @abstractmethod
    def _do_stop(self) -> None: ...

    @abstractmethod
    def _do_get_velocity(self) -> float: ...

    @abstractmethod
    def _do_set_velocity(self, value: float) -> None: ...

    @abstractmethod
    def _do_get_acceleration(self) -> float: ...

    @abstractmethod
    def _do_set_acceleration(self, value: float) -> None: ...


# --------------------------------------------------------------------------- camera


class PixelFormat(enum.Enum):
    """Monochrome pixel formats; the number is the significant bit depth."""

    MONO8 = 8
    MONO10 = 10
    MONO12 = 12
    MONO16 = 16

    @property
    def bit_depth(self) -> int:
        return self.value

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.uint8 if self.value <= 8 else np.uint16)


@dataclass(frozen=True)
class Roi:
    """Region of interest in unbinned sensor pixels: origin (x, y) and size."""

    x: int
    y: int
    width: int
    height: int

    def validate(self, sensor_width: int, sensor_height: int) -> Roi:
        values = (self.x, self.y, self.width, self.height)
        if any(int(v) != v for v in values):
            raise ValueError(f"ROI fields must be integers, got {self}")
        if self.x < 0 or self.y < 0 or self.width < 1 or self.height < 1:
            raise ValueError(f"ROI must have x, y >= 0 and a positive size, got {self}")
        if self.x + self.width > sensor_width or self.y + self.height > sensor_height:
            raise ValueError(
                f"ROI {self} exceeds the sensor ({sensor_width} x {sensor_height} px)"
            )
        return self


@dataclass(frozen=True)
class Frame:
    """One image with the settings it was actually taken with.

    ``data`` has shape (height, width) in DN; ``timestamp`` is seconds since the epoch
    at the end of the exposure; ``saturation_dn`` is the level at or above which a pixel
    must be treated as saturated.
    """

    data: np.ndarray
    index: int
    timestamp: float
    exposure_us: float
    gain: float
    saturation_dn: float
    bit_depth: int
    roi: Roi
    binning: int = 1
    metadata: dict[str, Any] = field(default_factory=dict)


class FrameRing:
    """A bounded, thread-safe ring buffer of frames that counts what it drops.

    When full, the oldest frame is dropped (and counted): a slow consumer sees the most
    recent frames, never an unbounded backlog.

    Every :meth:`clear` starts a new *epoch*. A producer reads :attr:`epoch` before it
    starts an exposure and hands it to :meth:`put`; a frame from an earlier epoch (exposed
    before the clear, e.g. before a settings change or a move) is discarded, not buffered
    and not counted as dropped.
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self._frames: deque[Frame] = deque()
        self._capacity = int(capacity)
        self._dropped = 0
        self._epoch = 0
        self._cond = threading.Condition()

    @property
    def capacity(self) -> int:
        return self._capacity

    @property
    def dropped(self) -> int:
        with self._cond:
            return self._dropped

    @property
    def epoch(self) -> int:
        """Number of :meth:`clear` calls so far."""
        with self._cond:
            return self._epoch

    def __len__(self) -> int:
        with self._cond:
            return len(self._frames)

    def put(self, frame: Frame, *, epoch: int | None = None) -> bool:
        """Buffer ``frame``; return False (and keep nothing) if ``epoch`` is given and a
        :meth:`clear` happened since the producer read it."""
        with self._cond:
            if epoch is not None and epoch != self._epoch:
                return False
            if len(self._frames) >= self._capacity:
                self._frames.popleft()
                self._dropped += 1
            self._frames.append(frame)
            self._cond.notify_all()
            return True

    def get(self, timeout: float) -> Frame | None:
        """Oldest buffered frame, waiting up to ``timeout`` s; ``None`` if none came."""
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._frames), timeout):
                return None
            return self._frames.popleft()

    def clear(self) -> int:
        """Discard everything buffered and start a new epoch; return how many frames
        were discarded (they are not counted as dropped)."""
        with self._cond:
            n = len(self._frames)
            self._frames.clear()
            self._epoch += 1
            return n


class Camera(Device):
    """An area camera delivering monochrome frames.

    Stale-frame policy: any change of exposure, gain, ROI, binning or pixel format, and
    any call to :meth:`invalidate` (the engine calls it after every move), discards the
    frames buffered so far; the next frame returned by :meth:`acquire` started its
    exposure after the change. Drivers whose backend buffers internally discard
    ``stale_frames`` frames in :meth:`_do_invalidate`.

    Units: exposure in µs (``NaN`` where a backend cannot report it, e.g. a file source),
    gain in the device's units (dB for the simulated camera), ROI in unbinned sensor
    pixels; ``Frame.data`` has shape (roi.height // binning, roi.width // binning).
    Streaming (:meth:`start_streaming`) fills a bounded :class:`FrameRing` from a worker
    thread; when the consumer falls behind, the oldest frames are dropped and counted in
    :attr:`dropped_frames`. ``acquire`` is refused while streaming.
    """

    #: Exposure range in microseconds, (min, max); drivers override.
    exposure_range_us: tuple[float, float] = (1.0, 60e6)
    #: Gain range in the device's units, (min, max); drivers override.
    gain_range: tuple[float, float] = (0.0, 0.0)

    def __init__(self, name: str, *, ring_capacity: int = 16) -> None:
        super().__init__(name)
        self._ring = FrameRing(ring_capacity)
        self._stream_thread: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self._stream_error: BaseException | None = None

    # settings -----------------------------------------------------------------
    @property
    def sensor_shape(self) -> tuple[int, int]:
        """(height, width) of the full sensor in unbinned pixels."""
        return self._do_sensor_shape()

    @property
    def exposure_us(self) -> float:
        self._check_open("exposure_us")
        return self._do_get_exposure_us()

    @exposure_us.setter
    def exposure_us(self, value: float) -> None:
        self._check_open("set exposure_us")
        value = float(value)
        low, high = self.exposure_range_us
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(
                f"{self.name}: exposure {exposure_text(value)} outside "
                f"[{exposure_text(low)}, {exposure_text(high)}]"
            )
        self._do_set_exposure_us(value)
        self.invalidate()

    @property
    def gain(self) -> float:
        self._check_open("gain")
        return self._do_get_gain()

    @gain.setter
    def gain(self, value: float) -> None:
        self._check_open("set gain")
        value = float(value)
        low, high = self.gain_range
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{self.name}: gain {value:g} outside [{low:g}, {high:g}]")
        self._do_set_gain(value)
        self.invalidate()

    @property
    def roi(self) -> Roi:
        self._check_open("roi")
        return self._do_get_roi()

    @roi.setter
    def roi(self, roi: Roi) -> None:
        self._check_open("set roi")
        height, width = self.sensor_shape
        self._do_set_roi(roi.validate(width, height))
        self.invalidate()

    @property
    def binning(self) -> int:
        self._check_open("binning")
        return self._do_get_binning()

    @binning.setter
    def binning(self, value: int) -> None:
        self._check_open("set binning")
        if int(value) != value or value < 1:
            raise ValueError(f"{self.name}: binning must be a positive integer, got {value}")
        self._do_set_binning(int(value))
        self.invalidate()

    @property
    def pixel_format(self) -> PixelFormat:
        self._check_open("pixel_format")
        return self._do_get_pixel_format()

    @pixel_format.setter
    def pixel_format(self, fmt: PixelFormat) -> None:
        self._check_open("set pixel_format")
        if not isinstance(fmt, PixelFormat):
            raise TypeError(f"{self.name}: pixel_format must be a PixelFormat, got {fmt!r}")
        self._do_set_pixel_format(fmt)
        self.invalidate()

    @property
    def bit_depth(self) -> int:
        return self.pixel_format.bit_depth

    # acquisition --------------------------------------------------------------
    def invalidate(self) -> None:
        """Forget buffered frames: the scene or the settings changed."""
        if not self._closed:
            self._do_invalidate()
        # After the backend's discard: a stream frame read from the backend's queue while
        # it was being emptied carries the old epoch and is dropped by the ring.
        self._ring.clear()

    def trigger(self) -> None:
        """Software trigger: start one exposure now.

        The triggered frames are returned, in order, by the next :meth:`acquire` calls
        before any new exposure starts; :meth:`invalidate` discards them.
        """
        self._check_open("trigger")
        self._do_trigger()

    def acquire(self, n: int = 1, *, timeout: float | None = None) -> list[Frame]:
        """Take ``n`` fresh frames and return them in order.

        ``timeout`` (for all ``n`` frames) defaults to ``n`` × (2 s + twice the exposure).
        """
        self._check_open("acquire")
        if int(n) != n or n < 1:
            raise ValueError(f"{self.name}: n must be a positive integer, got {n}")
        if self.is_streaming:
            raise StateError("camera is streaming", device=self.name, command="acquire",
                             hint="stop_streaming() first, or read from the stream")
        if timeout is None:
            timeout = int(n) * (2.0 + 2.0 * self._exposure_s_for_timeout())
        deadline = time.monotonic() + timeout
        frames: list[Frame] = []
        for _ in range(int(n)):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(
                    f"only {len(frames)} of {n} frames within {timeout:g} s",
                    device=self.name, command="acquire",
                )
            frames.append(self._do_acquire_one(remaining))
        return frames

    # streaming ----------------------------------------------------------------
    @property
    def is_streaming(self) -> bool:
        return self._stream_thread is not None and self._stream_thread.is_alive()

    @property
    def dropped_frames(self) -> int:
        """Frames the stream dropped because the consumer fell behind (ring full)."""
        return self._ring.dropped

    @property
    def ring_capacity(self) -> int:
        """How many frames the stream buffers before it drops the oldest."""
        return self._ring.capacity

    @property
    def buffered_frames(self) -> int:
        """Frames waiting in the stream buffer now."""
        return len(self._ring)

    def start_streaming(self) -> None:
        """Acquire continuously into the ring buffer on a background thread."""
        self._check_open("start_streaming")
        if self.is_streaming:
            return
        self._stream_stop.clear()
        self._stream_error = None
        self._ring.clear()
        self._stream_thread = threading.Thread(
            target=self._stream_loop, name=f"{self.name}-stream", daemon=True
        )
        self._stream_thread.start()

    def stop_streaming(self, timeout: float | None = None) -> None:
        """Stop the stream after the exposure in progress; buffered frames stay readable.

        ``timeout`` defaults to the stream's own per-frame limit (2 s + twice the exposure).
        """
        thread = self._stream_thread
        if thread is None:
            return
        self._stream_stop.set()
        if timeout is None:
            timeout = 2.0 + 2.0 * self._exposure_s_for_timeout()
        thread.join(timeout)
        if thread.is_alive():
            raise DeviceTimeout("streaming thread did not stop", device=self.name,
                                command="stop_streaming")
        self._stream_thread = None

    def next_frame(self, timeout: float = 1.0) -> Frame:
        """Oldest frame in the stream buffer; raises if none arrives within ``timeout``."""
        frame = self._ring.get(timeout)
        if frame is None:
            if self._stream_error is not None:
                raise self._stream_error
            raise DeviceTimeout(f"no frame within {timeout:g} s", device=self.name,
                                command="next_frame")
        return frame

    def _stream_loop(self) -> None:
        try:
            while not self._stream_stop.is_set():
                # Read the epoch before the exposure starts: a frame whose exposure began
                # before an invalidate() (settings change, move) is stale and discarded.
                epoch = self._ring.epoch
                exposure_s = self._exposure_s_for_timeout()
                self._ring.put(self._do_acquire_one(2.0 + 2.0 * exposure_s), epoch=epoch)
        except BaseException as err:  # surfaced by next_frame()
            self._stream_error = err

    def _exposure_s_for_timeout(self) -> float:
        """Exposure in seconds for timeouts; 0 where the backend cannot tell (NaN)."""
        exposure_us = self._do_get_exposure_us()
        return exposure_us * 1e-6 if math.isfinite(exposure_us) else 0.0

    def _do_close(self) -> None:
        if self._stream_thread is not None:
            self._stream_stop.set()
            self._stream_thread.join(2.0 + 2.0 * self._exposure_s_for_timeout())
            self._stream_thread = None
        self._do_close_camera()

    # hooks --------------------------------------------------------------------
    @abstractmethod
    def _do_sensor_shape(self) -> tuple[int, int]: ...

    @abstractmethod
    def _do_get_exposure_us(self) -> float: ...

    @abstractmethod
    def _do_set_exposure_us(self, value: float) -> None: ...

    @abstractmethod
    def _do_get_gain(self) -> float: ...

    @abstractmethod
    def _do_set_gain(self, value: float) -> None: ...

    @abstractmethod
    def _do_get_roi(self) -> Roi: ...

    @abstractmethod
    def _do_set_roi(self, roi: Roi) -> None: ...

    def _do_get_binning(self) -> int:
        return 1

    def _do_set_binning(self, value: int) -> None:
        if value != 1:
            raise UnsupportedFeature(f"binning {value} is not supported", device=self.name,
                                     command="set binning")

    @abstractmethod
    def _do_get_pixel_format(self) -> PixelFormat: ...

    def _do_set_pixel_format(self, fmt: PixelFormat) -> None:
        if fmt is not self._do_get_pixel_format():
            raise UnsupportedFeature(f"pixel format {fmt.name} is not supported",
                                     device=self.name, command="set pixel_format")

    def _do_invalidate(self) -> None:
        """Discard frames the backend may have buffered; default: nothing buffered."""

    def _do_trigger(self) -> None:
        raise UnsupportedFeature("software trigger is not supported", device=self.name,
                                 command="trigger")

    @abstractmethod
    def _do_acquire_one(self, timeout: float) -> Frame: ...

    @abstractmethod
    def _do_close_camera(self) -> None: ...


# --------------------------------------------------------------------------- source


class LightSource(Device):
    """A light source or a shutter in front of one.

    ``is_on`` means light reaches the sample (source on *and* shutter open). Dark frames
    are taken with it off; the run engine turns it off on abort and on any fault.
    """

    #: Power setpoint range in watts, or ``None`` where the source has no setpoint.
    power_range_w: tuple[float, float] | None = None

    def turn_on(self) -> None:
        self._check_open("turn_on")
        self._do_set_on(True)

    def turn_off(self) -> None:
        """Turn the light off. Always allowed; a no-op on a closed device."""
        if self._closed:
            return
        self._do_set_on(False)

    @property
    def is_on(self) -> bool:
        self._check_open("is_on")
        return self._do_is_on()

    @property
    def power_w(self) -> float:
        self._check_open("power_w")
        if self.power_range_w is None:
            raise UnsupportedFeature("this source has no power setpoint", device=self.name,
                                     command="power_w")
        return self._do_get_power_w()

    @power_w.setter
    def power_w(self, value: float) -> None:
        self._check_open("set power_w")
        if self.power_range_w is None:
            raise UnsupportedFeature("this source has no power setpoint", device=self.name,
                                     command="set power_w")
        value = float(value)
        low, high = self.power_range_w
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{self.name}: power {value:g} W outside [{low:g}, {high:g}] W")
        self._do_set_power_w(value)

    @abstractmethod
    def _do_set_on(self, on: bool) -> None: ...

    @abstractmethod
    def _do_is_on(self) -> bool: ...

    def _do_get_power_w(self) -> float:
        raise UnsupportedFeature("no power readback", device=self.name, command="power_w")

    def _do_set_power_w(self, value: float) -> None:
        raise UnsupportedFeature("no power setpoint", device=self.name, command="set power_w")


# --------------------------------------------------------------------------- shutter


class ShutterState(enum.Enum):
    """Where a shutter's blade is, as the controller reports it."""

    OPEN = "open"
    CLOSED = "closed"


class Shutter(LightSource):
    """A shutter in front of a source: light reaches the sample while it is open.

    As a :class:`LightSource`, :meth:`turn_on` opens the shutter and :meth:`turn_off`
    closes it (always allowed; a no-op on a closed device), and ``is_on`` is "the blade is
    open". :meth:`open_shutter`/:meth:`close_shutter` say the same in a shutter's words
    (``close`` is taken: it releases the device).
    """

    def open_shutter(self) -> None:
        self.turn_on()

    def close_shutter(self) -> None:
        """Close the shutter. Always allowed; a no-op on a closed device."""
        self.turn_off()

    @property
    def shutter_state(self) -> ShutterState:
        self._check_open("shutter_state")
        return self._do_shutter_state()

    def _do_set_on(self, on: bool) -> None:
        if on:
            self._do_open_shutter()
        else:
            self._do_close_shutter()

    def _do_is_on(self) -> bool:
        return self._do_shutter_state() is ShutterState.OPEN

    @abstractmethod
    def _do_shutter_state(self) -> ShutterState: ...

    @abstractmethod
    def _do_open_shutter(self) -> None: ...

    @abstractmethod
    def _do_close_shutter(self) -> None: ...


# --------------------------------------------------------------------------- filter wheel


class WheelSpeed(enum.Enum):
    """Move profile of a filter wheel."""

    NORMAL = "normal"
    HIGH = "high"


@dataclass(frozen=True)
class FilterSpec:
    """What sits in one filter-wheel slot, as the bench configuration describes it.

    A band-pass filter has a centre wavelength and a full width at half maximum, both in
    nm. A neutral-density filter has an optical density ``od`` (its nominal transmission
    is 10^−od) and may carry a calibrated ``transmission`` with its standard uncertainty
    ``u_transmission`` (from the ND calibration plan or the maker's certificate). A slot
    with none of them is empty (clear aperture, passes everything).
    """

    center_nm: float | None = None
    bandwidth_nm: float | None = None
    label: str = ""
    od: float | None = None
    transmission: float | None = None
    u_transmission: float | None = None

    def __post_init__(self) -> None:
        if (self.center_nm is None) != (self.bandwidth_nm is None):
            raise ValueError("a filter needs both center_nm and bandwidth_nm (or neither, "
                             f"for an empty slot), got {self}")
        if self.center_nm is not None:
            for what, value in (("center_nm", self.center_nm),
                                ("bandwidth_nm", self.bandwidth_nm)):
                if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                    raise ValueError(f"filter {what} must be a finite number > 0, got {value!r}")
        if self.od is not None:
            if self.center_nm is not None:
                raise ValueError("a filter is band-pass (center_nm, bandwidth_nm) or neutral "
                                 f"density (od), not both: {self}")
            if not (isinstance(self.od, int | float) and math.isfinite(self.od)
                    and self.od > 0):
                raise ValueError(f"filter od must be a finite number > 0, got {self.od!r}")
        elif self.transmission is not None or self.u_transmission is not None:
            raise ValueError("transmission and u_transmission belong to a neutral-density "
                             f"filter: give its od too, got {self}")
        if self.transmission is not None and not (
                isinstance(self.transmission, int | float) and 0 < self.transmission <= 1):
            raise ValueError(f"filter transmission must be in (0, 1], got "
                             f"{self.transmission!r}")
        if self.u_transmission is not None and not (
                isinstance(self.u_transmission, int | float)
                and math.isfinite(self.u_transmission) and self.u_transmission >= 0):
            raise ValueError(f"filter u_transmission must be a finite number >= 0, got "
                             f"{self.u_transmission!r}")

    @property
    def is_empty(self) -> bool:
        return self.center_nm is None and self.od is None

    @property
    def is_neutral_density(self) -> bool:
        return self.od is not None

    @classmethod
    def parse(cls, spec: FilterSpec | Mapping[str, Any] | None) -> FilterSpec:
        """A spec from its configuration form: a table ``{center_nm, bandwidth_nm, label}``
        (band-pass) or ``{od, transmission, u_transmission, label}`` (neutral density)."""
        if spec is None:
            return cls()
        if isinstance(spec, FilterSpec):
            return spec
        known = ("center_nm", "bandwidth_nm", "label", "od", "transmission", "u_transmission")
        if not isinstance(spec, Mapping):
            raise TypeError(f"a filter is a table {{center_nm, bandwidth_nm, label}} or "
                            f"{{od, transmission, u_transmission, label}}, got {spec!r}")
        unknown = set(spec) - set(known)
        if unknown:
            raise ValueError(f"unknown filter keys {sorted(unknown)}; known: "
                             + ", ".join(known))
        return cls(center_nm=spec.get("center_nm"), bandwidth_nm=spec.get("bandwidth_nm"),
                   label=str(spec.get("label", "")), od=spec.get("od"),
                   transmission=spec.get("transmission"),
                   u_transmission=spec.get("u_transmission"))


def parse_filters(filters: Mapping[Any, Any] | None) -> dict[int, FilterSpec]:
    """Slot number (1-based; TOML gives string keys) → :class:`FilterSpec`."""
    out: dict[int, FilterSpec] = {}
    for key, spec in (filters or {}).items():
        try:
            slot = int(key)
        except (TypeError, ValueError):
            raise ValueError(f"filter slots are numbered from 1, got {key!r}") from None
        if slot < 1 or str(slot) != str(key).strip():
            raise ValueError(f"filter slots are numbered from 1, got {key!r}")
        out[slot] = FilterSpec.parse(spec)
    return out


class FilterWheel(Device):
    """A motorised filter wheel with numbered slots.

    Positions are 1-based, as the wheel counts them, and checked against the wheel's slot
    count before anything moves (:class:`~drivers.errors.LimitError`). :meth:`move_to`
    blocks until the wheel stands at the slot, for at most ``timeout`` seconds (default:
    ``move_timeout_factor`` × the estimated move time + ``move_timeout_margin_s``), then
    reads the position back: a wheel that stopped elsewhere raises
    :class:`~drivers.errors.MotionError`.

    Parameters
    ----------
    name
        Role name (e.g. ``"filter_wheel"``).
    filters
        Slot → :class:`FilterSpec` (or its table form) from the bench configuration;
        slots not given are empty. Checked against the slot count when the driver knows it.
    """

    def __init__(
        self,
        name: str,
        *,
        filters: Mapping[Any, Any] | None = None,
        move_timeout_factor: float = 3.0,
        move_timeout_margin_s: float = 2.0,
    ) -> None:
        super().__init__(name)
        self._filters = parse_filters(filters)
        self.move_timeout_factor = finite_positive(move_timeout_factor, "move_timeout_factor")
        self.move_timeout_margin_s = float(move_timeout_margin_s)
        if not (math.isfinite(self.move_timeout_margin_s) and self.move_timeout_margin_s >= 0):
            raise ValueError("move_timeout_margin_s must be finite and >= 0")

    # configuration ------------------------------------------------------------
    @property
    def filters(self) -> dict[int, FilterSpec]:
        """The configured filters by slot (a copy)."""
        return dict(self._filters)

    def filter_at(self, position: int) -> FilterSpec:
        """The filter in slot ``position`` (an empty spec where none is configured)."""
        position = self.check_position(position, "filter_at")
        return self._filters.get(position, FilterSpec())

    def _check_filters(self, count: int) -> None:
        """Drivers call this once they know the slot count."""
        outside = sorted(slot for slot in self._filters if not 1 <= slot <= count)
        if outside:
            raise ValueError(f"{self.name}: filters configured for slots {outside}, but the "
                             f"wheel has slots 1..{count}")

    # state ----------------------------------------------------------------------
    @property
    def position_count(self) -> int:
        """Number of slots on the wheel."""
        self._check_open("position_count")
        return self._do_position_count()

    @property
    def position(self) -> int:
        """The slot in the beam (1-based), as the wheel reports it."""
        self._check_open("position")
        return self._do_get_position()

    @property
    def current_filter(self) -> FilterSpec:
        return self.filter_at(self.position)

    def check_position(self, position: int, command: str = "move_to") -> int:
        """Return ``position`` as int, or raise if it is no slot of this wheel."""
        if isinstance(position, bool) or not isinstance(position, int | np.integer):
            raise TypeError(f"{self.name}: a slot number is an int, got {position!r}")
        count = self._do_position_count()
        if not 1 <= position <= count:
            raise LimitError(f"slot {position} does not exist (the wheel has slots 1..{count})",
                             device=self.name, command=command,
                             hint="choose a slot from 1 to the slot count")
        return int(position)

    @property
    def speed(self) -> WheelSpeed:
        self._check_open("speed")
        return self._do_get_speed()

    @speed.setter
    def speed(self, value: WheelSpeed | str) -> None:
        self._check_open("set speed")
        if isinstance(value, str):
            try:
                value = WheelSpeed(value.lower())
            except ValueError:
                raise ValueError(f"{self.name}: speed must be 'normal' or 'high', "
                                 f"got {value!r}") from None
        if not isinstance(value, WheelSpeed):
            raise TypeError(f"{self.name}: speed must be a WheelSpeed, got {value!r}")
        self._do_set_speed(value)

    # motion -------------------------------------------------------------------
    def estimated_move_s(self, target: int) -> float:
        """Seconds a move from the present slot to ``target`` should take."""
        self._check_open("estimated_move_s")
        target = self.check_position(target, "estimated_move_s")
        return self._do_estimate_move_s(self._do_get_position(), target)

    def move_to(self, position: int, *, timeout: float | None = None) -> int:
        """Put slot ``position`` in the beam; return when it is there.

        Raises
        ------
        LimitError
            No such slot (raised before anything moves).
        DeviceTimeout
            The wheel did not arrive within ``timeout`` s.
        MotionError
            It stopped at another slot.
        """
        self._check_open("move_to")
        position = self.check_position(position, "move_to")
        if timeout is None:
            estimate = self._do_estimate_move_s(self._do_get_position(), position)
            timeout = self.move_timeout_factor * estimate + self.move_timeout_margin_s
        if not (math.isfinite(timeout) and timeout > 0):
            raise ValueError(f"{self.name}: timeout must be a finite number > 0, got {timeout}")
        self._do_move_to(position, float(timeout))
        actual = self._do_get_position()
        if actual != position:
            raise self._missed_error(actual, position)
        return actual

    def _missed_error(self, actual: int, target: int) -> MotionError:
        """The error for a move that ended at slot ``actual``; drivers may refine it."""
        return MotionError(
            f"the wheel stopped at slot {actual}, not at slot {target}",
            device=self.name, command="move_to",
            hint="check the wheel for an obstruction, then move again",
        )

    # hooks --------------------------------------------------------------------
    @abstractmethod
    def _do_position_count(self) -> int: ...

    @abstractmethod
    def _do_get_position(self) -> int: ...

    @abstractmethod
    def _do_move_to(self, position: int, timeout: float) -> None:
        """Move to the validated ``position``; return once it is there (or raise)."""

    @abstractmethod
    def _do_estimate_move_s(self, start: int, target: int) -> float: ...

    @abstractmethod
    def _do_get_speed(self) -> WheelSpeed: ...

    @abstractmethod
    def _do_set_speed(self, value: WheelSpeed) -> None: ...


# --------------------------------------------------------------------------- power meter


class WavelengthSetting(Device):
    """A device whose readings or settings depend on the light's wavelength (a power
    meter's responsivity correction, a modulator's retardation in waves): the
    :attr:`wavelength_nm` property, checked by ``_checked_wavelength_nm`` before the
    ``_do_set_wavelength_nm`` hook sees it."""

    @property
    def wavelength_nm(self) -> float:
        """The wavelength setting, nm."""
        self._check_open("wavelength_nm")
        return self._do_get_wavelength_nm()

    @wavelength_nm.setter
    def wavelength_nm(self, value: float) -> None:
        self._check_open("set wavelength_nm")
        self._do_set_wavelength_nm(self._checked_wavelength_nm(value))

    def _checked_wavelength_nm(self, value: float) -> float:
        """The value the hook gets; by default any finite number > 0."""
        return finite_positive(value, f"{self.name}: wavelength")

    @abstractmethod
    def _do_get_wavelength_nm(self) -> float: ...

    @abstractmethod
    def _do_set_wavelength_nm(self, value: float) -> None: ...


class PowerMeter(WavelengthSetting):
    """An optical power meter (photodiode or thermal sensor head)."""

    #: Wavelength correction range in nm, (min, max); drivers read it from the device.
    wavelength_range_nm: tuple[float, float] = (200.0, 20000.0)

    def _checked_wavelength_nm(self, value: float) -> float:
        value = float(value)
        low, high = self.wavelength_range_nm
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(
                f"{self.name}: wavelength {value:g} nm outside the sensor's "
                f"[{low:g}, {high:g}] nm"
            )
        return value

    @property
    def averaging(self) -> int:
        self._check_open("averaging")
        return self._do_get_averaging()

    @averaging.setter
    def averaging(self, count: int) -> None:
        self._check_open("set averaging")
        if int(count) != count or count < 1:
            raise ValueError(f"{self.name}: averaging count must be >= 1, got {count}")
        self._do_set_averaging(int(count))

    @property
    def auto_range(self) -> bool:
        self._check_open("auto_range")
        return self._do_get_auto_range()

    @auto_range.setter
    def auto_range(self, on: bool) -> None:
        self._check_open("set auto_range")
        self._do_set_auto_range(bool(on))

    def read_power_w(self) -> float:
        """One (averaged) power reading in watts."""
        self._check_open("read_power_w")
        return self._do_read_power_w()

    def zero(self, *, timeout: float = 10.0) -> None:
        """Dark-zero the sensor: the light must be blocked."""
        self._check_open("zero")
        self._do_zero(timeout)

    @abstractmethod
    def _do_get_averaging(self) -> int: ...

    @abstractmethod
    def _do_set_averaging(self, count: int) -> None: ...

    @abstractmethod
    def _do_get_auto_range(self) -> bool: ...

    @abstractmethod
    def _do_set_auto_range(self, on: bool) -> None: ...

    @abstractmethod
    def _do_read_power_w(self) -> float: ...

    @abstractmethod
    def _do_zero(self, timeout: float) -> None: ...


# --------------------------------------------------------------------------- lock-in amplifier
# Kept in one self-contained section (its own ``__all__`` extension and local imports) so that
# other device kinds can be added to this module without touching these lines.

__all__ += ["LockIn", "LockInReading", "LockInStatus", "ReferenceSource"]


class ReferenceSource(enum.Enum):
    """Where the lock-in takes its reference: its own oscillator or the REF IN connector
    (for example the reference output of an optical chopper)."""

    INTERNAL = "internal"
    EXTERNAL = "external"


@dataclass(frozen=True)
class LockInReading:
    """X, Y, R and θ recorded together (one snapshot, not four separate reads).

    ``x_v``, ``y_v`` and ``r_v`` are volts **rms** of the input's Fourier component at the
    detection frequency (the convention of laboratory lock-ins: a sine of amplitude A volts
    peak reads R = A/√2); ``theta_deg`` is the phase in degrees, in (−180, 180];
    ``timestamp`` is host time (``time.time()``) when the reading arrived.
    """

    x_v: float
    y_v: float
    r_v: float
    theta_deg: float
    timestamp: float


@dataclass(frozen=True)
class LockInStatus:
    """Overload and reference flags, each latched by the instrument since the last look.

    ``input_overload``: the input amplifier or the dynamic reserve overloaded;
    ``filter_overload``: the output (time-constant) filters overloaded;
    ``output_overload``: X, Y or R exceeded the full scale of the sensitivity;
    ``reference_unlocked``: the external reference was lost.
    """

    input_overload: bool = False
    filter_overload: bool = False
    output_overload: bool = False
    reference_unlocked: bool = False

    @property
    def overloaded(self) -> bool:
        """Any overload: the reading cannot be trusted."""
        return self.input_overload or self.filter_overload or self.output_overload

    def describe(self) -> str:
        names = [text for flag, text in (
            (self.input_overload, "input overload"),
            (self.filter_overload, "filter overload"),
            (self.output_overload, "output overload"),
            (self.reference_unlocked, "reference unlocked"),
        ) if flag]
        return ", ".join(names) or "ok"


class LockIn(Device):
    """A lock-in amplifier: reference, output filter, sensitivity and synchronous readings.

    Settings take physical units and are snapped to the instrument's tables:
    :attr:`time_constant_s` to the nearest entry of :attr:`time_constants_s` (in log scale),
    :attr:`sensitivity_v` (full scale, volts rms) *up* to the next entry of
    :attr:`sensitivities_v`, so that a signal that fits the requested full scale never
    overloads the chosen one. Values outside a table raise ``ValueError`` before anything is
    sent.

    Settling (:meth:`settle`) waits a number of time constants; by default the "wait time
    to reach 99 % of its final value" of the present filter slope (:data:`SETTLE_TIME_CONSTANTS`,
    the table of the SR830 manual, Rev. 2.5, p. 3-25, "Noise measurements")::

        slope (dB/oct)   poles   ENBW        wait    step reached (cascaded poles)
        6                1       1/(4τ)      5 τ     99.33 %
        12               2       1/(8τ)      7 τ     99.27 %
        18               3       3/(32τ)     9 τ     99.38 %
        24               4       5/(64τ)    10 τ     98.97 %

    The last column is the step response of n identical single poles,
    ``1 − e^{−t/τ} Σ_{k<n} (t/τ)^k/k!``; exactly 99 % takes 4.61, 6.64, 8.41 and 10.05 τ, so
    the manual's 24 dB/oct entry is rounded (a 24 dB/oct filter does not settle in 5 τ:
    it has reached only 73 % then).

    Parameters
    ----------
    name
        Role name (e.g. ``"lockin"``).
    sleep
        The waiting function used by :meth:`settle` and :meth:`auto_range` (injectable so
        tests can run simulated time).
    """

    #: Full-scale sensitivities in volts rms, ascending; drivers set the instrument's table.
    sensitivities_v: tuple[float, ...] = ()
    #: Output filter time constants in seconds, ascending; drivers set the instrument's table.
    time_constants_s: tuple[float, ...] = ()
    #: Output filter slopes in dB/octave (6 dB/octave per single-pole stage).
    filter_slopes_db_per_oct: tuple[int, ...] = (6, 12, 18, 24)
    #: Time constants to wait for 99 % of a step, by filter slope (SR830 manual, p. 3-25).
    SETTLE_TIME_CONSTANTS: dict[int, float] = {6: 5.0, 12: 7.0, 18: 9.0, 24: 10.0}  # noqa: RUF012
    #: Relative slack accepted when a value is meant to be exactly a table entry.
    _TABLE_RTOL = 1e-6

    def __init__(self, name: str, *, sleep: Callable[[float], None] = time.sleep) -> None:
        super().__init__(name)
        self._sleep = sleep

    # table helpers --------------------------------------------------------------
    def snap_time_constant(self, value: float) -> float:
        """The table time constant nearest ``value`` seconds (in log scale).

        Raises ``ValueError`` for a non-finite or non-positive value, or one outside the
        table's range.
        """
        value = finite_positive(value, f"{self.name}: time constant")
        table = self.time_constants_s
        low, high = table[0], table[-1]
        if not low * (1 - self._TABLE_RTOL) <= value <= high * (1 + self._TABLE_RTOL):
            raise ValueError(f"{self.name}: time constant {value:g} s outside the instrument's "
                             f"[{low:g}, {high:g}] s")
        return min(table, key=lambda t: abs(math.log(t / value)))

    def snap_sensitivity(self, value: float) -> float:
        """The smallest table full scale (volts rms) not below ``value``.

        Raises ``ValueError`` for a non-finite or non-positive value or one above the largest
        full scale.
        """
        value = finite_positive(value, f"{self.name}: sensitivity")
        for full_scale in self.sensitivities_v:
            if full_scale >= value * (1 - self._TABLE_RTOL):
                return full_scale
        raise ValueError(f"{self.name}: sensitivity {value:g} V above the largest full scale "
                         f"{self.sensitivities_v[-1]:g} V")

    # reference ------------------------------------------------------------------
    @property
    def reference_frequency_hz(self) -> float:
        """The detection frequency in Hz (internal oscillator, or measured at REF IN)."""
        self._check_open("reference_frequency_hz")
        return self._do_get_reference_frequency_hz()

    @property
    def reference_source(self) -> ReferenceSource:
        self._check_open("reference_source")
        return self._do_get_reference_source()

    @reference_source.setter
    def reference_source(self, source: ReferenceSource | str) -> None:
        self._check_open("set reference_source")
        if isinstance(source, str):
            try:
                source = ReferenceSource(source.lower())
            except ValueError:
                raise ValueError(f"{self.name}: reference source must be 'internal' or "
                                 f"'external', got {source!r}") from None
        if not isinstance(source, ReferenceSource):
            raise TypeError(f"{self.name}: reference_source must be a ReferenceSource, "
                            f"got {source!r}")
        self._do_set_reference_source(source)

    # output filter ----------------------------------------------------------------
    @property
    def time_constant_s(self) -> float:
        """Output filter time constant τ in seconds."""
        self._check_open("time_constant_s")
        return self._do_get_time_constant_s()

    @time_constant_s.setter
    def time_constant_s(self, value: float) -> None:
        self._check_open("set time_constant_s")
        self._do_set_time_constant_s(self.snap_time_constant(value))

    @property
    def filter_slope_db_per_oct(self) -> int:
        """Output filter roll-off: 6 dB/octave per single-pole stage."""
        self._check_open("filter_slope_db_per_oct")
        return self._do_get_filter_slope()

    @filter_slope_db_per_oct.setter
    def filter_slope_db_per_oct(self, value: int) -> None:
        self._check_open("set filter_slope_db_per_oct")
        if isinstance(value, bool) or value not in self.filter_slopes_db_per_oct:
            raise ValueError(f"{self.name}: filter slope must be one of "
                             f"{self.filter_slopes_db_per_oct} dB/oct, got {value!r}")
        self._do_set_filter_slope(int(value))

    # gain ---------------------------------------------------------------------------
    @property
    def sensitivity_v(self) -> float:
        """Full scale in volts rms."""
        self._check_open("sensitivity_v")
        return self._do_get_sensitivity_v()

    @sensitivity_v.setter
    def sensitivity_v(self, value: float) -> None:
        self._check_open("set sensitivity_v")
        self._do_set_sensitivity_v(self.snap_sensitivity(value))

    # readings -----------------------------------------------------------------------
    def snapshot(self) -> LockInReading:
        """X, Y, R and θ taken at one instant."""
        self._check_open("snapshot")
        return self._do_snapshot()

    def overload_status(self) -> LockInStatus:
        """The latched overload/unlock flags since the last call (reading clears them)."""
        self._check_open("overload_status")
        return self._do_status()

    def settle_time_s(self, n_time_constants: float | None = None) -> float:
        """Seconds :meth:`settle` would wait (``n_time_constants`` × τ; by default the 99 %
        wait of the present slope)."""
        self._check_open("settle_time_s")
        if n_time_constants is None:
            n_time_constants = self.SETTLE_TIME_CONSTANTS[self._do_get_filter_slope()]
        n = float(n_time_constants)
        if not (math.isfinite(n) and n > 0):
            raise ValueError(f"{self.name}: n_time_constants must be a finite number > 0, "
                             f"got {n_time_constants!r}")
        return n * self._do_get_time_constant_s()

    def settle(self, n_time_constants: float | None = None, *, timeout: float = 60.0) -> float:
        """Wait until the output filter has settled; return the seconds waited.

        Waits ``n_time_constants`` × τ (default: the 99 % wait of the present slope, see
        :data:`SETTLE_TIME_CONSTANTS`). A wait longer than ``timeout`` is refused with
        :class:`DeviceTimeout` *before* waiting.
        """
        self._check_open("settle")
        if not (math.isfinite(timeout) and timeout > 0):
            raise ValueError(f"{self.name}: timeout must be a finite number > 0")
        wait = self.settle_time_s(n_time_constants)
        if wait > timeout:
            raise DeviceTimeout(
                f"settling needs {wait:g} s, more than the timeout {timeout:g} s; "
                "nothing was waited", device=self.name, command="settle",
                hint="raise the timeout or choose a shorter time constant",
            )
        self._sleep(wait)
        return wait

    def auto_range(self, *, max_steps: int = 30, timeout: float = 120.0,
                   headroom: float = 0.5, n_time_constants: float | None = None) -> float:
        """Choose the full scale for the present signal; return it (volts rms).

        Repeats: settle, read the (cleared, then re-latched) overload flags and a snapshot;
        on an overload step the sensitivity up one range; otherwise pick the smallest full
        scale that keeps R below ``headroom`` × full scale, and stop when that is the present
        one. At most ``max_steps`` changes and ``timeout`` seconds.

        Raises
        ------
        OverloadError
            Still overloaded on the largest full scale (an input overload no range cures).
        DeviceTimeout
            No stable range within ``timeout`` s or ``max_steps`` changes.
        """
        from drivers.errors import OverloadError

        self._check_open("auto_range")
        if int(max_steps) != max_steps or max_steps < 1:
            raise ValueError(f"{self.name}: max_steps must be a positive integer")
        if not 0.0 < headroom <= 1.0:
            raise ValueError(f"{self.name}: headroom must be in (0, 1]")
        if not (math.isfinite(timeout) and timeout > 0):
            raise ValueError(f"{self.name}: timeout must be a finite number > 0")
        deadline = time.monotonic() + timeout
        table = self.sensitivities_v
        for _ in range(int(max_steps) + 1):
            wait = self.settle_time_s(n_time_constants)
            if time.monotonic() + wait > deadline:
                break
            self._do_status()  # clear the flags latched under the previous range
            self._sleep(wait)
            status = self._do_status()
            reading = self._do_snapshot()
            index = table.index(self._do_get_sensitivity_v())
            if status.input_overload and index == len(table) - 1:
                raise OverloadError(
                    f"input overload on the largest full scale {table[-1]:g} V "
                    f"(R = {reading.r_v:.4g} V)", device=self.name, command="auto_range",
                    hint="reduce the signal at the input (gain of the detector amplifier)",
                )
            if status.overloaded or reading.r_v > table[index]:
                if index == len(table) - 1:
                    raise OverloadError(
                        f"overloaded on the largest full scale {table[-1]:g} V "
                        f"({status.describe()}, R = {reading.r_v:.4g} V)", device=self.name,
                        command="auto_range", hint="reduce the signal at the input",
                    )
                self._do_set_sensitivity_v(table[index + 1])
                continue
            best = next((i for i, fs in enumerate(table) if reading.r_v <= headroom * fs),
                        len(table) - 1)
            if best == index:
                return table[index]
            self._do_set_sensitivity_v(table[best])
        raise DeviceTimeout(
            f"no stable range within {timeout:g} s and {max_steps} changes",
            device=self.name, command="auto_range",
            hint="the signal may be changing; raise the timeout or the time constant",
        )

    # hooks --------------------------------------------------------------------------
    @abstractmethod
    def _do_get_reference_frequency_hz(self) -> float: ...

    @abstractmethod
    def _do_get_reference_source(self) -> ReferenceSource: ...

    @abstractmethod
    def _do_set_reference_source(self, source: ReferenceSource) -> None: ...

    @abstractmethod
    def _do_get_time_constant_s(self) -> float: ...

    @abstractmethod
    def _do_set_time_constant_s(self, value: float) -> None: ...

    @abstractmethod
    def _do_get_filter_slope(self) -> int: ...

    @abstractmethod
    def _do_set_filter_slope(self, db_per_oct: int) -> None: ...

    @abstractmethod
    def _do_get_sensitivity_v(self) -> float: ...

    @abstractmethod
    def _do_set_sensitivity_v(self, value: float) -> None: ...

    @abstractmethod
    def _do_snapshot(self) -> LockInReading: ...

    @abstractmethod
    def _do_status(self) -> LockInStatus: ...


# --------------------------------------------------------------------------- modulator
# Kept in one self-contained section, like the lock-in's.

__all__ += ["Modulator"]


class Modulator(WavelengthSetting):
    """A photoelastic modulator (PEM): a retarder whose retardation oscillates at the
    resonance of its optical head, δ(t) = 2π·A·sin(2π f t).

    ``A`` is the peak retardation in waves at the wavelength
    (:attr:`~WavelengthSetting.wavelength_nm`; a half-wave modulator at 633 nm:
    ``A = 0.5``), :attr:`retardation_rad` the same in radians (2πA, the argument of the
    Bessel functions J₁, J₂ that weight the detector's 1f and 2f terms);
    :attr:`frequency_hz` is the modulation frequency f the lock-in takes as its reference
    (its harmonics 1 and 2 carry the polarisation signals). A modulator's retardation in
    nanometres is fixed by its drive, so the same drive is fewer waves at a longer
    wavelength: setting the wavelength keeps the drive and changes ``A``.

    Parameters
    ----------
    name
        Role name (e.g. ``"pem"``).
    """

    @property
    def retardation_waves(self) -> float:
        """Peak retardation amplitude in waves at :attr:`~WavelengthSetting.wavelength_nm`."""
        self._check_open("retardation_waves")
        return self._do_get_retardation_waves()

    @retardation_waves.setter
    def retardation_waves(self, value: float) -> None:
        self._check_open("set retardation_waves")
        if isinstance(value, bool):
            raise TypeError(f"{self.name}: retardation must be a number, got {value!r}")
        value = float(value)
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{self.name}: retardation must be a finite number >= 0 waves, "
                             f"got {value}")
        self._do_set_retardation_waves(value)

    @property
    def retardation_rad(self) -> float:
        """Peak retardation amplitude in radians (2π × waves)."""
        return 2.0 * math.pi * self.retardation_waves

    @property
    def frequency_hz(self) -> float:
        """The modulation frequency (the head's resonance), Hz: the lock-in's reference."""
        self._check_open("frequency_hz")
        return self._do_get_frequency_hz()

    @abstractmethod
    def _do_get_retardation_waves(self) -> float: ...

    @abstractmethod
    def _do_set_retardation_waves(self, value: float) -> None: ...

    @abstractmethod
    def _do_get_frequency_hz(self) -> float: ...
