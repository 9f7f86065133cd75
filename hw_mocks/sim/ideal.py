"""Ideal in-process devices: zero latency, no wire, no physics.

They implement the :mod:`drivers.base` ABCs exactly and do nothing else, so a run on them
measures the run engine and storage alone (engine-overhead benchmark, soak test). Moves
complete instantly; the camera returns small frames whose level is
``brightness() × exposure + 10`` DN, clipped at saturation (optionally with seeded Gaussian
noise); the power meter reads a constant. Imports only :mod:`drivers.base`
(docs/architecture.md import rules).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from drivers.base import (
    AxisKind,
    AxisStatus,
    Camera,
    DeviceIdentity,
    Frame,
    LightSource,
    MotionAxis,
    PixelFormat,
    PowerMeter,
    Roi,
)

__all__ = ["IdealAxis", "IdealCamera", "IdealPowerMeter", "IdealSource"]


class IdealAxis(MotionAxis):
    """A motion axis that is always homed and enabled and arrives instantly."""

    def __init__(self, name: str, *, kind: AxisKind = AxisKind.ROTARY,
                 soft_limits: tuple[float, float] = (-math.inf, math.inf)) -> None:
        super().__init__(name, kind=kind, soft_limits=soft_limits, poll_interval=0.0)
        self._pos = 0.0
        self._vel = 10.0
        self._acc = 10.0
        self.moves = 0

    def _do_status(self) -> AxisStatus:
        return AxisStatus(self._pos, False, True, True)

    def _do_get_position(self) -> float:
        return self._pos

    def _do_enable(self) -> None:
        pass

    def _do_disable(self) -> None:
        pass

    def _do_home(self) -> None:
        self._pos = 0.0

    def _do_move_absolute(self, target: float) -> None:
        self._pos = target
        self.moves += 1

    def _do_stop(self) -> None:
        pass

    def _do_get_velocity(self) -> float:
        return self._vel

    def _do_set_velocity(self, value: float) -> None:
        self._vel = value

    def _do_get_acceleration(self) -> float:
        return self._acc

    def _do_set_acceleration(self, value: float) -> None:
        self._acc = value

    def _do_identity(self) -> DeviceIdentity:
        return DeviceIdentity("scatterlab", "ideal-axis", self.name)

    def _do_close(self) -> None:
        pass


class IdealSource(LightSource):
    def __init__(self, name: str = "source") -> None:
        super().__init__(name)
        self._on = False

    def _do_set_on(self, on: bool) -> None:
        self._on = on

    def _do_is_on(self) -> bool:
        return self._on

    def _do_identity(self) -> DeviceIdentity:
        return DeviceIdentity("scatterlab", "ideal-source", self.name)

    def _do_close(self) -> None:
        pass


class IdealCamera(Camera):
    """Frames of ``shape`` at ``brightness() × exposure_us`` DN (12-bit, clipped)."""

    exposure_range_us = (1.0, 60e6)

    def __init__(self, name: str = "camera", *, shape: tuple[int, int] = (8, 8),
                 brightness: Callable[[], float] | None = None,
                 source: IdealSource | None = None, noise_dn: float = 0.0,
                 seed: int = 0, real_time: bool = False) -> None:
        super().__init__(name)
        self._real_time = real_time  # sleep for the exposure, like a sensor integrating
        self._noise = float(noise_dn)
        self._rng = np.random.default_rng(seed)
        self._shape = shape
        self._exp = 1000.0
        self._brightness = brightness or (lambda: 1.0)
        self._source = source
        self._index = 0

    def _do_sensor_shape(self) -> tuple[int, int]:
        return self._shape

    def _do_get_exposure_us(self) -> float:
        return self._exp

    def _do_set_exposure_us(self, value: float) -> None:
        self._exp = value

    def _do_get_gain(self) -> float:
        return 0.0

    def _do_set_gain(self, value: float) -> None:
        pass

    def _do_get_roi(self) -> Roi:
        return Roi(0, 0, self._shape[1], self._shape[0])

    def _do_set_roi(self, roi: Roi) -> None:
        pass

    def _do_get_pixel_format(self) -> PixelFormat:
        return PixelFormat.MONO12

    def _do_acquire_one(self, timeout: float) -> Frame:
        if self._real_time:
            time.sleep(self._exp * 1e-6)
        lit = self._source is None or self._source._on
        level = (self._brightness() if lit else 0.0) * self._exp + 10.0
        if self._noise > 0:  # Gaussian noise: frames that do not compress
            noisy = level + self._noise * self._rng.standard_normal(self._shape)
            data = np.clip(np.rint(noisy), 0, 4095).astype(np.uint16)
        else:
            data = np.full(self._shape, min(4095.0, level), dtype=np.uint16)
        self._index += 1
        return Frame(data, self._index, time.time(), self._exp, 0.0, 4095.0, 12,
                     self._do_get_roi())

    def _do_identity(self) -> DeviceIdentity:
        return DeviceIdentity("scatterlab", "ideal-camera", self.name)

    def _do_close_camera(self) -> None:
        pass


class IdealPowerMeter(PowerMeter):
    def __init__(self, name: str = "power_meter", *, reading_w: float = 1e-3) -> None:
        super().__init__(name)
        self._wl = 633.0
        self._avg = 1
        self._auto = True
        self.reading_w = reading_w

    def _do_get_wavelength_nm(self) -> float:
        return self._wl

    def _do_set_wavelength_nm(self, value: float) -> None:
        self._wl = value

    def _do_get_averaging(self) -> int:
        return self._avg

    def _do_set_averaging(self, count: int) -> None:
        self._avg = count

    def _do_get_auto_range(self) -> bool:
        return self._auto

    def _do_set_auto_range(self, on: bool) -> None:
        self._auto = on

    def _do_read_power_w(self) -> float:
        return self.reading_w

    def _do_zero(self, timeout: float) -> None:
        pass

    def _do_identity(self) -> DeviceIdentity:
        return DeviceIdentity("scatterlab", "ideal-power-meter", self.name)

    def _do_close(self) -> None:
        pass
