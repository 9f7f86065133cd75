"""Sphere captures: run file → HDR radiance images indexed [lighting, object].

A ``sphere_capture`` run holds one point per (lighting, object): the lighting axis
(``source_theta`` by default: the goniometer moves the source and with it the lighting) and
the sample changer (``sample_phi``) at the positions the plan names. Each point has its HDR
brackets and, with ``dark = "per_point"``, one dark per bracket. :func:`read_capture` matches
every point to its (lighting k, object j) by the read-back positions of the two axes against
the plan stored in the file and merges the brackets (:func:`analysis.hdr.merge_hdr`,
inverse-variance weights from the camera's EMVA 1288 constants when known) into a radiance
image (:func:`analysis.radiometry.rate_to_radiance` with the pinhole's cos⁴α; relative
units, DN/µs, when the camera has no calibration; no flat field: PRNU stays in the image).
:func:`locate_sphere` finds the sphere in the images.

Image frame of :mod:`analysis.sh.sphere_image` (x along columns, y up, z towards the
camera), the lab frame of the bench when ``detector_theta = 0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from analysis.hdr import merge_hdr
from analysis.radiometry import (
    CameraResponse,
    pinhole_relative_illumination,
    rate_to_radiance,
)
from instrument.run.layout import FRAMES_LOST
from instrument.run.runfile import RunData, read_run

__all__ = ["SphereCapture", "locate_sphere", "read_capture"]


@dataclass(frozen=True)
class SphereCapture:
    """The HDR images of a sphere capture, indexed [lighting k, object j].

    Attributes
    ----------
    path : Path
    objects : tuple of str, length s
    lighting_deg : tuple of float, length r
        Lighting-axis positions of the plan.
    selector, lighting_role : str
        The sample-changer and lighting axes.
    known_brdf : dict
        Object name → the BRDF the plan declares known (``{model, ...}``).
    radiance : ndarray of shape (r, s, H, W)
        Merged radiance (``units``).
    variance : ndarray of shape (r, s, H, W)
        Its variance from the noise model (NaN when the camera has no noise model).
    valid : ndarray of bool, shape (r, s, H, W)
        Not saturated in every bracket (radiance there is a lower bound only).
    rows : ndarray of int, shape (r, s)
        Row of each image in the run file's point table.
    units : str
    camera : dict
        ``pixel_pitch_um`` and ``focal_length_mm`` when known (pinhole intrinsics).
    """

    path: Path
    objects: tuple[str, ...]
    lighting_deg: tuple[float, ...]
    selector: str
    lighting_role: str
    known_brdf: dict[str, dict[str, Any]]
    radiance: np.ndarray
    variance: np.ndarray
    valid: np.ndarray
    rows: np.ndarray
    units: str
    camera: dict[str, float] = field(default_factory=dict)


def _match(values: np.ndarray, targets: list[float], what: str, tol: float) -> np.ndarray:
    """Index of the target each read-back value belongs to (angles compared mod 360)."""
    t = np.asarray(targets, dtype=float)
    d = np.abs((values[:, None] - t[None, :] + 180.0) % 360.0 - 180.0)
    idx = np.argmin(d, axis=1)
    far = d[np.arange(values.size), idx] > tol
    if np.any(far):
        raise ValueError(f"{what}: read-back position(s) {values[far]} match no plan position "
                         f"within {tol:g} deg")
    return cast(np.ndarray, idx)  # numpy's stubs: Any


def read_capture(path: str | Path, *, position_tol_deg: float = 0.5) -> SphereCapture:
    """Read a ``sphere_capture`` run and merge each point's brackets into a radiance image.

    Raises
    ------
    ValueError
        Not a sphere capture, an image missing (every (lighting, object) pair is needed),
        or a point whose positions match no planned one.
    """
    run = read_run(path)
    if run.plan_kind != "sphere_capture":
        raise ValueError(f"{run.path} is a {run.plan_kind!r} run, not a sphere_capture")
    spec = run.plan()
    scan = spec.scan
    selector = str(scan.get("selector", "sample_phi"))
    lrole = str(scan.get("lighting_role", "source_theta"))
    objects = tuple(str(o["name"]) for o in scan["objects"])
    stations = [float(o["station_deg"]) for o in scan["objects"]]
    lights = [float(x) for x in scan["lighting_deg"]]
    known = {str(o["name"]): dict(o["known_brdf"]) for o in scan["objects"]
             if "known_brdf" in o}
    rows = np.flatnonzero((run.label == "sphere") & (run.point_status == 0))
    k_of = _match(run.position(lrole)[rows], lights, lrole, position_tol_deg)
    j_of = _match(run.position(selector)[rows], stations, selector, position_tol_deg)
    table = np.full((len(lights), len(objects)), -1)
    for row, k, j in zip(rows, k_of, j_of, strict=True):
        table[k, j] = row  # a point taken twice (resume): the last one counts
    if np.any(table < 0):
        missing = [(lights[k], objects[j]) for k, j in zip(*np.nonzero(table < 0), strict=True)]
        lost = run.index[run.point_status == FRAMES_LOST]
        why = (f"; the frames of point(s) {', '.join(map(str, lost))} were lost to a damaged "
               f"file: measure them again with `scatterlab resume --remeasure-lost "
               f"{run.path}`" if lost.size else "")
        raise ValueError(f"{run.path}: no image for (lighting, object) {missing}{why}")
    merger = _Merger(run)
    imgs, vars_, valid = [], [], []
    for row in table.ravel():
        rad, var, ok = merger.merge(int(row))
        imgs.append(rad)
        vars_.append(var)
        valid.append(ok)
    shape = table.shape + imgs[0].shape
    return SphereCapture(
        run.path, objects, tuple(lights), selector, lrole, known,
        np.array(imgs).reshape(shape), np.array(vars_).reshape(shape),
        np.array(valid).reshape(shape), table, merger.units, merger.camera,
    )


class _Merger:
    """HDR merge of a run's points with the camera's constants (when known)."""

    def __init__(self, run: RunData) -> None:
        self.run = run
        self.camera: dict[str, float] = {}
        try:
            cal = run.camera_calibration()
        except ValueError:
            cal = None
        fmt = run.identities.get("camera", {}).get("pixel_format", "MONO12").upper()
        bits = int(fmt[4:]) if fmt.startswith("MONO") and fmt[4:].isdigit() else 12
        if cal is None:
            self.saturation = float(2**bits - 1)
            self.gain = self.read_dn = None
            self.response = None
            self.units = "DN/us (relative radiance)"
            return
        n = cal.noise
        self.saturation = float(n.saturation_dn)
        self.gain = float(n.system_gain_dn_per_e)
        self.read_dn = float(n.read_noise_e * n.system_gain_dn_per_e)
        if cal.pixel_pitch_um is not None and cal.focal_length_mm is not None:
            self.camera = {"pixel_pitch_um": float(cal.pixel_pitch_um),
                           "focal_length_mm": float(cal.focal_length_mm)}
            self.response = CameraResponse(self.gain, cal.quantum_efficiency,
                                           cal.wavelength_nm, float(cal.pixel_pitch_um),
                                           float(cal.focal_length_mm), cal.pupil_diameter_mm)
            self.units = "W m-2 sr-1"
        else:
            self.response = None
            self.units = "DN/us (relative radiance)"

    def merge(self, row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        frames, exposures, darks = self.run.frames_of(row)
        if darks is None:
            # No dark frames: the black level is the best dark there is (EMVA 1288 offset).
            darks = np.zeros_like(frames)
        model = self.gain is not None
        res = merge_hdr(frames, exposures, darks=darks, saturation_dn=self.saturation,
                        weighting="inverse_variance" if model else "hat",
                        system_gain_dn_per_e=self.gain,
                        read_noise_dn=self.read_dn if model else None)
        rate, var = res.rate, res.variance
        if var is None:
            var = np.full(rate.shape, np.nan)
        if self.response is not None:
            # camera equation inverted per pixel, natural vignetting cos⁴α included
            f_px = 1e3 * self.camera["focal_length_mm"] / self.camera["pixel_pitch_um"]
            rel = pinhole_relative_illumination(rate.shape, focal_length_px=f_px)
            scale = rate_to_radiance(np.ones(rate.shape), response=self.response,
                                     relative_illumination=rel)
            rate, var = rate * scale, var * scale**2
        return rate, var, ~res.saturated


def locate_sphere(images: np.ndarray, *, threshold: float = 1e-3) -> tuple[tuple[float, float],
                                                                            float]:
    """Centre (x, y) and radius (px) of the sphere's image from the lit disc.

    The disc is where the summed images exceed ``threshold`` × their 99th percentile (the
    background is black); its centroid is the centre and √(area/π) the radius (pixel
    centres sample the disc uniformly, so the area estimate is unbiased).

    Parameters
    ----------
    images : ndarray of shape (..., H, W)
    """
    a = np.asarray(images, dtype=float)
    total = np.nansum(np.abs(a.reshape(-1, *a.shape[-2:])), axis=0)
    level = threshold * float(np.percentile(total, 99.0))
    disc = total > level
    if disc.sum() < 20:
        raise ValueError("no sphere found in the images")
    yy, xx = np.nonzero(disc)
    return (float(xx.mean()), float(yy.mean())), float(math.sqrt(disc.sum() / math.pi))
