"""The light-field bench's geometry and the wall's BRDF: from a geometry file or the run's profile.

The camera is a pinhole carried by the ``camera_z`` linear stage parallel to the wall. Lab frame
as in ``hw_mocks.sim.world``: wall in the plane z = 0, flatland transverse axis
``y = x_lab``, measurement plane z = d2. The pinhole sits at
``y_m = x0_mm + direction · (scale · camera_z + offset)``. The optical axis makes the angle ψ
(``yaw_deg``, the ``detector_theta`` convention) with the wall normal; a pixel in column j has
the image coordinate ``u_j = (j − c_x) · pitch / f`` (c_x the principal point, default the
sensor centre) and sees the ray that left the wall at ``θ_m = ψ − atan(u_j)`` (rad from +z,
unfolded convention of :mod:`analysis.lightfield`), from the wall point
``c = y_m − d2 tan θ_m``. Rows of the sensor repeat the flatland field.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.lightfield import (
    MATERIALS,
    FlatlandBRDF,
)
from instrument.bench.camera_calibration import camera_spec
from instrument.run.runfile import read_run

__all__ = [
    "CameraIntrinsics",
    "GeometryError",
    "LightFieldGeometry",
    "brdf_from_run",
    "geometry_from_run",
    "load_geometry",
    "parse_brdf",
]


class GeometryError(ValueError):
    """The light-field geometry cannot be determined (give a geometry file)."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics along the sensor's x axis (and y for the field angle).

    Attributes
    ----------
    width_px, height_px : sensor size in pixels (full frame)
    pixel_pitch_um : pixel pitch (µm)
    focal_length_mm : focal length (mm)
    principal_x_px, principal_y_px : principal point (pixels; NaN → the sensor centre
        ``(size − 1)/2``)
    """

    width_px: int
    height_px: int
    pixel_pitch_um: float
    focal_length_mm: float
    principal_x_px: float = math.nan
    principal_y_px: float = math.nan

    def __post_init__(self) -> None:
        if self.width_px < 2 or self.height_px < 1:
            raise GeometryError("the sensor needs width ≥ 2 and height ≥ 1 pixels")
        if not (self.pixel_pitch_um > 0 and self.focal_length_mm > 0):
            raise GeometryError("pixel pitch and focal length must be > 0")

    @property
    def cx(self) -> float:
        return (self.width_px - 1) / 2 if math.isnan(self.principal_x_px) \
            else self.principal_x_px

    @property
    def cy(self) -> float:
        return (self.height_px - 1) / 2 if math.isnan(self.principal_y_px) \
            else self.principal_y_px

    def image_u(self, columns: ArrayLike) -> NDArray[np.float64]:
        """Image coordinate ``u = (column − c_x) · pitch / f`` (tangent of the in-plane
        field angle)."""
        col = np.asarray(columns, dtype=float)
        return (col - self.cx) * (self.pixel_pitch_um * 1e-3 / self.focal_length_mm)

    def image_v(self, rows: ArrayLike) -> NDArray[np.float64]:
        """Image coordinate ``v = (row − c_y) · pitch / f``."""
        r = np.asarray(rows, dtype=float)
        return (r - self.cy) * (self.pixel_pitch_um * 1e-3 / self.focal_length_mm)

    def cos4(self, shape: tuple[int, int]) -> NDArray[np.float64]:
        """``cos⁴α`` of every pixel of a full frame of ``shape`` = (H, W)."""
        h, w = shape
        u = self.image_u(np.arange(w))
        v = self.image_v(np.arange(h))
        return 1.0 / (1.0 + u[None, :] ** 2 + v[:, None] ** 2) ** 2


@dataclass(frozen=True)
class LightFieldGeometry:
    """Measurement-side geometry of a light-field scan (module docstring, item 1).

    Attributes
    ----------
    intrinsics : CameraIntrinsics
    d2_mm : distance of the measurement plane (the pinhole track) from the wall (mm)
    x0_mm : pinhole y at ``camera_z = 0`` (mm)
    direction : +1 or −1, the sense in which ``camera_z`` moves the pinhole along y
    stage_scale, stage_offset_mm : world position = scale · stage reading + offset
    yaw_deg : optical axis angle from the wall normal (the ``detector_theta`` convention),
        used when the run has no ``detector_theta`` axis
    source : where the geometry came from (provenance)
    """

    intrinsics: CameraIntrinsics
    d2_mm: float
    x0_mm: float = 0.0
    direction: float = 1.0
    stage_scale: float = 1.0
    stage_offset_mm: float = 0.0
    yaw_deg: float = 0.0
    source: str = ""

    def __post_init__(self) -> None:
        if not self.d2_mm > 0:
            raise GeometryError("d2_mm must be > 0")
        if self.direction not in (1.0, -1.0):
            raise GeometryError("direction must be +1 or -1")

    def pinhole_y_mm(self, camera_z_mm: ArrayLike) -> NDArray[np.float64]:
        """y_m of the pinhole at the stage reading(s) ``camera_z_mm``."""
        z = np.asarray(camera_z_mm, dtype=float)
        return self.x0_mm + self.direction * (self.stage_scale * z + self.stage_offset_mm)

    def pixel_theta_rad(
        self, columns: ArrayLike, *, yaw_deg: float | None = None
    ) -> NDArray[np.float64]:
        """``θ_m = ψ − atan(u)`` of the given pixel columns (rad)."""
        psi = math.radians(self.yaw_deg if yaw_deg is None else yaw_deg)
        return psi - np.arctan(self.intrinsics.image_u(columns))

    def pixel_rays(
        self, camera_z_mm: float, columns: ArrayLike, *, yaw_deg: float | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(y_m, θ_m, c)`` of the pixels of ``columns`` at one stage position.

        ``y_m`` is the pinhole (broadcast to the columns), ``θ_m`` the ray angle and
        ``c = y_m − d2 tan θ_m`` the wall point the pixel sees (mm, rad, mm).
        """
        th = self.pixel_theta_rad(columns, yaw_deg=yaw_deg)
        y = np.broadcast_to(self.pinhole_y_mm(camera_z_mm), th.shape).astype(float)
        return y, th, y - self.d2_mm * np.tan(th)

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["intrinsics"] = {k: (None if isinstance(v, float) and math.isnan(v) else v)
                           for k, v in d["intrinsics"].items()}
        return d


