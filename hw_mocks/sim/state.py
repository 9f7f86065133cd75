"""What the virtual bench is made of: roles, pose, source, a world snapshot, the scene protocol.

Data types shared by the virtual bench (:mod:`hw_mocks.sim.world`, which states the lab frame
and the kinematics) and the scenes that render from it, kept apart so that a scene needs
nothing of the bench that holds it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from hw_mocks import registry
from hw_mocks.sim.filters import FilterBand, NeutralDensity, parse_bands

__all__ = ["ARM_ROLES", "COHERENCE", "ROLES", "BenchPose", "LightPath", "PowerMeterHead", "Scene",
           "SourceState", "WorldState", "rotation"]


#: What a source's light can be: ``"laser"`` (spatially coherent: speckle) or
#: ``"incoherent"`` (a lamp).
COHERENCE = ("incoherent", "laser")

ROLES = ("sample_theta", "sample_phi", "sample_tilt", "detector_theta", "source_theta",
         "camera_z", "source_arc", "source_azimuth", "detector_arc", "detector_azimuth")
#: The arms of a type (i) goniometer: a world with any of them has a stationary sample.
ARM_ROLES = ("source_arc", "source_azimuth", "detector_arc", "detector_azimuth")


def rotation(axis: str, angle_rad: float) -> NDArray[np.float64]:
    """Right-handed 3×3 rotation matrix about the lab axis ``"x"``, ``"y"`` or ``"z"``."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    if axis == "x":
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == "y":
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    if axis == "z":
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    raise ValueError(f"axis must be x, y or z, got {axis!r}")


@dataclass(frozen=True)
class SourceState:
    """The light source: collimated Gaussian beam of 1/e² radius ``beam_radius_mm``.

    Its spectrum is a line at ``wavelength_nm`` (``bandwidth_nm`` 0, a laser) or a flat band
    of full width ``bandwidth_nm`` around it (see :mod:`hw_mocks.sim.filters`).
    ``coherence`` is ``"incoherent"`` (a lamp: no interference, the default) or
    ``"laser"``: light scattered by a rough sample then shows speckle on the camera
    (:mod:`hw_mocks.sim.speckle`).
    """

    on: bool = False
    power_w: float = 1e-3
    wavelength_nm: float = 633.0
    beam_radius_mm: float = 2.0
    max_power_w: float = 5e-3
    bandwidth_nm: float = 0.0
    coherence: str = "incoherent"

    def __post_init__(self) -> None:
        if self.coherence not in COHERENCE:
            raise ValueError(f"source coherence must be one of {', '.join(COHERENCE)}, got "
                             f"{self.coherence!r}")

    def peak_intensity_w_m2(self) -> float:
        """On-axis intensity 2P/(π w²) of the Gaussian beam, perpendicular to it (W/m²)."""
        if not self.on:
            return 0.0
        w = self.beam_radius_mm * 1e-3
        return 2.0 * self.power_w / (math.pi * w * w)


