"""A uniform target for camera characterization: the exit port of an integrating sphere.

EMVA 1288 (Release 4.0 Linear, §6 "Methods for Sensitivity, Linearity, and Noise")
characterizes a camera under a homogeneous irradiance; a common set-up is the exit port of
an integrating sphere filling the camera's view. The port of a sphere of inner wall area
A_s and reflectance ρ, fed with the flux Φ, has the radiance (Labsphere, "A guide to
integrating sphere theory and applications", the sphere radiance equation
with the sphere multiplier M)

    L = Φ / (π A_s) · ρ / (1 − ρ (1 − f)),

where f is the fraction of the wall taken by the ports. The sphere is lit by the bench's
source (the light that reaches the sample, :meth:`~hw_mocks.sim.world.VirtualBench.
light_at_sample`), so turning the source off gives dark frames and its power scales L.

Every ray from the camera ends on the port (it fills the view, as the standard asks), so
the radiance is the same in every direction; the camera's lens still adds its cos⁴
fall-off across the field, which on a sensor a few hundred pixels wide stays far below the
1 % PRNU (hw_mocks.sim.camera; the sim-camera-ptc bench uses a 256 px sensor).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hw_mocks.sim.state import WorldState

__all__ = ["IntegratingSphereTarget"]


@dataclass(frozen=True)
class IntegratingSphereTarget:
    """The exit port of an integrating sphere in front of the camera.

    Parameters
    ----------
    sphere_diameter_mm : float
        Inner diameter of the sphere.
    wall_reflectance : float
        ρ of the coating (PTFE-like coatings: 0.95–0.99).
    port_fraction : float
        f: the fraction of the wall area taken by the ports.
    port_diameter_mm : float
        Exit-port diameter (for the power on a detector aperture).
    """

    sphere_diameter_mm: float = 100.0
    wall_reflectance: float = 0.98
    port_fraction: float = 0.05
    port_diameter_mm: float = 50.0
    #: The port is flat: no defocus blur to refine (hw_mocks.sim.camera).
    depth_extent_mm: float = 0.0

    def __post_init__(self) -> None:
        if not self.sphere_diameter_mm > 0 or not self.port_diameter_mm > 0:
            raise ValueError("integrating sphere: sphere_diameter_mm and port_diameter_mm "
                             "must be > 0")
        if not 0.0 < self.wall_reflectance < 1.0:
            raise ValueError(f"integrating sphere: wall_reflectance must lie in (0, 1), got "
                             f"{self.wall_reflectance}")
        if not 0.0 < self.port_fraction < 1.0:
            raise ValueError(f"integrating sphere: port_fraction must lie in (0, 1), got "
                             f"{self.port_fraction}")

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> IntegratingSphereTarget:
        """Keys: ``kind = "integrating_sphere"`` and the fields of the class."""
        known = {"kind", "sphere_diameter_mm", "wall_reflectance", "port_fraction",
                 "port_diameter_mm"}
        unknown = set(config) - known
        if unknown:
            raise ValueError(f"unknown integrating-sphere scene keys {sorted(unknown)}; "
                             f"known {sorted(known)}")
        return cls(**{k: float(v) for k, v in config.items() if k != "kind"})

    def port_radiance(self, state: WorldState) -> float:
        """L (W m⁻² sr⁻¹) of the exit port for the light that reaches the sphere."""
        src = state.source
        if not src.on:
            return 0.0
        wall_m2 = math.pi * (self.sphere_diameter_mm * 1e-3) ** 2
        rho, f = self.wall_reflectance, self.port_fraction
        return src.power_w / (math.pi * wall_m2) * rho / (1.0 - rho * (1.0 - f))

    def radiance(self, origin_mm: NDArray[np.float64], directions: NDArray[np.float64],
                 state: WorldState) -> NDArray[np.float64]:
        """The port's radiance along every direction (it fills the view)."""
        shape = np.asarray(directions).shape[:-1]
        return np.full(shape, self.port_radiance(state))

    def power_on_aperture(self, center_mm: NDArray[np.float64], facing: NDArray[np.float64],
                          diameter_mm: float, state: WorldState) -> float:
        """L · A · Ω: the port seen from the aperture's distance on its axis (small-angle)."""
        distance = float(np.linalg.norm(np.asarray(center_mm, dtype=float)))
        area = math.pi * (0.5 * diameter_mm * 1e-3) ** 2
        half = math.atan2(0.5 * self.port_diameter_mm, max(distance, 1e-9))
        solid = 2.0 * math.pi * (1.0 - math.cos(half))
        return self.port_radiance(state) * area * solid
