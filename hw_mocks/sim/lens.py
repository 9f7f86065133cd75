"""What the simulated camera's rendering needs that depends only on its lens and sensor.

In the camera frame (x = image right, y = image down, z = the optical axis, mm, origin at
the entrance-pupil centre) the pixel at tangent coordinates (u, v) = (p·i/f, p·j/f) (p the
pitch, i and j the pixel's offsets from the sensor centre) looks along (u, v, 1)/√(1+u²+v²)
and, through an ideal thin lens focused at F, sees the point F·(u, v, 1) of the focus plane.
A ray from the pupil point ρ·(x, y, 0) to that point makes the angle γ with the axis,

    cos γ = F / √((F u − ρ x)² + (F v − ρ y)² + F²),

whatever the pose of the camera. So the chief rays' obliquity cos α, and the pupil's own
obliquity (1/A)∫cos⁴γ da of every pixel (module docstring of
:mod:`hw_mocks.sim.camera`, step 3), depend only on the sensor, the ROI, the lens and the
focus distance: :func:`lens_grid` computes them once per such set and keeps them, so that a
re-rendered view (after a move, or a dark frame) pays only for the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from hw_mocks.sim import pupil as pupil_rules

__all__ = ["LensGrid", "PupilBundle", "lens_grid"]


@dataclass(frozen=True)
class LensGrid:
    """Per-pixel quantities of a ROI that depend on the lens and sensor alone.

    Attributes
    ----------
    u, v : ndarray, shapes (W,) and (H,)
        Tangent coordinates of the pixel columns (image right) and rows (image down).
    cos_alpha : ndarray, shape (H, W)
        cos α of every chief ray to the optical axis.
    obliquity : ndarray, shape (H, W)
        (1/A)∫cos⁴γ da over the pupil (Radon's degree-5 rule, exact to (ρ/F)⁶ ≈ 10⁻¹⁰).
    focus_mm, pupil_radius_mm : float
    """

    u: NDArray[np.float64]
    v: NDArray[np.float64]
    cos_alpha: NDArray[np.float64]
    obliquity: NDArray[np.float64]
    focus_mm: float
    pupil_radius_mm: float

    def chief_directions(self, rows: slice, cols: slice, right: NDArray, down: NDArray,
                         forward: NDArray) -> NDArray[np.float64]:
        """Unit lab directions (h, w, 3) of the chief rays of ``rows`` × ``cols``."""
        u, v = self.u[cols], self.v[rows]
        dirs = (forward[None, None, :] + u[None, :, None] * right[None, None, :]
                + v[:, None, None] * down[None, None, :])
        dirs *= self.cos_alpha[rows, cols][..., None]
        return dirs

    def pupil_rays(self, x: float, y: float, rows: NDArray[np.intp], cols: NDArray[np.intp],
                   right: NDArray, down: NDArray, forward: NDArray
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The rays from the pupil point ρ·(x, y) (unit-disk coordinates) to the conjugate
        points of the pixels (``rows``, ``cols``): unit lab directions (M, 3) and cos γ (M,)."""
        f, rho = self.focus_mm, self.pupil_radius_mm
        dx = f * self.u[cols] - rho * x
        dy = f * self.v[rows] - rho * y
        inv = 1.0 / np.sqrt(dx * dx + dy * dy + f * f)
        dx *= inv
        dy *= inv
        cos_g = f * inv
        # built component by component into a (3, M) array and returned as its (M, 3)
        # transpose: every component contiguous, which the scene's per-component dot
        # products read several times faster than an interleaved (M, 3) array
        d = np.empty((3, dx.size))
        for i in range(3):
            np.multiply(dx, right[i], out=d[i])
            d[i] += dy * down[i]
            d[i] += cos_g * forward[i]
        return d.T, cos_g


    def pupil_bundle(self, rows: NDArray[np.intp], cols: NDArray[np.intp], right: NDArray,
                     down: NDArray, forward: NDArray) -> PupilBundle:
        """The rays from every pupil point to the conjugate points of the pixels
        (``rows``, ``cols``), as projectors (:class:`PupilBundle`)."""
        return PupilBundle(self, rows, cols, (right, down, forward))


class PupilBundle:
    """The rays of :meth:`LensGrid.pupil_rays` for a set of pixels and any pupil point, as
    projectors ``a ↦ d · a`` (a scene asks for a few projections of each ray and never
    needs the (M, 3) directions).

    For the pupil point ρ(x, y) and the pixel's conjugate point F(u, v, 1) (camera frame)
    the ray is d = (Fu − ρx, Fv − ρy, F)/|·|, so for a lab vector a with camera-frame
    components (a_r, a_d, a_f)

        d · a = (P_a − ρ(x a_r + y a_d)) / |·|,    P_a = Fu a_r + Fv a_d + F a_f,

    where P_a depends on the pixel alone: it is computed once per pixel set and vector a
    and reused by every pupil point of every rule (two passes a ray instead of five)."""

    def __init__(self, grid: LensGrid, rows: NDArray[np.intp], cols: NDArray[np.intp],
                 axes: tuple[NDArray, NDArray, NDArray]) -> None:
        self._f, self._rho = grid.focus_mm, grid.pupil_radius_mm
        self._fu = self._f * grid.u[cols]
        self._fv = self._f * grid.v[rows]
        self._axes = axes
        self._per_pixel: dict[bytes, tuple[NDArray[np.float64], float, float]] = {}

    def _pixel_part(self, a: NDArray) -> tuple[NDArray[np.float64], float, float]:
        """(P_a, a_r, a_d) for the lab vector a, cached."""
        a = np.asarray(a, dtype=float)
        key = a.tobytes()
        hit = self._per_pixel.get(key)
        if hit is None:
            a_r, a_d, a_f = (float(axis @ a) for axis in self._axes)
            p = self._fu * a_r + self._fv * a_d  # (broadcast: rows and columns may be
            p += self._f * a_f  # index arrays of shapes (h, 1) and (1, w))
            hit = self._per_pixel[key] = (p, a_r, a_d)
        return hit

    def rays(self, x: float, y: float):
        """The rays from the pupil point ρ·(x, y) (unit-disk coordinates): a projector
        ``a ↦ d · a`` (M,) for lab vectors a, and their cos γ (M,)."""
        f, rho = self._f, self._rho
        dx = self._fu - rho * x
        dy = self._fv - rho * y
        dx *= dx
        dy *= dy
        s = dx + dy
        s += f * f
        np.sqrt(s, out=s)
        inv = np.divide(1.0, s, out=s)
        rx, ry = rho * x, rho * y

        def project(a: NDArray) -> NDArray[np.float64]:
            p, a_r, a_d = self._pixel_part(a)
            out = p - (rx * a_r + ry * a_d)
            out *= inv
            return out

        return project, f * inv


@lru_cache(maxsize=8)
def lens_grid(roi: tuple[int, int, int, int], sensor_size: tuple[int, int], pitch_um: float,
              focal_length_mm: float, pupil_radius_mm: float, focus_mm: float) -> LensGrid:
    """The :class:`LensGrid` of ``roi`` = (x, y, width, height) on a sensor of
    ``sensor_size`` = (width, height) pixels; arrays are read-only (shared by every view)."""
    x0, y0, w, h = roi
    width, height = sensor_size
    scale = pitch_um * 1e-3 / focal_length_mm
    u = (np.arange(x0, x0 + w) - (width - 1) / 2.0) * scale
    v = (np.arange(y0, y0 + h) - (height - 1) / 2.0) * scale
    cos_alpha = 1.0 / np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2)
    rule = pupil_rules.radon7()
    f, rho = focus_mm, pupil_radius_mm
    obliquity = np.zeros((h, w))
    for k in range(len(rule)):
        dx2 = (f * u - rho * rule.x[k]) ** 2
        dy2 = (f * v - rho * rule.y[k]) ** 2
        s = dx2[None, :] + dy2[:, None] + f * f
        obliquity += rule.weights[k] * (f ** 4) / (s * s)  # cos⁴γ = F⁴ / |X − a|⁴
    for a in (u, v, cos_alpha, obliquity):
        a.flags.writeable = False
    return LensGrid(u=u, v=v, cos_alpha=cos_alpha, obliquity=obliquity,
                    focus_mm=float(focus_mm), pupil_radius_mm=float(pupil_radius_mm))


