"""Light-field scans: run file → measured light field → reconstruction → localisation.

The analysis of a ``lightfield`` run (issue 6 §4; physics.md §§3–4, Sasaki's thesis S2–S3):

1. **Geometry** (:class:`LightFieldGeometry`).  The camera is a pinhole carried by the
   ``camera_z`` linear stage parallel to the wall.  Lab frame as in
   :mod:`hw_mocks.sim.world`: wall in the plane z = 0, flatland transverse axis
   ``y = x_lab``, measurement plane z = d2.  The pinhole sits at
   ``y_m = x0_mm + direction · (scale · camera_z + offset)``.  The optical axis makes the
   angle ψ (``yaw_deg``, the ``detector_theta`` convention) with the wall normal; a pixel
   in column j has the image coordinate ``u_j = (j − c_x) · pitch / f`` (c_x the principal
   point, default the sensor centre) and sees the ray that left the wall at
   ``θ_m = ψ − atan(u_j)`` (rad from +z, unfolded convention of
   :mod:`analysis.lightfield`), from the wall point ``c = y_m − d2 tan θ_m``.  Rows of the
   sensor repeat the flatland field; they are averaged.
2. **Assembly** (:func:`read_scan`, :func:`assemble`).  For every light-field point the
   longest unsaturated exposure is taken, its dark frame (same point, or the run's dark
   frames at the same exposure) subtracted, the result divided by the exposure and by the
   camera's ``cos⁴α`` fall-off (α the field angle of the pixel), and the rows averaged:
   a quantity proportional to radiance (``DN/µs``, no absolute calibration needed for
   localisation).  The pixel samples are then averaged into the cells of the regular
   cell-centred θ grid on the domain [a, b] (box average: the pixels are several times
   finer than the grid, so this is the anti-aliasing resampling), and interpolated
   linearly onto a uniform y grid when the read-back stage positions are not uniform.
3. **Reconstruction** (:func:`reconstruct_run`): :func:`analysis.lightfield.reconstruct`
   (per scattering point, closed form S2-32/33, Wiener filter from the pooled signal
   spectrum; ADR 0030) on the scattering points whose curves lie inside the measured y
   range.
4. **Localisation** (:func:`locate_run`): :func:`analysis.lightfield.detect_objects`
   (focal stack, RP refocusing, depth filter, iterative subtraction of point responses).

Results go into the run file under ``/entry/analysis/lightfield`` (an ``NXprocess``;
rewritten on every call)::

    measured/        radiance (N_y, N_θ), y_mm, theta_rad, cell_pixels (N_θ,) ; attrs
                     units, domain_rad, sigma_rows (noise of one cell from the row spread)
    reconstruction/  incident_radiance (R, N_θ), points_mm, theta_rad, filter_factors,
                     orders, signal_power, noise_power, gamma, snr_eff, delta_p,
                     valid_fraction ; attrs method, parameter_name, parameter,
                     effective_dof, residual_ratio, recoverable, message, solver, p_hat,
                     solvable_domain_rad, noise_sigma, noise_method
    localisation/    positions_mm (K, 2), brightness_rp, brightness_conventional,
                     transverse_mm, depth_mm, depth_profiles (K, N_z), stack_y_mm,
                     stack_z_mm, stack_conventional, stack_rp ; attrs count, p_hat
    attrs: program, version, date, geometry (JSON), brdf (JSON)

Figures (PNG, matplotlib) go to ``<run>.lightfield/`` next to the run file.
"""

from __future__ import annotations

import json
import math
import time
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import h5py
import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.lightfield import (
    MATERIALS,
    Detection,
    FlatlandBRDF,
    LightField2D,
    Reconstruction,
    detect_objects,
    effective_p_max,
    reconstruct,
    theoretical_resolution,
    theta_grid,
)

__all__ = [
    "CameraIntrinsics",
    "GeometryError",
    "LightFieldGeometry",
    "LocalisationResult",
    "MeasuredScan",
    "ReconstructionResult",
    "assemble",
    "brdf_from_run",
    "geometry_from_run",
    "load_geometry",
    "locate_run",
    "parse_brdf",
    "read_scan",
    "reconstruct_run",
]