def load_geometry(path: str | Path) -> LightFieldGeometry:
    """Read a geometry file (TOML) for a real bench::

        [camera]
        width_px = 1024
        height_px = 8
        pixel_pitch_um = 5.5
        focal_length_mm = 4.0
        principal_x_px = 511.5      # optional
        [track]
        d2_mm = 30.0                # pinhole track ↔ wall
        x0_mm = 0.0                 # pinhole y at camera_z = 0
        direction = 1.0
        yaw_deg = 0.0               # optical axis from the wall normal

    The units are in the key names.
    """
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise GeometryError(f"cannot read geometry file {p}: {err}") from err
    _missing = object()

    def num(section: str, key: str, default: Any = _missing, kind: type = float) -> Any:
        table = data.get(section, {})
        if not isinstance(table, dict):
            raise GeometryError(f"geometry file {p}: [{section}] must be a table")
        if key not in table:
            if default is _missing:
                raise GeometryError(f"geometry file {p}: missing [{section}] {key}")
            return default
        v = table[key]
        if isinstance(v, bool) or not isinstance(v, int | float) \
                or (kind is int and not float(v).is_integer()):
            raise GeometryError(f"geometry file {p}: [{section}] {key} = {v!r} must be "
                                f"{'an integer' if kind is int else 'a number'}")
        if not math.isfinite(v):
            raise GeometryError(f"geometry file {p}: [{section}] {key} = {v!r} must be finite")
        return kind(v)

    intr = CameraIntrinsics(
        num("camera", "width_px", kind=int), num("camera", "height_px", 1, int),
        num("camera", "pixel_pitch_um"), num("camera", "focal_length_mm"),
        num("camera", "principal_x_px", math.nan), num("camera", "principal_y_px", math.nan))
    return LightFieldGeometry(
        intr, num("track", "d2_mm"), num("track", "x0_mm", 0.0),
        num("track", "direction", 1.0), num("track", "stage_scale", 1.0),
        num("track", "stage_offset_mm", 0.0), num("track", "yaw_deg", 0.0),
        f"geometry file {p}")