def pixel_box(points_mm: NDArray[np.float64], center: NDArray, right: NDArray, down: NDArray,
              forward: NDArray, grid: LensGrid, margin_px: int
              ) -> tuple[slice, slice] | None:
    """Rows and columns of the ROI that the chief rays through the lab points
    ``points_mm`` (K, 3) reach, as a box grown by ``margin_px``: the box holds the image of
    their convex hull (a perspective projection maps a convex set in front of the pupil
    onto the convex hull of its vertices' images). None: a point lies at or behind the
    pupil plane (no box bounds its image); an empty box when the image misses the ROI."""
    rel = np.asarray(points_mm, dtype=float) - center
    depth = rel @ forward
    if np.any(depth <= 1e-9):
        return None
    pu = (rel @ right) / depth
    pv = (rel @ down) / depth
    step_u = grid.u[1] - grid.u[0] if grid.u.size > 1 else 1.0
    step_v = grid.v[1] - grid.v[0] if grid.v.size > 1 else 1.0
    c0 = math.floor((pu.min() - grid.u[0]) / step_u) - margin_px
    c1 = math.ceil((pu.max() - grid.u[0]) / step_u) + margin_px + 1
    r0 = math.floor((pv.min() - grid.v[0]) / step_v) - margin_px
    r1 = math.ceil((pv.max() - grid.v[0]) / step_v) + margin_px + 1
    w, h = grid.u.size, grid.v.size
    c0, c1 = min(max(c0, 0), w), min(max(c1, 0), w)
    r0, r1 = min(max(r0, 0), h), min(max(r1, 0), h)
    return slice(r0, r1), slice(c0, c1)
