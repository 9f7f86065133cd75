"""The light-field scene of the virtual bench: a scattering wall, hidden objects, a camera track.

This puts the continuous-geometry renderer
:class:`hw_mocks.sim.lightfield_scene.HiddenScene` (the unfolded flatland scene of Sasaki
2020, PhD thesis, Univ. of Minnesota, eqs. 2-3, 2-6) on the virtual bench, so that the
simulated camera on its linear stage records the light field a real light-field scan would,
through the EMVA 1288 sensor model.

Geometry (lab frame of :mod:`hw_mocks.sim.world`, lengths in mm)
-------------------------------------------------------------------
* The **wall** is the plane z = 0 through the bench origin, its normal +ẑ (towards the
  camera).  Its extent along x is ``wall = [x_min, x_max]``.
* The **flatland plane** is the lab x–z plane (the plane of incidence); the flatland
  transverse coordinate is ``y = x_lab`` and the scene is invariant along the lab y axis
  (extruded objects and wall), so a ray's radiance depends only on its in-plane
  projection.  This is the 2-D light field of the thesis; rows of the sensor repeat it.
* The **measurement plane** is z = ``camera_track.z_mm`` (= d2).  The camera's pinhole
  rides on the ``camera_z`` linear stage, parallel to the wall:
  ``pinhole = (x0_mm + direction · camera_z, 0, z_mm)``.  Its orientation is that of the
  detector arm (:class:`hw_mocks.sim.camera.SimulatedCamera`): optical axis
  ``−R_y(detector_theta) ẑ``, image right ``= forward × ŷ``.
* A camera ray leaves the pinhole along a lab direction d (d_z < 0); the light travels
  the other way, from the wall to the pinhole, at the flatland angle
  ``θ_m = atan2(−d_x, −d_z)`` from +ẑ, and left the wall at ``c = o_x − o_z tan θ_m``.
  The renderer is asked for ``L(y_m, θ_m)`` with ``y_m = c + d2 tan θ_m`` on its own
  measurement plane, which is the same ray.  For a camera at yaw ψ = detector_theta and
  a pixel at image coordinate ``u = (column − c_x) · pitch / f``: ``θ_m = ψ − atan u``.
* **Hidden objects** live in the unfolded scene at z < 0 (their real position is the
  mirror image in front of the wall, out of the camera's view).  They shine only while
  the source is on, with radiance scaled by ``source.power_w / reference_power_w`` (they
  are lit by it); ``ambient_radiance`` adds a constant, source-independent level.

Configuration (``[simulation.scene]`` of a bench profile, ``kind = "lightfield"``)::

    kind = "lightfield"
    material = "brushed_metal"          # analysis.lightfield.MATERIALS, or:
    brdf = { specular_reflectance = 0.6, specular_width_deg = 2.0,
             diffuse_reflectance = 0.08 }
    wall = [-150.0, 150.0]
    camera_track = { x0_mm = 0.0, z_mm = 30.0, direction = 1.0 }
    reference_power_w = 1e-3
    ambient_radiance = 0.0              # W m⁻² sr⁻¹
    renderer = "lobe"                   # or "reference" (HiddenScene: the check renderer)
    objects = [
      { kind = "point", y_mm = -8.0, z_mm = -200.0, radius_mm = 1.5, radiance = 5.0 },
      { kind = "bar", y_min_mm = 15.0, y_max_mm = 30.0, z_mm = -260.0, radiance = 1.5 },
    ]

Radiance unit: W m⁻² sr⁻¹ (object radiance at the reference source power).  The flatland
BRDF (1/rad) maps it to the wall's outgoing radiance in the same unit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from analysis.lightfield.brdf import MATERIALS, FlatlandBRDF
from hw_mocks.sim.lightfield_scene import BarObject, HiddenScene, PointObject, Wall

__all__ = ["CameraTrack", "LightFieldBenchScene", "flatland_ray"]


@dataclass(frozen=True)
class CameraTrack:
    """Where the ``camera_z`` stage carries the pinhole: ``(x0 + direction·z_stage, 0, z_mm)``.

    ``z_mm`` is the distance d2 of the measurement plane from the wall (> 0).
    """

    x0_mm: float = 0.0
    z_mm: float = 30.0
    direction: float = 1.0

    def __post_init__(self) -> None:
        if not self.z_mm > 0:
            raise ValueError("camera_track.z_mm (d2) must be > 0")
        if self.direction not in (1.0, -1.0):
            raise ValueError("camera_track.direction must be +1 or -1")

    def pinhole_mm(self, camera_z_mm: float) -> NDArray[np.float64]:
        """Lab position of the pinhole at stage position ``camera_z_mm``."""
        return np.array([self.x0_mm + self.direction * camera_z_mm, 0.0, self.z_mm])


def flatland_ray(
    origin_mm: NDArray[np.float64], directions: NDArray[np.float64], d2_mm: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Map camera rays to flatland measurement coordinates (module docstring).

    Parameters
    ----------
    origin_mm : (3,) — the pinhole (lab frame)
    directions : (..., 3) — viewing directions from the pinhole (away from the observer)
    d2_mm : the measurement plane's distance from the wall

    Returns
    -------
    y_m : (...) — where the ray crosses z = d2 (mm)
    theta_m : (...) — its flatland angle from +ẑ (rad), the light travelling to the camera
    toward_wall : (...) bool — False for rays that never reach the wall (d_z ≥ 0)
    """
    o = np.asarray(origin_mm, dtype=float)
    d = np.asarray(directions, dtype=float)
    dx, dz = d[..., 0], d[..., 2]
    toward = dz < 0
    theta = np.arctan2(-dx, -dz)
    c = o[0] - o[2] * np.tan(theta)
    return c + d2_mm * np.tan(theta), theta, toward