GROUP = "entry/analysis/lightfield"
CAMERA_DRIVERS = ("sim_camera", "opencv_camera")


class GeometryError(ValueError):
    """The light-field geometry cannot be determined (give a geometry file)."""


# ----------------------------------------------------------------------------- geometry
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


def _profile(f: h5py.File) -> dict[str, Any]:
    text = f["entry/instrument/bench_profile"][()]
    return tomllib.loads(text.decode() if isinstance(text, bytes) else str(text))


def _camera_spec(profile: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    for role, spec in profile.get("devices", {}).items():
        if spec.get("driver") in CAMERA_DRIVERS:
            return role, spec
    raise GeometryError("the run's bench profile has no camera")


def geometry_from_run(path: str | Path) -> LightFieldGeometry:
    """The geometry of an emulated light-field bench, from the profile stored in the run.

    Intrinsics come from the camera URL's options (``focal_length_mm``,
    ``pixel_pitch_um``, ``width``, ``height``) or the camera's ``options`` table; the track
    from ``[simulation.scene.camera_track]`` and the ``camera_z``/``detector_theta``
    entries of ``[simulation.roles]`` (the bench as built).  A real bench has no such
    table: pass a geometry file (:func:`load_geometry`).
    """
    with h5py.File(path, "r") as f:
        profile = _profile(f)
        frame_shape = f["entry/data/frames"].shape[1:] if "entry/data/frames" in f else None
    role, spec = _camera_spec(profile)
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
    """A wall BRDF from a material name or ``"ρ_s,σ_deg,ρ_d"`` (flatland, eq. S2-14)."""
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
    with h5py.File(path, "r") as f:
        scene = _profile(f).get("simulation", {}).get("scene", {})
    if "brdf" in scene:
        b = scene["brdf"]
        return FlatlandBRDF(float(b["specular_reflectance"]),
                            math.radians(float(b["specular_width_deg"])),
                            float(b["diffuse_reflectance"]),
                            float(b.get("window_exponent", 0.0)), str(b.get("name", "custom")))
    if "material" in scene:
        return parse_brdf(str(scene["material"]))
    raise GeometryError("the run's profile does not state the wall BRDF; give --brdf")


# ----------------------------------------------------------------------------- assembly
@dataclass(frozen=True)
class MeasuredScan:
    """One row of pixel samples per light-field point, before resampling.

    Attributes
    ----------
    y_mm : (P,) — pinhole position y_m of each point (sorted increasing)
    theta_rad : (P, W) — θ_m of every pixel column at each point
    radiance : (P, W) — dark-subtracted, exposure- and cos⁴-normalised, row-averaged
        signal (DN/µs, proportional to radiance)
    variance : (P, W) — variance of ``radiance`` from the spread of the sensor rows
    exposure_us : (P,) — exposure used
    point_index : (P,) — plan index of each point
    notes : tuple of str — what the assembly had to assume (missing dark frames …)
    """

    y_mm: NDArray[np.float64]
    theta_rad: NDArray[np.float64]
    radiance: NDArray[np.float64]
    variance: NDArray[np.float64]
    exposure_us: NDArray[np.float64]
    point_index: NDArray[np.int64]
    notes: tuple[str, ...] = ()


def _s(x: Any) -> str:
    return x.decode() if isinstance(x, bytes) else str(x)


def read_scan(path: str | Path, geometry: LightFieldGeometry) -> MeasuredScan:
    """Frames of a light-field run → per-point rows of pixel samples (module doc, item 2)."""
    notes: list[str] = []
    with h5py.File(path, "r") as f:
        e = f["entry"]
        kind = _s(e.attrs.get("plan_kind", ""))
        if kind != "lightfield":
            raise ValueError(f"{path} is a {kind!r} run, not a light-field scan")
        axes = [_s(a) for a in e["plan/axes"][()]]
        if "camera_z" not in axes:
            raise ValueError("the run has no camera_z axis")
        labels = [_s(s) for s in e["points/label"][()]]
        index = e["points/index"][()]
        status = e["points/status"][()]
        pos = e["points/positions"][()]
        fpoint = e["data/frame_point"][()]
        flight = e["data/frame_light"][()].astype(bool)
        fexp = e["data/frame_exposure_us"][()]
        fsat = e["data/frame_saturated"][()]
        frames = e["data/frames"]
        h, w = frames.shape[1:]
        if w != geometry.intrinsics.width_px:
            raise GeometryError(f"frames are {w} px wide, the camera {geometry.intrinsics.width_px}"
                                " px: cropped or binned frames are not supported")
        cos4 = geometry.intrinsics.cos4((geometry.intrinsics.height_px, w))
        if h != geometry.intrinsics.height_px:
            # an ROI of full rows centred like the sensor (the simulated default)
            top = (geometry.intrinsics.height_px - h) // 2
            cos4 = cos4[top:top + h]
        iz = axes.index("camera_z")
        iyaw = axes.index("detector_theta") if "detector_theta" in axes else None
        dark_frames = [k for k in range(len(fpoint)) if not flight[k]]
        shared_darks: dict[tuple[int, ...], NDArray[np.float64]] = {}
        ys, ths, rads, vars_, exps, idxs = [], [], [], [], [], []
        for row, pidx in enumerate(index):
            if labels[row] != "lightfield" or status[row] != 0:
                continue
            mine = np.nonzero(fpoint == pidx)[0]
            light = [k for k in mine if flight[k]]
            if not light:
                continue
            unsat = [k for k in light if fsat[k] == 0]
            best = max(unsat, key=lambda k: fexp[k]) if unsat else min(light, key=lambda k: fexp[k])
            if not unsat:
                notes.append(f"point {int(pidx)}: every exposure saturated; used the shortest")
            t = float(fexp[best])
            own = [k for k in mine if not flight[k] and fexp[k] == t]
            other = [k for k in dark_frames if fexp[k] == t]
            if own:
                dark = np.mean([frames[k].astype(float) for k in own], axis=0)
            elif other:
                key = tuple(other)
                if key not in shared_darks:
                    shared_darks[key] = np.mean([frames[k].astype(float) for k in other],
                                                axis=0)
                dark = shared_darks[key]
            elif dark_frames:
                # the black level dominates a dark frame; its dark current (∝ t) is small,
                # so the nearest exposure is the best stand-in
                near = min(dark_frames, key=lambda k: abs(fexp[k] - t))
                dark = frames[near].astype(float)
                notes.append(f"point {int(pidx)}: no dark frame at {t:g} µs; used the one "
                             f"at {fexp[near]:g} µs")
            else:
                dark = np.zeros((h, w))
                notes.append(f"point {int(pidx)}: no dark frame at all; none subtracted")
            img = (frames[best].astype(float) - dark) / (t * cos4)
            ys.append(float(geometry.pinhole_y_mm(pos[row, iz])))
            yaw = None if iyaw is None else float(pos[row, iyaw])
            ths.append(geometry.pixel_theta_rad(np.arange(w), yaw_deg=yaw))
            rads.append(img.mean(axis=0))
            vars_.append(img.var(axis=0, ddof=1) / h if h > 1 else np.full(w, np.nan))
            exps.append(t)
            idxs.append(int(pidx))
    if len(ys) < 4:
        raise ValueError(f"{path}: only {len(ys)} light-field points; need at least 4")
    order = np.argsort(ys, kind="stable")
    return MeasuredScan(
        np.asarray(ys)[order], np.asarray(ths)[order], np.asarray(rads)[order],
        np.asarray(vars_)[order], np.asarray(exps)[order], np.asarray(idxs)[order],
        tuple(dict.fromkeys(notes)))


def default_domain(scan: MeasuredScan, *, margin_fraction: float = 0.02) -> tuple[float, float]:
    """The θ range every point's pixels cover, less ``margin_fraction`` at each end."""
    lo = float(np.max(np.min(scan.theta_rad, axis=1)))
    hi = float(np.min(np.max(scan.theta_rad, axis=1)))
    m = margin_fraction * (hi - lo)
    return (max(lo + m, -1.5), min(hi - m, 1.5))


@dataclass(frozen=True)
class Assembled:
    """The measured light field on the regular grid and what went into each cell.

    Attributes
    ----------
    field : LightField2D (N_y, N_θ) at z = d2
    cell_pixels : (N_θ,) — mean number of pixels per θ cell (cell width / pixel width)
    sigma_rows : float — rms noise of one cell predicted from the sensor-row spread
    """

    field: LightField2D
    cell_pixels: NDArray[np.float64]
    sigma_rows: float


def assemble(
    scan: MeasuredScan,
    *,
    d2_mm: float,
    domain_rad: tuple[float, float] | None = None,
    n_theta: int = 128,
) -> Assembled:
    """Resample the pixel rows onto the regular (y, θ) grid (module doc, item 2).

    θ: each cell-centred cell of the domain gets the exact average, over the cell, of the
    piecewise-constant function the pixels define (each pixel covering θ from midway to
    its neighbours): a box filter matched to the grid, so the pixel noise is averaged
    rather than aliased, and no first-order bias from the pixels' positions in a cell.
    y: uniform grid from the first to the last pinhole position with the median step;
    rows are interpolated linearly where the read-back positions are not on it.
    """
    a, b = default_domain(scan) if domain_rad is None else domain_rad
    th = theta_grid((a, b), n_theta)
    width = (b - a) / n_theta
    p = scan.y_mm.size
    cells = np.empty((p, n_theta))
    var_cells = np.empty((p, n_theta))
    counts = np.zeros((p, n_theta))
    edges_cells = a + width * np.arange(n_theta + 1)
    for r in range(p):
        order = np.argsort(scan.theta_rad[r])
        t = scan.theta_rad[r][order]
        # each pixel covers θ from midway to its left neighbour to midway to its right one
        mid = 0.5 * (t[1:] + t[:-1])
        edges = np.concatenate([[t[0] - (mid[0] - t[0])], mid, [t[-1] + (t[-1] - mid[-1])]])
        if edges_cells[0] < edges[0] or edges_cells[-1] > edges[-1]:
            raise ValueError(f"the angle domain [{a:.4f}, {b:.4f}] rad exceeds the pixels of "
                             f"the point at y = {scan.y_mm[r]:.3f} mm")
        px = np.diff(edges)
        # the integral of the piecewise-constant pixel function is piecewise linear: its
        # differences over the cells are the exact cell averages of that function
        big_f = np.concatenate([[0.0], np.cumsum(scan.radiance[r][order] * px)])
        big_v = np.concatenate([[0.0], np.cumsum(np.nan_to_num(scan.variance[r][order]) * px)])
        cells[r] = np.diff(np.interp(edges_cells, edges, big_f)) / width
        n_px = width / np.interp(th, t, px)
        var_cells[r] = np.diff(np.interp(edges_cells, edges, big_v)) / width / n_px
        counts[r] = n_px
    y = scan.y_mm
    uy, inv = np.unique(np.round(y, 6), return_inverse=True)
    if uy.size < y.size:  # repeated positions: average them
        cells = np.array([cells[inv == i].mean(axis=0) for i in range(uy.size)])
        var_cells = np.array([var_cells[inv == i].mean(axis=0) / np.sum(inv == i)
                              for i in range(uy.size)])
        y = uy
    step = float(np.median(np.diff(y)))
    n_y = round(float(y[-1] - y[0]) / step) + 1
    grid = np.linspace(y[0], y[-1], n_y)
    if n_y != y.size or not np.allclose(grid, y, atol=1e-6 * max(step, 1e-12)):
        cells = np.array([np.interp(grid, y, cells[:, j]) for j in range(n_theta)]).T
    lf = LightField2D(cells, grid, th, (a, b), d2_mm)
    sigma = float(np.sqrt(np.nanmean(var_cells))) if np.any(np.isfinite(var_cells)) \
        else math.nan
    return Assembled(lf, counts.mean(axis=0), sigma)


# ----------------------------------------------------------------------- reconstruction
@dataclass(frozen=True)
class ReconstructionResult:
    """What :func:`reconstruct_run` produced.

    Attributes
    ----------
    measured : Assembled — the measured light field on its grid
    reconstruction : analysis.lightfield.Reconstruction
    p_hat : float — effective highest recovered angular order (filter ≥ ½)
    geometry : LightFieldGeometry
    brdf : FlatlandBRDF
    notes : tuple of str
    figures : tuple of Path
    """

    measured: Assembled
    reconstruction: Reconstruction
    p_hat: float
    geometry: LightFieldGeometry
    brdf: FlatlandBRDF
    notes: tuple[str, ...] = ()
    figures: tuple[Path, ...] = field(default_factory=tuple)


def scattering_points(lf: LightField2D, d2_mm: float) -> NDArray[np.float64]:
    """Wall points whose whole curve ``c + d2 tan θ``, θ ∈ [a, b], lies in the measured y
    range, on the measurement grid's step."""
    a, b = lf.domain_rad
    lo = lf.y_mm[0] - d2_mm * math.tan(a)
    hi = lf.y_mm[-1] - d2_mm * math.tan(b)
    if hi <= lo:
        raise ValueError("the scan is too short for any complete curve: widen the camera_z "
                         "range or narrow the angle domain")
    n = math.floor((hi - lo) / lf.dy_mm + 1e-9) + 1
    return lo + lf.dy_mm * np.arange(n)


def reconstruct_run(
    path: str | Path,
    *,
    geometry: LightFieldGeometry | None = None,
    brdf: FlatlandBRDF | None = None,
    domain_rad: tuple[float, float] | None = None,
    n_theta: int = 128,
    method: str = "wiener",
    write: bool = True,
    figures_dir: str | Path | None = None,
) -> ReconstructionResult:
    """Assemble L_meas from the run, reconstruct the object light field, store the result.

    ``geometry``/``brdf`` default to the emulated bench's own (:func:`geometry_from_run`,
    :func:`brdf_from_run`).  With ``write`` the measured field and the reconstruction go
    into ``/entry/analysis/lightfield``; with ``figures_dir`` the PNG figures too.
    """
    geometry = geometry or geometry_from_run(path)
    brdf = brdf or brdf_from_run(path)
    scan = read_scan(path, geometry)
    measured = assemble(scan, d2_mm=geometry.d2_mm, domain_rad=domain_rad, n_theta=n_theta)
    lf = measured.field
    points = scattering_points(lf, geometry.d2_mm)
    rec = reconstruct(lf, brdf, d2_mm=geometry.d2_mm, points_mm=points,
                      method=method)  # type: ignore[arg-type]
    p_hat = effective_p_max(rec.regularization.filter_factors, rec.orders)
    notes = scan.notes + _noise_disagreement(rec.diagnostics.noise.sigma_per_sample,
                                             measured.sigma_rows, n_theta)
    result = ReconstructionResult(measured, rec, p_hat, geometry, brdf, notes)
    if write:
        _write_reconstruction(path, result)
    if figures_dir is not None:
        from instrument import lightfield_figures

        figs = lightfield_figures.reconstruction_figures(result, figures_dir)
        result = ReconstructionResult(measured, rec, p_hat, geometry, brdf, notes, tuple(figs))
    return result


#: Tail-noise estimate over sensor-row prediction above which the tail holds signal.  The
#: two agree to ~10 % on a resolved scan (examples/lightfield_scan.toml: 2.08e-4 against
#: 2.25e-4 at the default 128 angles); a factor 3 is
#: far outside the scatter of either estimate, so it flags aliasing, not noise.
NOISE_DISAGREEMENT_FACTOR = 3.0


def _noise_disagreement(sigma_tail: float, sigma_rows: float, n_theta: int) -> tuple[str, ...]:
    """A note when the high-frequency tail is dominated by signal, not noise.

    The Wiener/GCV/discrepancy parameters use the tail estimate; if the angular grid is too
    coarse for the signal, the tail holds signal, the noise is overestimated and the
    reconstruction over-smoothed (or declared unrecoverable).
    """
    if sigma_rows > 0 and sigma_tail > NOISE_DISAGREEMENT_FACTOR * sigma_rows:
        return (f"the noise estimated from the high-frequency tail ({sigma_tail:.3g}) is "
                f"{sigma_tail / sigma_rows:.0f}× the sensor-row prediction ({sigma_rows:.3g}): "
                f"the tail holds signal, so the reconstruction is over-regularised; raise "
                f"n_theta (now {n_theta}) until the two agree",)
    return ()


def median_delta_p(delta_p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Median over points of Δ_p (R, N) → (N,), ignoring the ``inf`` of unobservable
    orders; ``inf`` where no point has a finite value."""
    d = np.asarray(delta_p, dtype=float)
    fin = np.isfinite(d)
    out = np.full(d.shape[-1], np.inf)
    cols = fin.any(axis=0)
    if np.any(cols):
        masked = np.where(fin[:, cols], d[:, cols], np.nan)
        out[cols] = np.nanmedian(masked, axis=0)
    return out


def _replace(group: h5py.Group, name: str, nx_class: str) -> h5py.Group:
    if name in group:
        del group[name]
    g = group.create_group(name)
    g.attrs["NX_class"] = nx_class
    return g


def _analysis_group(f: h5py.File) -> h5py.Group:
    entry = f["entry"]
    if "analysis" not in entry:
        entry.create_group("analysis").attrs["NX_class"] = "NXcollection"
    g = entry["analysis"]
    if "lightfield" not in g:
        g.create_group("lightfield").attrs["NX_class"] = "NXprocess"
    return g["lightfield"]


def _brdf_dict(b: FlatlandBRDF) -> dict[str, Any]:
    return {"name": b.name, "specular_reflectance": b.specular_reflectance,
            "specular_width_rad": b.specular_width_rad,
            "diffuse_reflectance": b.diffuse_reflectance,
            "window_exponent": b.window_exponent}


def _write_reconstruction(path: str | Path, r: ReconstructionResult) -> None:
    from instrument.runner import software_version

    rec = r.reconstruction
    reg = rec.regularization
    diag = rec.diagnostics
    lf = r.measured.field
    with h5py.File(path, "r+") as f:
        if _s(f["entry"].attrs.get("status", "")) == "running":
            raise RuntimeError(f"{path} is still being written; analyse it when the run ends")
        g = _analysis_group(f)
        g.attrs["program"] = "scatterlab instrument.lightfield_io"
        g.attrs["version"] = software_version()
        g.attrs["date"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        g.attrs["geometry"] = json.dumps(r.geometry.as_dict())
        g.attrs["brdf"] = json.dumps(_brdf_dict(r.brdf))
        g.attrs["notes"] = json.dumps(list(r.notes))
        m = _replace(g, "measured", "NXdata")
        m["radiance"] = lf.radiance
        m["radiance"].attrs["units"] = "DN/us (cos^4-corrected, proportional to radiance)"
        m["y_mm"] = lf.y_mm
        m["theta_rad"] = lf.theta_rad
        m["cell_pixels"] = r.measured.cell_pixels
        m.attrs["domain_rad"] = lf.domain_rad
        m.attrs["d2_mm"] = lf.z_mm
        m.attrs["sigma_rows"] = r.measured.sigma_rows
        m.attrs["signal"] = "radiance"
        c = _replace(g, "reconstruction", "NXdata")
        c["incident_radiance"] = rec.incident_field.radiance
        c["points_mm"] = rec.incident_field.y_mm
        c["theta_rad"] = rec.incident_field.theta_rad
        c["filter_factors"] = np.atleast_2d(reg.filter_factors).mean(axis=0)
        c["orders"] = rec.orders
        c["signal_power"] = reg.signal_power
        c["noise_power"] = reg.noise_power
        c["gamma"] = diag.gamma
        c["snr_eff"] = diag.snr_eff
        c["delta_p"] = median_delta_p(diag.delta_p)
        c["valid_fraction"] = rec.valid_fraction
        c.attrs.update({
            "signal": "incident_radiance", "method": reg.method,
            "parameter_name": reg.parameter_name, "parameter": reg.parameter,
            "effective_dof": reg.effective_dof, "residual_ratio": reg.residual_ratio,
            "recoverable": rec.recoverable, "message": rec.message, "solver": rec.solver,
            "p_hat": r.p_hat, "solvable_domain_rad": rec.solvable_domain_rad,
            "noise_sigma": diag.noise.sigma_per_sample, "noise_method": diag.noise.method,
            "domain_rad": rec.incident_field.domain_rad,
        })
        if "localisation" in g:  # stale: it belonged to an earlier reconstruction
            del g["localisation"]


def _read_reconstruction(path: str | Path) -> dict[str, Any] | None:
    with h5py.File(path, "r") as f:
        if f"{GROUP}/reconstruction" not in f:
            return None
        c = f[f"{GROUP}/reconstruction"]
        g = f[GROUP]
        out = {k: c[k][()] for k in ("incident_radiance", "points_mm", "theta_rad",
                                     "filter_factors", "orders")}
        out.update({k: c.attrs[k] for k in ("p_hat", "solvable_domain_rad", "domain_rad",
                                            "recoverable", "message")})
        out["geometry"] = json.loads(_s(g.attrs["geometry"]))
    return out


# ------------------------------------------------------------------------- localisation
@dataclass(frozen=True)
class LocalisationResult:
    """What :func:`locate_run` found.

    Attributes
    ----------
    detection : analysis.lightfield.Detection (count, (y, z), brightness, resolutions,
        focal stack, depth profiles)
    p_hat : float — the angular order the resolutions are computed from
    recoverable : bool — False: the reconstruction holds no object information (then
        nothing is detected)
    message : str
    figures : tuple of Path
    """

    detection: Detection
    p_hat: float
    recoverable: bool
    message: str
    figures: tuple[Path, ...] = ()


def locate_run(
    path: str | Path,
    *,
    y_range_mm: tuple[float, float] | None = None,
    z_range_mm: tuple[float, float] = (-400.0, -60.0),
    y_step_mm: float = 0.5,
    z_step_mm: float = 1.0,
    threshold_rel: float = 0.3,
    min_measure_fraction: float = 0.1,
    write: bool = True,
    figures_dir: str | Path | None = None,
    **reconstruct_options: Any,
) -> LocalisationResult:
    """Locate the hidden objects of a light-field run (reconstructing it first if needed).

    The trial grid covers ``y_range_mm`` (default: the reconstructed wall points ± 60 mm)
    and ``z_range_mm`` (z < 0, in front of the wall, unfolded).  Trial points seen through
    less than ``min_measure_fraction`` of the solvable angle domain are not searched: a
    light-field bench's wall aperture W limits that fraction to about
    ``W / (|z| (B − A))``, so the default is lower than the analysis default (0.25), which
    would hide everything beyond ~230 mm on the 100 mm emulated stage.  ``threshold_rel``:
    detections weaker than this fraction of the strongest are dropped.  Results go to
    ``/entry/analysis/lightfield/localisation``.
    """
    for name, rng in (("y_range_mm", y_range_mm), ("z_range_mm", z_range_mm)):
        if rng is not None and not (len(rng) == 2 and float(rng[0]) < float(rng[1])):
            raise ValueError(f"{name} {tuple(rng)} must be (low, high) with low < high (mm)")
    if not 0.0 <= threshold_rel < 1.0:
        raise ValueError(f"threshold_rel {threshold_rel:g} must be in [0, 1): a fraction of "
                         f"the strongest detection")
    stored = None if reconstruct_options else _read_reconstruction(path)
    if stored is None:
        reconstruct_run(path, write=True, **reconstruct_options)
        stored = _read_reconstruction(path)
        if stored is None:  # pragma: no cover - written just above
            raise RuntimeError("the reconstruction was not stored")
    dom = tuple(float(x) for x in stored["domain_rad"])
    field_ = LightField2D(stored["incident_radiance"], stored["points_mm"],
                          stored["theta_rad"], dom, 0.0)  # type: ignore[arg-type]
    p_hat = float(stored["p_hat"])
    pts = stored["points_mm"]
    y_lo, y_hi = y_range_mm or (float(pts[0]) - 60.0, float(pts[-1]) + 60.0)
    ys = np.arange(y_lo, y_hi + 0.5 * y_step_mm, y_step_mm)
    zs = np.arange(z_range_mm[0], z_range_mm[1] + 0.5 * z_step_mm, z_step_mm)
    if np.any(zs >= 0):
        raise ValueError("z_range_mm must lie in front of the wall (z < 0)")
    solvable = tuple(float(x) for x in stored["solvable_domain_rad"])
    recoverable = bool(stored["recoverable"])
    if recoverable:
        det = detect_objects(field_, p_max=p_hat, y_mm=ys, z_mm=zs,
                             solvable_domain_rad=solvable,  # type: ignore[arg-type]
                             filter_factors=stored["filter_factors"], threshold_rel=threshold_rel,
                             min_measure_fraction=min_measure_fraction)
        message = f"{det.count} object(s) found (p̂_max = {p_hat:g})"
    else:
        det = detect_objects(field_, p_max=0.0, y_mm=ys, z_mm=zs,
                             solvable_domain_rad=solvable,  # type: ignore[arg-type]
                             max_objects=0)
        message = f"nothing located: {_s(stored['message'])}"
    if write:
        _write_localisation(path, det, p_hat, message)
    figs: tuple[Path, ...] = ()
    if figures_dir is not None:
        from instrument import lightfield_figures

        figs = tuple(lightfield_figures.localisation_figures(det, p_hat, figures_dir))
    return LocalisationResult(det, p_hat, recoverable, message, figs)


def _write_localisation(path: str | Path, det: Detection, p_hat: float, message: str) -> None:
    with h5py.File(path, "r+") as f:
        g = _analysis_group(f)
        loc = _replace(g, "localisation", "NXdata")
        loc["positions_mm"] = det.positions_mm
        loc["positions_mm"].attrs["columns"] = "y_mm, z_mm"
        loc["brightness_rp"] = det.brightness_rp
        loc["brightness_conventional"] = det.brightness_conventional
        loc["transverse_mm"] = np.array([r.transverse_mm for r in det.resolutions])
        loc["depth_mm"] = np.array([r.depth_mm for r in det.resolutions])
        loc["depth_profiles"] = det.depth_profiles
        # What the depth is worth: the interval the data support, the flag, and the three
        # estimates behind it (depth filter, matched filter, RP peak).
        loc["depth_interval_mm"] = det.depth_interval_mm
        loc["depth_interval_mm"].attrs["columns"] = "far_mm, near_mm"
        loc["depth_estimates_mm"] = det.depth_estimates_mm
        loc["depth_estimates_mm"].attrs["columns"] = (
            "depth_filter_mm, matched_filter_mm, radiance_preserving_mm")
        loc["quality"] = np.array(det.quality, dtype=h5py.string_dtype())
        loc["stack_y_mm"] = det.stack.y_mm
        loc["stack_z_mm"] = det.stack.z_mm
        loc["stack_conventional"] = det.stack.conventional
        loc["stack_rp"] = det.stack.radiance_preserving
        loc.attrs.update({"count": det.count, "p_hat": p_hat, "message": message,
                          "signal": "stack_rp"})


def resolution_at(p_hat: float, depth_mm: float, *, domain_rad: tuple[float, float],
                  aperture_mm: float,
                  solvable_domain_rad: tuple[float, float] | None = None) -> tuple[float, float]:
    """(transverse, depth) theoretical blur in mm for an object ``depth_mm`` from the wall
    (:func:`analysis.lightfield.theoretical_resolution`)."""
    r = theoretical_resolution(p_hat, domain_rad=domain_rad, distance_mm=abs(depth_mm),
                               aperture_mm=aperture_mm, solvable_domain_rad=solvable_domain_rad)
    return r.transverse_mm, r.depth_mm
