"""Assembly of a light-field run: frames → per-point pixel rows → the measured field on a grid.

For every light-field point the longest unsaturated exposure is taken, its dark frame (same
point, or the run's dark frames at the same exposure) subtracted, the result divided by the
exposure and by the camera's ``cos⁴α`` fall-off (α the field angle of the pixel), and the
rows averaged: a quantity proportional to radiance (``DN/µs``, no absolute calibration needed
for localisation). The pixel samples are then averaged into the cells of the regular
cell-centred θ grid on the domain [a, b] (box average: the pixels are several times finer than
the grid, so this is the anti-aliasing resampling), and interpolated linearly onto a uniform y
grid when the read-back stage positions are not uniform.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from analysis.lightfield import (
    LightField2D,
    theta_grid,
)
from instrument.pipelines.lightfield.geometry import GeometryError, LightFieldGeometry
from instrument.run.runfile import read_plan_kind, read_run

__all__ = ["Assembled", "MeasuredScan", "assemble", "default_domain", "read_scan"]


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


def read_scan(path: str | Path, geometry: LightFieldGeometry) -> MeasuredScan:
    """Frames of a light-field run → per-point rows of pixel samples (module docstring)."""
    notes: list[str] = []
    kind = read_plan_kind(path)
    if kind != "lightfield":
        raise ValueError(f"{path} is a {kind!r} run, not a light-field scan")
    run = read_run(path)
    axes = list(run.axes)
    if "camera_z" not in axes:
        raise ValueError("the run has no camera_z axis")
    labels, index, status, pos = run.label, run.index, run.point_status, run.positions
    fpoint, fexp, fsat = run.frame_point, run.frame_exposure_us, run.frame_saturated
    flight = run.frame_light.astype(bool)
    with run.frames() as frames:
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
        # Dark frames of measured points only: a point whose frames a damaged file lost
        # (status 2) holds zeros, and frames of no point (frame_point -1) were superseded.
        valid = {int(i) for i, st in zip(index, status, strict=True) if st == 0}
        dark_frames = [k for k in range(len(fpoint))
                       if not flight[k] and int(fpoint[k]) in valid]
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
                notes.append(f"point {int(pidx)}: every exposure saturated; used the shortest "
                             f"(its brightest pixels are clipped)")
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