def _brdf_from_config(cfg: Mapping[str, Any]) -> FlatlandBRDF:
    if "brdf" in cfg and "material" in cfg:
        raise ValueError("give either scene.material or scene.brdf, not both")
    if "brdf" in cfg:
        b = dict(cfg["brdf"])
        unknown = set(b) - {"specular_reflectance", "specular_width_deg",
                            "diffuse_reflectance", "window_exponent", "name"}
        if unknown:
            raise ValueError(f"unknown scene.brdf keys {sorted(unknown)}")
        return FlatlandBRDF(float(b["specular_reflectance"]),
                            float(np.deg2rad(b["specular_width_deg"])),
                            float(b["diffuse_reflectance"]), float(b.get("window_exponent", 0)),
                            str(b.get("name", "custom")))
    name = str(cfg.get("material", "brushed_metal"))
    if name not in MATERIALS:
        raise ValueError(f"unknown material {name!r}; choose from {sorted(MATERIALS)}")
    return MATERIALS[name]


def _object_from_config(o: Mapping[str, Any]) -> PointObject | BarObject:
    o = dict(o)
    kind = o.pop("kind", "point")
    if kind == "point":
        unknown = set(o) - {"y_mm", "z_mm", "radius_mm", "radiance", "profile"}
        if unknown:
            raise ValueError(f"unknown point-object keys {sorted(unknown)}")
        return PointObject(float(o["y_mm"]), float(o["z_mm"]), float(o.get("radius_mm", 1.0)),
                           float(o.get("radiance", 1.0)), str(o.get("profile", "disc")))
    if kind == "bar":
        unknown = set(o) - {"y_min_mm", "y_max_mm", "z_mm", "radiance"}
        if unknown:
            raise ValueError(f"unknown bar-object keys {sorted(unknown)}")
        return BarObject(float(o["y_min_mm"]), float(o["y_max_mm"]), float(o["z_mm"]),
                         float(o.get("radiance", 1.0)))
    raise ValueError(f"unknown object kind {kind!r}; use 'point' or 'bar'")


def _object_at(index: int, o: Mapping[str, Any]) -> PointObject | BarObject:
    """One entry of ``objects``; errors name its index."""
    try:
        return _object_from_config(o)
    except KeyError as err:
        raise ValueError(f"objects[{index}]: missing key {err.args[0]!r}") from None
    except (TypeError, ValueError) as err:
        raise ValueError(f"objects[{index}]: {err}") from None


