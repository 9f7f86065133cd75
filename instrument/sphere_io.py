"""Sphere captures: run file → HDR radiance images → spherical-harmonic analysis → run file.

A ``sphere_capture`` run (:mod:`instrument.plans`) holds one point per (lighting, object):
the lighting axis (``source_theta`` by default: the goniometer moves the source and with it
the lighting) and the sample changer (``sample_phi``) at the positions the plan names. Each
point has its HDR brackets (the engine's auto-exposure policy) and, with
``dark = "per_point"``, one dark per bracket. This module

1. matches every point to its (lighting k, object j) by the read-back positions of the two
   axes against the plan stored in the file;
2. merges the brackets (:func:`analysis.hdr.merge_hdr`, inverse-variance weights from the
   camera's EMVA 1288 constants when known) into a radiance image
   (:func:`analysis.radiometry.rate_to_radiance` with the pinhole's cos⁴α; relative units,
   DN/µs, when the camera has no calibration; no flat field: PRNU stays in the image);
3. finds the sphere in the images (centroid and area of the lit disc) and maps pixels to
   normals and reflected directions (:func:`analysis.sh.sphere_image.sphere_geometry`, with
   the camera's pinhole intrinsics when known), fits B_lm of every image with one shared
   least-squares operator;
4. runs the identities of physics.md §5 — M16 (two objects, one lighting) per lighting,
   M21 (two objects × two lightings) on the corner images, M25 (rank one) on all — and,
   for an object whose BRDF the plan declares known, estimates each lighting by Wiener
   deconvolution (M7) and tests M10 (known lighting) and M19 (one object, two lightings);
5. renders the last image B^{r,s} from B^{1,1}, B^{1,s}, B^{r,1} by BRDF transfer
   (M15/M20, the preferred route) and reports its L1 error against the measured image;
6. checks consistency: the per-order M21 errors against their distribution on consistent
   data simulated at the measured noise level (a parametric bootstrap,
   :mod:`analysis.sh.consistency`). α is calibrated against that noise model only, not
   against the departures from the ideal convolution that consistent captures share (the
   sphere's horizon, the finite view, orders above ``lmax``): on the simulated bench the
   measured false-alarm rate is above α (:data:`CONSISTENCY_LIMIT`);
7. writes the results into ``/entry/analysis`` of the run file (replacing an earlier
   analysis) and draws the relighting figure.

Units and frames: angles in degrees at the interface; image frame of
:mod:`analysis.sh.sphere_image` (x along columns, y up, z towards the camera), which is the
lab frame of the bench when ``detector_theta = 0``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from analysis.hdr import merge_hdr
from analysis.radiometry import (
    CameraResponse,
    pinhole_relative_illumination,
    rate_to_radiance,
)
from analysis.sh.consistency import (
    ConsistencyReport,
    bootstrap_consistent_errors,
    calibrate,
    check,
    scale_threshold,
)
from analysis.sh.convolve import wiener_deconvolve
from analysis.sh.filters import phong_filter
from analysis.sh.identities import (
    IdentityError,
    brdf_transfer,
    four_images,
    known_lighting,
    one_object_two_lightings,
    rank_one,
    render_missing_image,
    two_objects_one_lighting,
)
from analysis.sh.sphere_image import (
    SphereGeometry,
    image_fit_operator,
    images_to_sh,
    sh_to_image,
    sphere_geometry,
)
from instrument.analysis_io import RunData, camera_calibration_for, read_run
from instrument.plans.planfile import parse_plan

__all__ = [
    "CONSISTENCY_LIMIT",
    "SIM_SPHERES_THRESHOLD_SCALE",
    "SphereAnalysis",
    "SphereCapture",
    "analyse_capture",
    "analyse_run",
    "locate_sphere",
    "read_capture",
    "relighting_figure",
    "write_sphere_analysis",
]


# ------------------------------------------------------------------------------ reading
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
    return idx


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
    spec = parse_plan(run.plan_text, source=str(run.path))
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
        raise ValueError(f"{run.path}: no image for (lighting, object) {missing}")
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
            cal = camera_calibration_for(run)
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


# ------------------------------------------------------------------------------ analysis
@dataclass(frozen=True)
class SphereAnalysis:
    """Results of :func:`analyse_capture`.

    Attributes
    ----------
    lmax : int
    center : (float, float)
    radius : float
        Sphere image centre (x, y) and radius in pixels.
    coeffs : ndarray of shape (r, s, (lmax+1)²)
        B_lm of every image (reflected parameterisation).
    identities : dict of str → IdentityError
        M16 per lighting ("M16 lighting k"), M21 (corner images), M25 (all), and with a
        known BRDF M10 per image ("M10 k,j") and M19 per object ("M19 object").
    gamma : ndarray of shape (lmax+1,)
        BRDF transfer γ_l from object 1 to object s in lighting 1.
    predicted : ndarray of shape (H, W)
        B^{r,s} rendered from the other corner images (NaN off the sphere).
    measured : ndarray of shape (H, W)
    relight_l1 : float
        Σ|predicted − measured| / Σ|measured| over the observed pixels.
    observed : ndarray of bool, shape (H, W)
    lighting : ndarray of shape (r, (lmax+1)²) or None
        Lighting estimated from the object of known BRDF (Wiener, M7).
    lighting_object : str or None
    consistency : ConsistencyReport
        M21 per-order errors against the calibrated noise level.
    threshold_scale : float
        The factor the bootstrap threshold was multiplied by (1: noise-only threshold).
    """

    lmax: int
    center: tuple[float, float]
    radius: float
    coeffs: np.ndarray
    identities: dict[str, IdentityError]
    gamma: np.ndarray
    predicted: np.ndarray
    measured: np.ndarray
    relight_l1: float
    observed: np.ndarray
    lighting: np.ndarray | None
    lighting_object: str | None
    consistency: ConsistencyReport
    threshold_scale: float = 1.0


def _known_filter(brdf: dict[str, Any], lmax: int) -> np.ndarray:
    """A_l of a BRDF declared known in the plan (reflected parameterisation)."""
    model = brdf["model"]
    if model == "phong":
        return float(brdf.get("ks", 1.0)) * phong_filter(lmax, float(brdf["s"])).values
    if model == "mirror":
        return np.full(lmax + 1, float(brdf.get("reflectance", 1.0)))
    raise ValueError(f"no reflected-parameterisation filter for a {model!r} probe")


def _geometry(capture: SphereCapture, center: tuple[float, float], radius: float,
              max_view_angle_deg: float, use_intrinsics: bool) -> SphereGeometry:
    shape = capture.radiance.shape[-2:]
    intr = None
    if use_intrinsics and capture.camera:
        f_px = 1e3 * capture.camera["focal_length_mm"] / capture.camera["pixel_pitch_um"]
        h, w = shape
        intr = np.array([[f_px, 0.0, (w - 1) / 2.0], [0.0, f_px, (h - 1) / 2.0],
                         [0.0, 0.0, 1.0]])
    return sphere_geometry(shape, center=center, radius=radius, intrinsics=intr,
                           max_view_angle_deg=max_view_angle_deg)


def analyse_capture(
    capture: SphereCapture,
    *,
    lmax: int = 20,
    lmax_check: int = 12,
    max_view_angle_deg: float = 85.0,
    check_view_angle_deg: float = 80.0,
    center: tuple[float, float] | None = None,
    radius: float | None = None,
    use_intrinsics: bool = True,
    n_calibration: int = 200,
    false_alarm: float = 0.01,
    threshold_scale: float = 1.0,
    seed: int = 0,
) -> SphereAnalysis:
    """The spherical-harmonic analysis of a capture (module docstring, steps 3–6).

    Parameters
    ----------
    capture : SphereCapture
        At least 2 lightings × 2 objects.
    lmax : int
        Order of the image fits, the transfer and the relighting.
    lmax_check : int
        Orders 0 … lmax_check of M21 enter the consistency decision (higher orders hold
        mostly noise for glossy-but-not-mirror objects).
    max_view_angle_deg : float
        Pixels viewed more obliquely are left out (grazing, unreliable).
    check_view_angle_deg : float
        The stricter cut-off of the consistency check (≤ ``max_view_angle_deg``): near
        grazing the sphere's horizon clips the lobes, a departure from the ideal
        convolution that consistent images share but the noise model does not hold.
    center, radius : optional
        Sphere image centre (x, y) and radius in pixels; found by :func:`locate_sphere`
        when not given.
    use_intrinsics : bool
        Use the camera's pinhole intrinsics (per-pixel view directions) when known.
    n_calibration : int
        Consistent cases simulated for the checker's calibration.
    false_alarm : float
        The checker's target false-alarm rate α.
    threshold_scale : float
        Multiplies the bootstrap threshold: the bench's factor q from
        :func:`analysis.sh.consistency.threshold_factor` over consistent captures (the
        bootstrap alone misses the departures consistent captures share; see
        :data:`CONSISTENCY_LIMIT`). 1 keeps the noise-only threshold.
    seed : int
        Seeds the bootstrap.
    """
    r, s = capture.radiance.shape[:2]
    if r < 2 or s < 2:
        raise ValueError("the analysis needs at least 2 lightings × 2 objects")
    if not 0 < lmax_check <= lmax:
        raise ValueError("lmax_check must lie in [1, lmax]")
    if not 0 < check_view_angle_deg <= max_view_angle_deg:
        raise ValueError("check_view_angle_deg must lie in (0, max_view_angle_deg]")
    if not threshold_scale > 0:
        raise ValueError("threshold_scale must be > 0")
    if center is None or radius is None:
        c0, r0 = locate_sphere(capture.radiance)
        center = c0 if center is None else center
        radius = r0 if radius is None else radius
    geo = _geometry(capture, center, radius, max_view_angle_deg, use_intrinsics)
    obs = geo.observed & np.all(capture.valid, axis=(0, 1))
    geo = SphereGeometry(geo.on_sphere, obs, geo.normals, geo.view, geo.reflected,
                         geo.cos_view, geo.max_view_angle)
    op = image_fit_operator(geo, lmax=lmax)
    stack = capture.radiance.reshape(r * s, *capture.radiance.shape[2:])
    coeffs = images_to_sh(stack, op, geo).T.reshape(r, s, -1)

    ids: dict[str, IdentityError] = {}
    for k in range(r):
        ids[f"M16 lighting {k}"] = two_objects_one_lighting(coeffs[k, 0], coeffs[k, s - 1])
    b11, b12, b21, b22 = coeffs[0, 0], coeffs[0, s - 1], coeffs[r - 1, 0], coeffs[r - 1, s - 1]
    ids["M21"] = four_images(b11, b12, b21, b22)
    ids["M25"] = rank_one(coeffs)

    lighting, lobj = _estimate_lighting(capture, coeffs, lmax)
    if lighting is not None:
        # The probe object itself satisfies both identities by construction: test the others.
        others = [j for j, name in enumerate(capture.objects) if name != lobj]
        for k in range(r):
            for j in others:
                ids[f"M10 {k},{j}"] = known_lighting(coeffs[k, j], lighting[k])
        for j in others:
            name = capture.objects[j]
            ids[f"M19 {name}"] = one_object_two_lightings(coeffs[0, j], coeffs[r - 1, j],
                                                          lighting[0], lighting[r - 1])

    gamma = brdf_transfer(b11, b12).values
    b22_hat = render_missing_image(b11, b12, b21, route="brdf")
    predicted = sh_to_image(b22_hat, geo)
    measured = capture.radiance[r - 1, s - 1]
    m = geo.observed
    l1 = float(np.sum(np.abs(predicted[m] - measured[m])) / np.sum(np.abs(measured[m])))

    # The check sees only pixels well inside the grazing cut-off: there the sphere's own
    # horizon does not clip the lobes, so consistent images obey M21 to the noise level.
    geo_c = _geometry(capture, center, radius, check_view_angle_deg, use_intrinsics)
    geo_c = SphereGeometry(geo_c.on_sphere, geo_c.observed & obs, geo_c.normals, geo_c.view,
                           geo_c.reflected, geo_c.cos_view, geo_c.max_view_angle)
    op_c = image_fit_operator(geo_c, lmax=lmax)
    coeffs_c = images_to_sh(stack, op_c, geo_c).T.reshape(r, s, -1)
    report = _consistency(capture, coeffs_c, geo_c, op_c, lmax_check=lmax_check,
                          n_cases=n_calibration, false_alarm=false_alarm,
                          threshold_scale=threshold_scale, seed=seed)
    return SphereAnalysis(lmax, (float(center[0]), float(center[1])), float(radius), coeffs,
                          ids, gamma, predicted, measured, l1, m, lighting, lobj, report,
                          float(threshold_scale))


def _estimate_lighting(capture: SphereCapture, coeffs: np.ndarray, lmax: int
                       ) -> tuple[np.ndarray | None, str | None]:
    """Lighting per condition by Wiener deconvolution of the first object of known BRDF."""
    for j, name in enumerate(capture.objects):
        brdf = capture.known_brdf.get(name)
        if brdf is None or brdf["model"] == "lambertian":
            continue  # a Lambertian sphere is a low-pass probe: lighting beyond l = 2 is lost
        a = _known_filter(brdf, lmax)
        est = np.array([wiener_deconvolve(coeffs[k, j], a).coeffs
                        for k in range(coeffs.shape[0])])
        return est, name
    return None, None


def _consistency(capture: SphereCapture, coeffs: np.ndarray, geo: SphereGeometry, op, *,
                 lmax_check: int, n_cases: int, false_alarm: float,
                 threshold_scale: float, seed: int) -> ConsistencyReport:
    """M21 per-order errors of the corner images against a parametric bootstrap.

    Consistent data: the fitted B^{1,1}, B^{1,s}, B^{r,1} and the B^{r,s} they predict,
    rendered back to the observed pixels (these satisfy M21 exactly), plus Gaussian noise
    at the measured level. The level per image is the rms of its fit residual (image minus
    its own SH fit), which holds the sensor noise and whatever the order-``lmax`` model
    cannot represent; the HDR variance alone would test against shot noise only and call
    the finite view and the sphere's horizon "tampering".
    """
    r, s = coeffs.shape[:2]
    n_sub = (lmax_check + 1) ** 2
    m = geo.observed
    corners = [(0, 0), (0, s - 1), (r - 1, 0), (r - 1, s - 1)]
    b = [coeffs[k, j] for k, j in corners]
    b[3] = render_missing_image(b[0], b[1], b[2], route="brdf")
    models = np.stack([sh_to_image(x, geo)[m] for x in b])  # (4, N)
    sigma = np.array([
        float(np.sqrt(np.mean((capture.radiance[k, j][m] - sh_to_image(coeffs[k, j], geo)[m])
                              ** 2)))
        for k, j in corners
    ])
    sig = np.repeat(sigma[:, None], models.shape[1], axis=1)

    def errors_of(flat: np.ndarray) -> np.ndarray:
        c = op.apply(flat.reshape(4, -1).T).T[:, :n_sub]
        return four_images(*c).error

    rng = np.random.default_rng(seed)
    cal_err = bootstrap_consistent_errors(models.ravel(), sig.ravel(), errors_of,
                                          n_cases=n_cases, rng=rng)
    cal = calibrate(cal_err, orders=np.arange(lmax_check + 1), false_alarm=false_alarm)
    if threshold_scale != 1.0:
        cal = scale_threshold(cal, threshold_scale)
    measured = four_images(*(coeffs[k, j][:n_sub] for k, j in corners)).error
    return check(measured, cal)


#: The consistency threshold factor q of the sim-spheres bench at α = 0.01: the conformal
#: (1 − α) quantile of T / threshold over 100 consistent captures (environments 17–116;
#: ``benchmarks/bench_sphere_capture.py --calibrate 17-116``: 8 of the 100 exceed the
#: noise-only threshold, the largest by 2.119), rounded up. Pass it as ``threshold_scale``
#: (``scatterlab spheres --threshold-scale``) for captures of that bench; another
#: instrument needs its own factor.
SIM_SPHERES_THRESHOLD_SCALE = 2.12

#: The noise-only decision's known limit, printed by ``scatterlab spheres`` and stored with
#: the results when no threshold factor is given. Measured by
#: ``benchmarks/bench_sphere_capture.py`` (BENCHMARKS.md ``## sphere_capture``).
CONSISTENCY_LIMIT = (
    "the M21 threshold is calibrated on noise-only bootstrap captures (fit-residual level), "
    "not on model departures consistent captures share (sphere horizon, finite view, "
    "orders > lmax): on the sim-spheres bench 2 of 16 untampered captures are flagged at "
    "alpha = 0.01 (8 of 100 in a second set), not 1 %; with --threshold-scale 2.12, the "
    "factor calibrated for alpha = 0.01 on 100 consistent captures of that bench, 0 of 16 "
    "held-out untampered captures and 10 of 16 top-half splices are flagged; on another "
    "instrument calibrate its own factor (benchmarks/bench_sphere_capture.py --calibrate)"
)


# ------------------------------------------------------------------------------ writing
def _replace(parent: h5py.Group, name: str, nx_class: str) -> h5py.Group:
    if name in parent:
        del parent[name]
    g = parent.create_group(name)
    g.attrs["NX_class"] = nx_class
    return g


def summary(capture: SphereCapture, result: SphereAnalysis) -> dict[str, Any]:
    """Plain-data summary of an analysis (what ``results_json`` and the CLI report)."""
    rep = result.consistency
    return {
        "objects": list(capture.objects),
        "lighting_deg": list(capture.lighting_deg),
        "lighting_role": capture.lighting_role,
        "selector": capture.selector,
        "units": capture.units,
        "lmax": result.lmax,
        "center_px": list(result.center),
        "radius_px": result.radius,
        "relight": {
            "target": {"lighting_deg": capture.lighting_deg[-1], "object": capture.objects[-1]},
            "route": "brdf",
            "l1_error": result.relight_l1,
            "n_pixels": int(result.observed.sum()),
        },
        "gamma": result.gamma.tolist(),
        "identities": {name: {"orders": e.orders.tolist(), "error": e.error.tolist(),
                              "defined": e.defined.tolist()}
                       for name, e in result.identities.items()},
        "lighting_object": result.lighting_object,
        "consistency": {
            "identity": "M21",
            "orders": rep.orders.tolist(),
            "error": rep.error.tolist(),
            "noise_error": rep.noise_error.tolist(),
            "z": rep.z.tolist(),
            "statistic": rep.statistic,
            "threshold": rep.threshold,
            "false_alarm": rep.false_alarm,
            "inconsistent": bool(rep.inconsistent),
            "calibration": "parametric bootstrap at the images' fit-residual level",
            "threshold_scale": result.threshold_scale,
            "limit": CONSISTENCY_LIMIT if result.threshold_scale == 1.0 else None,
        },
    }


def write_sphere_analysis(path: str | Path, capture: SphereCapture,
                          result: SphereAnalysis) -> None:
    """Write ``/entry/analysis`` (NXprocess, replacing an earlier analysis)."""
    with h5py.File(path, "r+") as f:
        g = _replace(f["entry"], "analysis", "NXprocess")
        g.attrs["program"] = "scatterlab spheres"
        g.attrs["references"] = ("Ramamoorthi & Hanrahan 2001; Mahajan, Ramamoorthi & "
                                 "Curless, PAMI 2008 (identities M10-M25); physics.md §5")
        g.create_dataset("results_json", data=json.dumps(summary(capture, result)),
                         dtype=h5py.string_dtype())
        img = _replace(g, "images", "NXdata")
        img.attrs["signal"] = "radiance"
        img.attrs["axes_order"] = "lighting, object, row, column"
        img.create_dataset("radiance", data=capture.radiance, compression="gzip")
        img["radiance"].attrs["units"] = capture.units
        img.create_dataset("variance", data=capture.variance, compression="gzip")
        img.create_dataset("valid", data=capture.valid, compression="gzip")
        img.create_dataset("point_row", data=capture.rows)
        img.create_dataset("lighting_deg", data=np.array(capture.lighting_deg))
        img.create_dataset("objects", data=np.array(capture.objects, dtype=object),
                           dtype=h5py.string_dtype())
        sh = _replace(g, "sh", "NXdata")
        sh.attrs["convention"] = ("real orthonormal, Condon-Shortley phase, theta colatitude "
                                  "from +z (towards the camera); docs/decisions/0040")
        sh.create_dataset("coeffs", data=result.coeffs)
        sh.create_dataset("gamma", data=result.gamma)
        if result.lighting is not None:
            sh.create_dataset("lighting", data=result.lighting)
            sh["lighting"].attrs["from_object"] = str(result.lighting_object)
        rel = _replace(g, "relight", "NXdata")
        rel.attrs["signal"] = "predicted"
        rel.create_dataset("predicted", data=result.predicted)
        rel.create_dataset("measured", data=result.measured)
        rel.create_dataset("observed", data=result.observed)
        rel.attrs["l1_error"] = result.relight_l1


def read_sphere_results(path: str | Path) -> dict[str, Any] | None:
    """The ``results_json`` a sphere analysis stored in a run file, or None."""
    with h5py.File(path, "r") as f:
        g = f.get("entry/analysis")
        if g is None or g.attrs.get("program") != "scatterlab spheres":
            return None
        raw = g["results_json"][()]
        return json.loads(raw.decode() if isinstance(raw, bytes) else raw)


def relighting_figure(capture: SphereCapture, result: SphereAnalysis,
                      path: str | Path) -> Path:
    """The four corner images, the rendered B^{r,s}, its error, and M21 against noise."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, s = capture.radiance.shape[:2]
    fig, axes = plt.subplots(2, 4, figsize=(13, 6.5))
    vmax = float(np.nanpercentile(capture.radiance[..., result.observed], 99.5))
    corners = [(0, 0), (0, s - 1), (r - 1, 0), (r - 1, s - 1)]
    for ax, (k, j) in zip(axes[0], corners, strict=True):
        ax.imshow(capture.radiance[k, j], cmap="magma", vmin=0, vmax=vmax)
        ax.set_title(f"{capture.objects[j]}, {capture.lighting_role} "
                     f"{capture.lighting_deg[k]:g}°", fontsize=9)
    ax = axes[1, 0]
    ax.imshow(np.where(result.observed, result.predicted, np.nan), cmap="magma", vmin=0,
              vmax=vmax)
    ax.set_title(f"rendered from the other three\nL1 error {100 * result.relight_l1:.2f} %",
                 fontsize=9)
    ax = axes[1, 1]
    diff = np.where(result.observed, result.predicted - result.measured, np.nan)
    lim = float(np.nanmax(np.abs(diff))) or 1.0
    im = ax.imshow(diff, cmap="RdBu_r", vmin=-lim, vmax=lim)
    fig.colorbar(im, ax=ax, fraction=0.046)
    ax.set_title("rendered − measured", fontsize=9)
    ax = axes[1, 2]
    l = np.arange(result.gamma.size)
    ax.plot(l, result.gamma, "o-", ms=3)
    ax.set_xlabel("l")
    ax.set_title(f"BRDF transfer γ_l ({capture.objects[0]} → {capture.objects[-1]})",
                 fontsize=9)
    ax = axes[1, 3]
    rep = result.consistency
    ax.semilogy(rep.orders, rep.error, "o-", ms=3, label="M21 error")
    ax.semilogy(rep.orders, rep.noise_error, "k--", label="noise level")
    ax.set_xlabel("l")
    verdict = "inconsistent" if rep.inconsistent else "consistent"
    ax.set_title(f"consistency: T = {rep.statistic:.3g} (threshold {rep.threshold:.3g}),\n"
                 f"{verdict} at α = {rep.false_alarm:g}", fontsize=9)
    ax.legend(fontsize=8)
    for a in axes[0]:
        a.set_xticks([])
        a.set_yticks([])
    for a in axes[1, :2]:
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def analyse_run(path: str | Path, *, write: bool = True, figure: str | Path | None = None,
                **options: Any) -> tuple[SphereCapture, SphereAnalysis]:
    """Read, analyse and (by default) write back a sphere capture; optionally draw the figure.

    ``options`` go to :func:`analyse_capture`.
    """
    capture = read_capture(path)
    result = analyse_capture(capture, **options)
    if write:
        write_sphere_analysis(path, capture, result)
    if figure is not None:
        relighting_figure(capture, result, figure)
    return capture, result