@dataclass(frozen=True)
class BenchPose:
    """Geometry derived from the axis positions (lab frame, unit vectors, mm).

    Attributes
    ----------
    source_dir : ndarray, shape (3,)
        ω_s, from the sample towards the source (the beam travels along −ω_s).
    sample_axes : ndarray, shape (3, 3)
        Rows x_s, y_s, n of the sample frame in lab coordinates.
    detector_dir : ndarray, shape (3,)
        ω_d, from the sample towards the detector arm.
    detector_distance_mm : float
        Distance of the camera's pinhole (or the meter head) from the sample centre.
    """

    source_dir: NDArray[np.float64]
    sample_axes: NDArray[np.float64]
    detector_dir: NDArray[np.float64]
    detector_distance_mm: float

    @property
    def normal(self) -> NDArray[np.float64]:
        return self.sample_axes[2]

    def to_sample(self, vectors: NDArray[np.float64]) -> NDArray[np.float64]:
        """Lab vectors of shape (..., 3) in sample coordinates (x_s, y_s, n)."""
        return vectors @ self.sample_axes.T

    def local_angles(self, vectors: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """(θ, φ) in radians of lab direction(s) in the sample frame (analysis.brdf)."""
        loc = self.to_sample(np.asarray(vectors, dtype=float))
        norm = np.linalg.norm(loc, axis=-1)
        theta = np.arccos(np.clip(loc[..., 2] / norm, -1.0, 1.0))
        phi = np.arctan2(loc[..., 1], loc[..., 0])
        return theta, phi

    @property
    def incidence_deg(self) -> float:
        return float(np.degrees(self.local_angles(self.source_dir)[0]))

    @property
    def scatter_deg(self) -> float:
        return float(np.degrees(self.local_angles(self.detector_dir)[0]))


@dataclass(frozen=True)
class WorldState:
    """A consistent snapshot: positions, pose, light, scene and a hashable cache key.

    ``source`` is the light as it reaches the sample
    (:meth:`hw_mocks.sim.world.VirtualBench.light_at_sample`): off while a shutter is shut,
    filtered by the filter-wheel slot in the beam.
    """

    positions: Mapping[str, float]
    pose: BenchPose
    source: SourceState
    scene: Scene
    key: tuple
    #: The polarisation optics as they stand (a
    #: :class:`~hw_mocks.sim.polarisation.PolarisationState`), None on a bench without.
    optics: Any = None


@dataclass(frozen=True)
class PowerMeterHead:
    """Where the power-meter head sits: on the detector arm, facing the sample."""

    distance_mm: float = 300.0
    aperture_diameter_mm: float = 9.5
    #: ``simusb://`` URL of the PM100USB emulator bound to this head, if any.
    url: str | None = None


@dataclass(frozen=True)
class LightPath:
    """What stands between the source and the sample, by emulator URL.

    ``shutter`` is an SC10 emulator (``simsc10://name``): the light passes while its blade
    is open. ``filter_wheel`` is an FW102C emulator (``simfw102c://name``) whose slots hold
    ``filters`` (slot → :class:`~hw_mocks.sim.filters.FilterBand` or
    :class:`~hw_mocks.sim.filters.NeutralDensity`; slots not listed are clear); while it
    turns, or stands jammed between slots, the beam is blocked.
    """

    shutter: str | None = None
    filter_wheel: str | None = None
    filters: Mapping[int, FilterBand | NeutralDensity] = field(default_factory=dict)

    @classmethod
    def from_config(cls, shutter: Any = None, filter_wheel: Any = None) -> LightPath:
        """From ``[simulation]``'s ``shutter = URL`` and ``filter_wheel = {url, filters}``."""
        if shutter is not None:
            registry.parse_url(str(shutter))
        wheel_url, filters = None, {}
        if filter_wheel is not None:
            if isinstance(filter_wheel, str):
                filter_wheel = {"url": filter_wheel}
            if not isinstance(filter_wheel, Mapping):
                raise TypeError(f"filter_wheel is a table {{url, filters}}, got {filter_wheel!r}")
            unknown = set(filter_wheel) - {"url", "filters"}
            if unknown:
                raise ValueError(f"unknown filter_wheel keys {sorted(unknown)}; known: url, "
                                 "filters")
            wheel_url = filter_wheel.get("url")
            if wheel_url is not None:
                registry.parse_url(str(wheel_url))
            filters = parse_bands(filter_wheel.get("filters"))
        return cls(shutter=None if shutter is None else str(shutter),
                   filter_wheel=None if wheel_url is None else str(wheel_url),
                   filters=filters)


class Scene(Protocol):
    """What the virtual bench needs from a scene."""

    def radiance(
        self, origin_mm: NDArray[np.float64], directions: NDArray[np.float64],
        state: WorldState,
    ) -> NDArray[np.float64]:
        """Radiance (W m⁻² sr⁻¹) arriving at ``origin_mm`` from the lab ``directions``
        (shape (..., 3), unit vectors pointing away from the observer)."""
        ...

    def power_on_aperture(
        self, center_mm: NDArray[np.float64], facing: NDArray[np.float64],
        diameter_mm: float, state: WorldState,
    ) -> float:
        """Optical power (W) on a disk aperture at ``center_mm`` whose normal is ``facing``."""
        ...