@dataclass(frozen=True)
class LightFieldBenchScene:
    """The light-field scene as a :class:`hw_mocks.sim.world.Scene` (module docstring).

    Parameters
    ----------
    hidden : HiddenScene — objects, wall and d2 (its ``d2_mm`` must equal the track's z)
    track : CameraTrack — where the ``camera_z`` stage puts the pinhole
    reference_power_w : source power at which the objects have their nominal radiance
    ambient_radiance : constant radiance added to every ray that meets the wall
    """

    hidden: HiddenScene
    track: CameraTrack = field(default_factory=CameraTrack)
    reference_power_w: float = 1e-3
    ambient_radiance: float = 0.0

    def __post_init__(self) -> None:
        if abs(self.hidden.d2_mm - self.track.z_mm) > 1e-9:
            raise ValueError("the renderer's d2 must equal camera_track.z_mm")
        if not self.reference_power_w > 0:
            raise ValueError("reference_power_w must be > 0")

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> LightFieldBenchScene:
        """From the ``[simulation.scene]`` table (module docstring).

        Raises ValueError prefixed ``[simulation.scene]`` that names the key at fault.
        """
        try:
            return cls._from_config(config)
        except KeyError as err:
            raise ValueError(f"[simulation.scene]: missing key {err.args[0]!r}") from None
        except (TypeError, ValueError) as err:
            raise ValueError(f"[simulation.scene]: {err}") from None

    @classmethod
    def _from_config(cls, config: Mapping[str, Any]) -> LightFieldBenchScene:
        cfg = dict(config)
        kind = cfg.pop("kind", "lightfield")
        if kind != "lightfield":
            raise ValueError(f"not a light-field scene: kind = {kind!r}")
        known = {"material", "brdf", "wall", "camera_track", "objects", "reference_power_w",
                 "ambient_radiance", "renderer"}
        unknown = set(cfg) - known
        if unknown:
            raise ValueError(f"unknown light-field scene keys {sorted(unknown)}; "
                             f"known {sorted(known)}")
        brdf = _brdf_from_config(cfg)
        track_cfg = dict(cfg.get("camera_track", {}))
        bad = set(track_cfg) - {"x0_mm", "z_mm", "direction"}
        if bad:
            raise ValueError(f"unknown camera_track keys {sorted(bad)}")
        track = CameraTrack(float(track_cfg.get("x0_mm", 0.0)),
                            float(track_cfg.get("z_mm", 30.0)),
                            float(track_cfg.get("direction", 1.0)))
        wall_lo, wall_hi = (float(v) for v in cfg.get("wall", (-150.0, 150.0)))
        objects = tuple(_object_at(i, o) for i, o in enumerate(cfg.get("objects", ())))
        hidden = HiddenScene(objects, Wall(wall_lo, wall_hi, brdf), d2_mm=track.z_mm,
                             renderer=str(cfg.get("renderer", "lobe")))
        return cls(hidden, track, float(cfg.get("reference_power_w", 1e-3)),
                   float(cfg.get("ambient_radiance", 0.0)))

    #: A flatland scene renders rays (y_m, θ_m) in one plane; the simulated camera keeps
    #: its pinhole model here (the light-field analysis models pinhole rays too).
    pupil_sampling = False

    @property
    def d2_mm(self) -> float:
        """Wall → measurement-plane distance (mm)."""
        return self.track.z_mm

    # --------------------------------------------------------------- bench protocol
    def camera_center_mm(self, state: Any) -> NDArray[np.float64]:
        """The pinhole for the simulated camera: on the track at the ``camera_z`` position."""
        return self.track.pinhole_mm(float(state.positions.get("camera_z", 0.0)))

    def radiance(
        self, origin_mm: NDArray[np.float64], directions: NDArray[np.float64], state: Any
    ) -> NDArray[np.float64]:
        """Radiance (W m⁻² sr⁻¹) arriving at ``origin_mm`` from ``directions`` (..., 3).

        Each distinct flatland angle is rendered once (the rows of the sensor share them).
        """
        y_m, theta, toward = flatland_ray(origin_mm, directions, self.d2_mm)
        c = y_m - self.d2_mm * np.tan(theta)
        on_wall = toward & (c >= self.hidden.wall.y_min_mm) & (c <= self.hidden.wall.y_max_mm)
        out = np.zeros(theta.shape)
        src = state.source
        scale = src.power_w / self.reference_power_w if src.on else 0.0
        if scale > 0 and np.any(on_wall):
            ys, ts = y_m[on_wall], theta[on_wall]
            key = np.round(np.stack([ys, ts]), 12)
            _, first, inverse = np.unique(key, axis=1, return_index=True, return_inverse=True)
            vals = self.hidden.radiance(ys[first], ts[first])
            out[on_wall] = scale * vals[np.ravel(inverse)]
        out[on_wall] += self.ambient_radiance
        return out

    def power_on_aperture(
        self, center_mm: NDArray[np.float64], facing: NDArray[np.float64],
        diameter_mm: float, state: Any,
    ) -> float:
        """Power on a disk aperture: radiance along its axis × area × a nominal 1 msr.

        The light-field bench uses no power meter; this coarse estimate (a head with a
        1 msr acceptance looking along ``facing``) only keeps the
        :class:`~hw_mocks.sim.world.Scene` protocol whole.
        """
        axis = np.asarray(facing, dtype=float)
        axis = axis / np.linalg.norm(axis)
        lum = float(self.radiance(np.asarray(center_mm, float), axis[None, :], state)[0])
        area_m2 = np.pi * (0.5e-3 * diameter_mm) ** 2
        return lum * area_m2 * 1e-3