def geometry_from_run(path: str | Path) -> LightFieldGeometry:
    """The geometry of an emulated light-field bench, from the profile stored in the run.

    Intrinsics come from the camera URL's options (``focal_length_mm``,
    ``pixel_pitch_um``, ``width``, ``height``) or the camera's ``options`` table; the track
    from ``[simulation.scene.camera_track]`` and the ``camera_z``/``detector_theta``
    entries of ``[simulation.roles]`` (the bench as built).  A real bench has no such
    table: pass a geometry file (:func:`load_geometry`).
    """
    run = read_run(path)
    profile, frame_shape = run.profile(), run.frame_shape
    found = camera_spec(profile)
    if found is None:
        raise GeometryError("the run's bench profile has no camera")
    role, spec = found
    opts: dict[str, Any] = {k: v[-1] for k, v in parse_qs(urlsplit(spec["url"]).query).items()}
    opts.update(spec.get("options", {}))
    missing = [k for k in ("focal_length_mm", "pixel_pitch_um") if k not in opts]
    if missing:
        raise GeometryError(f"camera {role!r}: the profile does not state {missing}; "
                            "give a geometry file (--geometry)")
    h, w = frame_shape if frame_shape is not None else (1, 2)
    intr = CameraIntrinsics(int(opts.get("width", w)), int(opts.get("height", h)),
                            float(opts["pixel_pitch_um"]), float(opts["focal_length_mm"]))
    sim = profile.get("simulation", {})
    track = sim.get("scene", {}).get("camera_track")
    if track is None:
        raise GeometryError("the run's profile has no [simulation.scene] camera_track; "
                            "give a geometry file (--geometry)")
    roles = sim.get("roles", {})
    cz = roles.get("camera_z", {})
    scale = float(cz.get("scale", 1.0)) if isinstance(cz, dict) else 1.0
    offset = float(cz.get("offset", 0.0)) if isinstance(cz, dict) else 0.0
    yaw = roles.get("detector_theta", 0.0)
    yaw = float(yaw.get("value", 0.0)) if isinstance(yaw, dict) else float(yaw) \
        if isinstance(yaw, int | float) else 0.0
    return LightFieldGeometry(intr, float(track["z_mm"]), float(track.get("x0_mm", 0.0)),
                              float(track.get("direction", 1.0)), scale, offset, yaw,
                              "bench profile stored in the run ([simulation.scene])")


def parse_brdf(text: str) -> FlatlandBRDF:
    """A wall BRDF from a material name or ``"ρ_s,σ_deg,ρ_d"`` (flatland, eq. 2-14)."""
    if text in MATERIALS:
        return MATERIALS[text]
    usage = (f"BRDF {text!r}: a material ({', '.join(sorted(MATERIALS))}) "
             "or 'rho_s,sigma_deg,rho_d'")
    parts = text.split(",")
    if len(parts) != 3:
        raise ValueError(usage)
    try:
        rs, sd, rd = (float(p) for p in parts)
        return FlatlandBRDF(rs, math.radians(sd), rd, 0.0, "custom")
    except ValueError as err:
        raise ValueError(f"{usage}: {err}") from None


def brdf_from_run(path: str | Path) -> FlatlandBRDF:
    """The wall's BRDF as the emulated bench's profile states it (a real wall's BRDF is
    measured separately and given with ``--brdf``)."""
    scene = read_run(path).profile().get("simulation", {}).get("scene", {})
    if "brdf" in scene:
        b = scene["brdf"]
        return FlatlandBRDF(float(b["specular_reflectance"]),
                            math.radians(float(b["specular_width_deg"])),
                            float(b["diffuse_reflectance"]),
                            float(b.get("window_exponent", 0.0)), str(b.get("name", "custom")))
    if "material" in scene:
        return parse_brdf(str(scene["material"]))
    raise GeometryError("the run's profile does not state the wall BRDF; give --brdf")
