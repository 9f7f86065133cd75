"""Reduce a BRDF run: the run's points and frames → BRDF values with their uncertainty budget.

The run is read through :mod:`instrument.run.runfile` (each point's light brackets with
their darks); the camera's radiometric calibration (K, η, read noise, saturation, pupil)
comes from :mod:`instrument.bench.camera_calibration`.

What each reading integrated is recorded on the reduced points
(:class:`analysis.brdf.reduction.ReceiverGeometry`: the beam radius from the options, the
run's calibration or geometry, or a simulated bench's source; the receiver distance and
aperture): the receiver factor is divided out and the fit compares the data with the
models as the receiver sees them. The camera's pixel-response error (PRNU from the
calibration without a flat, the flat's own noise with one) is carried as a covariance
between points. All of it is listed in the provenance.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis.brdf.reduction import (
    BRDFPoints,
    ReceiverGeometry,
    ReferenceStandard,
    absolute_brdf,
    camera_power_w,
    camera_signal,
    camera_solid_angle_sr,
    pixel_response_covariance,
    relative_brdf,
    solid_angle_sr,
    speckle_rel,
    spin_patterns,
    subtract_signature,
)
from analysis.radiometry import FlatField, flat_field
from instrument.bench.angles import AngularModel, angular_model
from instrument.bench.camera_calibration import CameraCalibration
from instrument.bench.meter_noise import MeterNoise, meter_noise
from instrument.pipelines.brdf.attenuation import (
    apply_nd,
    calibration_run_path,
    nd_slots,
    nd_transmissions,
)
from instrument.pipelines.brdf.dark import PointDark, power_meter_dark
from instrument.run.runfile import RunData, read_run

__all__ = ["Reduced", "ReductionOptions", "first_pass_path", "flat_from_run",
           "instrument_function", "load_reference_table", "reduce_run"]


@dataclass(frozen=True)
class ReductionOptions:
    """How to reduce a run (the ``scatterlab fit`` options).

    Attributes
    ----------
    method : {"absolute", "relative"}
    detector : {"camera", "power_meter"}
        (``"lockin"`` only for :func:`instrument_function`, which the per-wavelength
        lock-in reduction shares with the camera's and the power meter's.)
    cosine_corrected : bool
    incident_power_w, u_incident_power_rel : float or None
        P_i and its relative uncertainty; default from the run's calibration attribute
        ``incident_power_w`` or, on a simulated bench, the source power of the profile.
    receiver_distance_mm : float or None
        Sample-to-receiver distance; default the profile's detector distance plus the
        run's ``camera_z`` read-back when the run moved it (the camera rides on it); the
        lock-in's photodiode: the profile's ``[photodiode] distance_mm`` when given.
    aperture_diameter_mm : float or None
        A meter's or photodiode's aperture; default the profile's ``[photodiode]
        aperture_diameter_mm`` (lock-in) or the bench geometry's ``detector_aperture_mm``.
    u_distance_mm, u_aperture_mm : float or None
        Standard uncertainties of the receiver distance and aperture (mm); ``None``: not
        known (taken as 0 and reported as an unknown part of the common scale).
    sigma_theta_deg : float or None
        Angular standard uncertainty of θi and θr; default from the stages' read-back
        resolution and repeatability (:mod:`instrument.bench.angles`).
    u_power_meter_rel : float or None
        Relative noise of one power-meter reading (power-meter detector); default from
        the profile's ``relative_noise`` or the meter's kind
        (:func:`instrument.bench.meter_noise.meter_noise`).
    camera_calibration : path or None
    flat_run : path or None
        A ``flat_field`` run (uniform radiance); default the run's ``calibration.flat``.
    reference_run, signature_run : path or None
    reference_table : path or None
        CSV of the standard's BRDF (theta_i_deg, theta_r_deg, brdf, u_rel).
    beam_radius_mm : float or None
        1/e² radius of the incident beam; default the run's calibration attribute
        ``beam_radius_mm``, the stored geometry's, or on a simulated bench the profile's
        source. With it the reduction divides out the receiver factor and records the
        receiver geometry for instrument-aware fitting
        (:class:`analysis.brdf.reduction.ReceiverGeometry`); without it (unknown beam)
        the points are treated as point samples and the provenance says so.
    receiver_geometry : bool
        Use the receiver geometry when the beam radius is known (default True).
    beam_divergence_mrad, sample_radius_mm : float or None
        The beam's 1/e² divergence half-angle and the sample's radius; default the run's
        calibration or stored bench geometry, or on a simulated bench its source
        (collimated) and scene.
    nd_calibration : path or None
        An ND calibration run (``examples/calibration_nd.toml``) for the transmissions of
        the neutral-density filters points were read through; default the run's
        ``calibration.nd``, else the profile's values (:mod:`.attenuation`).
    """

    method: str = "absolute"
    detector: str = "camera"
    cosine_corrected: bool = False
    incident_power_w: float | None = None
    u_incident_power_rel: float | None = None
    receiver_distance_mm: float | None = None
    aperture_diameter_mm: float | None = None
    u_distance_mm: float | None = None
    u_aperture_mm: float | None = None
    sigma_theta_deg: float | None = None
    u_power_meter_rel: float | None = None
    camera_calibration: str | None = None
    flat_run: str | None = None
    reference_run: str | None = None
    signature_run: str | None = None
    reference_table: str | None = None
    beam_radius_mm: float | None = None
    receiver_geometry: bool = True
    beam_divergence_mrad: float | None = None
    sample_radius_mm: float | None = None
    nd_calibration: str | None = None


@dataclass(frozen=True)
class Reduced:
    """A reduced run: BRDF points and where every number came from.

    A two-pass lobe run is reduced together with its first pass: ``sources`` lists the
    run ids (this run first) and ``source`` says which one each point came from.

    ``warnings`` are the assumptions that change the result (an assumed receiver distance,
    an unknown beam radius, a common scale whose uncertainty nobody gave): each says what
    was assumed and which option sets it. ``scale_unknown`` names the contributions to
    the common scale uncertainty that are unknown, so that ``points.u_scale_rel`` is a
    lower bound rather than a value when it is not empty.
    """

    points: BRDFPoints
    rows: np.ndarray            # row of each BRDF point in its run's tables
    detector_theta: np.ndarray  # read-back arm position per point (deg; NaN if unknown)
    provenance: dict[str, Any]
    point_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    source: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    sources: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    scale_unknown: tuple[str, ...] = ()

    def point_label(self, k: int | np.integer[Any]) -> str:
        """How a reduced point is named to the user: its run's point index (and the run,
        for a point of a first pass)."""
        idx = int(self.point_index[k]) if self.point_index.size else int(self.rows[k])
        src = int(self.source[k]) if self.source.size else 0
        return f"point {idx}" + (f" of {self.sources[src]}" if src else "")


def flat_from_run(path: str | Path) -> FlatField:
    """Normalised flat field (:func:`analysis.radiometry.flat_field`) from a ``flat_field``
    run: the light frames of its "flat" points at the exposure with the most frames, less
    the mean of their dark frames (EMVA 1288 R3.1 §4, PRNU)."""
    return _flat_and_frames(path)[0]


def _flat_residual_rel(flat: FlatField, n_frames: int, cal: CameraCalibration) -> float:
    """Relative σ of one pixel of a flat averaged from ``n_frames`` frames: its shot noise
    K·S and the dark noise of the light and the (averaged) dark frame, EMVA 1288 §2.3."""
    k = cal.noise.system_gain_dn_per_e
    s = max(flat.mean_signal_dn, 1e-12)
    read_dn2 = (k * cal.noise.read_noise_e) ** 2 + 1.0 / 12.0
    return float(math.sqrt((k * s + 2.0 * read_dn2) / n_frames) / s)


def _flat_and_frames(path: str | Path) -> tuple[FlatField, int]:
    run = read_run(path)
    groups: dict[float, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for r in np.flatnonzero(run.label == "flat"):
        light, exp, dark = run.frames_of(int(r))
        if dark is None:
            raise ValueError(f"flat run {run.run_id}: point {run.index[r]} has no dark frame")
        for lf, e, df in zip(light, exp, dark, strict=True):
            g = groups.setdefault(round(float(e), 6), ([], []))
            g[0].append(lf)
            g[1].append(df)
    if not groups:
        raise ValueError(f"run {run.run_id} holds no flat-field frames")
    lights, darks = max(groups.values(), key=lambda g: len(g[0]))
    return flat_field(np.array(lights), np.mean(np.array(darks), axis=0)), len(lights)


def _flat_for(run: RunData, opts: ReductionOptions
              ) -> tuple[FlatField | None, str, int]:
    src = opts.flat_run or run.calibration.get("flat")
    if src is None:
        return None, "none", 0
    path = calibration_run_path(run, src)
    flat, n = _flat_and_frames(path)
    return flat, str(path), n


#: Signal images for the pixel-response covariance are kept summed over blocks so that they
#: are at most this many blocks wide (a 1024-px frame: 8 × 8 blocks; the footprint's image
#: is tens of pixels wide there, smooth on that scale; small frames are kept per pixel).
_PROFILE_SIDE = 128


@dataclass(frozen=True)
class _Signals:
    """Collected power (W) and its σ per row, the pixels clipped in each row's shortest
    exposure, and the signal images for the pixel-response covariance (camera, when a
    response error is carried; ``block`` 0 otherwise)."""

    power_w: np.ndarray
    u_power_w: np.ndarray
    clipped: np.ndarray
    profiles: list[np.ndarray]
    sq_sums: list[float]
    block: int
    #: Covariance (W²) of errors shared between rows (a power-meter dark read once for
    #: several points), or None.
    cov_shared_w2: np.ndarray | None = None
    #: What was subtracted as the detector's dark (power meter), for the provenance.
    dark: PointDark | None = None

    @staticmethod
    def join(parts: list[_Signals]) -> _Signals:
        cov = None
        if any(p.cov_shared_w2 is not None for p in parts):
            blocks = [p.cov_shared_w2 if p.cov_shared_w2 is not None
                      else np.zeros((p.power_w.size, p.power_w.size)) for p in parts]
            n = sum(b.shape[0] for b in blocks)
            cov = np.zeros((n, n))
            k = 0
            for b in blocks:  # two runs never share a dark reading
                cov[k:k + b.shape[0], k:k + b.shape[0]] = b
                k += b.shape[0]
        return _Signals(np.concatenate([p.power_w for p in parts]),
                        np.concatenate([p.u_power_w for p in parts]),
                        np.concatenate([p.clipped for p in parts]),
                        [x for p in parts for x in p.profiles],
                        [x for p in parts for x in p.sq_sums],
                        max(p.block for p in parts), cov, parts[0].dark)

    def covariance(self, u_response_rel: float) -> np.ndarray | None:
        """Relative covariance of the errors shared between rows (None without any): the
        pixel-response error (:func:`analysis.brdf.reduction.pixel_response_covariance`)
        and a shared dark reading."""
        cov = None
        if self.block and self.profiles:
            cov = pixel_response_covariance(np.array(self.profiles),
                                            u_response_rel=u_response_rel,
                                            block=self.block, sq_sums=self.sq_sums)
        if self.cov_shared_w2 is not None and np.any(self.cov_shared_w2):
            p = np.where(self.power_w != 0, self.power_w, np.inf)
            shared = self.cov_shared_w2 / np.outer(p, p)
            cov = shared if cov is None else cov + shared
        return cov


def _signals(run: RunData, rows: np.ndarray, opts: ReductionOptions,
             cal: CameraCalibration | None, flat: FlatField | None = None,
             *, u_response_rel: float = 0.0) -> _Signals:
    """The camera's or the power meter's signals of ``rows`` (:class:`_Signals`)."""
    if opts.detector == "power_meter":
        return _power_meter_signals(run, rows, opts)
    assert cal is not None
    n_avg = int(run.acquisition.get("frames", 1))
    rate = np.empty(rows.size)
    sd = np.empty(rows.size)
    clipped = np.zeros(rows.size, dtype=int)
    block = 0
    profiles, sq_sums = [], []
    for k, r in enumerate(rows):
        light, exp, dark = run.frames_of(int(r))
        if dark is None:
            raise ValueError(f"point {run.index[r]} has no dark frames at its exposure(s)")
        if u_response_rel > 0 and block == 0:
            block = max(1, max(light.shape[1:]) // _PROFILE_SIDE)
        s = camera_signal(light, exp, dark, noise=cal.noise, n_averaged=n_avg, flat=flat,
                          profile_block=block)
        rate[k], sd[k], clipped[k] = s.rate_dn_per_us, s.sigma, s.clipped_pixels
        if s.profile is not None:
            profiles.append(s.profile)
            sq_sums.append(s.profile_sq_sum)
    conv = {"system_gain_dn_per_e": cal.noise.system_gain_dn_per_e,
            "quantum_efficiency": cal.quantum_efficiency, "wavelength_nm": cal.wavelength_nm}
    return _Signals(camera_power_w(rate, **conv), camera_power_w(sd, **conv), clipped,
                    profiles, sq_sums, block)


def _power_meter_signals(run: RunData, rows: np.ndarray, opts: ReductionOptions
                         ) -> _Signals:
    """The power meter's readings less its dark (:mod:`instrument.pipelines.brdf.dark`).

    σ of a reading: the noise floor measured from the dark readings' spread combined with
    the meter's relative noise of the signal (:func:`_meter_relative_noise`); the
    subtracted dark adds its own σ (independent for a dark of its own, a covariance for a
    dark shared between points).
    """
    p = run.power_w[rows].astype(float)
    if not np.all(np.isfinite(p)):
        raise ValueError("the run has no power-meter readings at every point")
    dark = power_meter_dark(run, rows)
    meter = _meter_relative_noise(run, opts)
    rel = meter.relative
    # the floor from the darks' spread; too few darks: the profile's declared floor
    floor = dark.noise_floor if dark.noise_floor is not None else (meter.floor_w or 0.0)
    net = p - dark.level
    u = np.hypot(floor, np.abs(p) * rel)
    # a dark whose noise was not measured: the declared floor, else the relative noise of
    # a reading (and a warning)
    u_dark = (dark.u_level if dark.noise_floor is not None
              else np.full(p.size, meter.floor_w) if meter.floor_w is not None
              else np.abs(dark.level) * rel)
    shared = dark.group >= 0
    u = np.where(shared, u, np.hypot(u, u_dark))
    cov = dark.shared_covariance(u_dark) if shared.any() else None
    return _Signals(net, u, np.zeros(rows.size, dtype=int), [], [], 0, cov, dark)


def _meter_relative_noise(run: RunData, opts: ReductionOptions) -> MeterNoise:
    """The power meter's relative noise per reading: the option, else what the run's
    profile or the meter's kind says (:mod:`instrument.bench.meter_noise`)."""
    if opts.u_power_meter_rel is not None:
        return MeterNoise(float(opts.u_power_meter_rel),
                          f"{opts.u_power_meter_rel:.2g} of the reading (option)",
                          floor_w=meter_noise(run.profile()).floor_w)
    return meter_noise(run.profile())


def first_pass_path(run: RunData) -> Path | None:
    """The first-pass run a two-pass lobe plan names (``[scan] first_pass``,
    :mod:`instrument.plans.lobe`), resolved next to the run file."""
    if not run.plan_text:
        return None
    ref = tomllib.loads(run.plan_text).get("scan", {}).get("first_pass")
    if ref is None:
        return None
    path = Path(ref)
    if not path.is_absolute() and not path.exists():
        path = run.path.parent / ref
        if not path.suffix:
            path = path.with_suffix(".h5")
    if not path.is_file():
        raise ValueError(f"run {run.run_id} is the second pass of {ref!r}, which is not at "
                         f"{path}: keep the two runs side by side")
    return path


def _incident_power(run: RunData, opts: ReductionOptions
                    ) -> tuple[float, float | None, str]:
    """(P_i in W, its relative standard uncertainty or None when nobody gave it, source)."""
    u_opt = opts.u_incident_power_rel
    if opts.incident_power_w is not None:
        return float(opts.incident_power_w), u_opt, "option"
    if "incident_power_w" in run.calibration:
        u_cal = run.calibration.get("u_incident_power_rel", u_opt)
        return (float(run.calibration["incident_power_w"]),
                None if u_cal is None else float(u_cal), "run calibration")
    sim = run.profile().get("simulation", {})
    if "power_w" in sim.get("source", {}):
        return (float(sim["source"]["power_w"]), u_opt,
                "simulated source power (bench profile)")
    raise ValueError("the absolute method needs the incident power (--incident-power-w)")


def _receiver_distance(run: RunData, rows: np.ndarray, opts: ReductionOptions
                       ) -> tuple[float, str]:
    if opts.receiver_distance_mm is not None:
        return float(opts.receiver_distance_mm), "option"
    if "receiver_distance_mm" in run.calibration:
        return float(run.calibration["receiver_distance_mm"]), "run calibration"
    base = float(run.geometry.get("detector_distance_mm", 300.0))
    photodiode = run.profile().get("photodiode", {})
    if opts.detector == "lockin" and "distance_mm" in photodiode:
        return float(photodiode["distance_mm"]), "bench profile [photodiode]"
    if opts.detector == "camera":
        z = run.position("camera_z")[rows]
        if np.all(np.isfinite(z)):
            # one distance per run: the plan does not move camera_z during a BRDF scan
            return base + float(np.mean(z)), "profile distance + camera_z read-back"
        if run.geometry.get("axis_homed.camera_z") == 1:
            z0 = float(run.geometry["axis_position.camera_z"])
            return base + z0, "profile distance + camera_z at run start (homed)"
        if "axis_position.camera_z" in run.geometry:
            return base, ("profile detector distance; camera_z was not homed, so its position "
                          "is unknown (assumed 0: give --distance-mm if it is elsewhere)")
        return base, ("profile detector distance; camera_z was not recorded by this run "
                      "(assumed 0: give --distance-mm if the camera stage is elsewhere)")
    return base, "profile detector distance"


def _beam_radius(run: RunData, opts: ReductionOptions) -> tuple[float | None, str]:
    if opts.beam_radius_mm is not None:
        return float(opts.beam_radius_mm), "option"
    if "beam_radius_mm" in run.calibration:
        return float(run.calibration["beam_radius_mm"]), "run calibration"
    if "beam_radius_mm" in run.geometry:
        return float(run.geometry["beam_radius_mm"]), "bench geometry"
    src = run.profile().get("simulation", {}).get("source", {})
    if "beam_radius_mm" in src:
        return float(src["beam_radius_mm"]), "simulated source (bench profile)"
    return None, "unknown (points treated as point samples: give --beam-radius-mm)"


def _light_seconds(run: RunData, rows: np.ndarray) -> np.ndarray:
    """Seconds of light each point's stored frames collected, brackets and repeats alike.

    A spinning sample shows each frame other patterns (it turns on between frames), and
    a merge that weighs the frames by their exposure (shot-noise-limited HDR) averages
    as many independent patterns as all its frames swept together: N = ω Σt / Δφ_c.
    A point without frames (a meter's reading) counts 0 s: N = 1, a static sample's
    error (the larger, so an upper bound)."""
    out = np.zeros(rows.size)
    for k, r in enumerate(rows):
        n0, n = int(run.frame_start[r]), int(run.n_frames[r])
        light = run.frame_light[n0:n0 + n].astype(bool)
        exposures = run.frame_exposure_us[n0:n0 + n][light]
        out[k] = float(np.sum(exposures[np.isfinite(exposures)])) * 1e-6
    return out


def _speckle_rel(run: RunData, opts: ReductionOptions,
                 angles: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                 exposure_s: np.ndarray, solid_angle_sr: float, spin_deg_s: float
                 ) -> np.ndarray | None:
    """The relative error laser speckle leaves in each reading
    (:mod:`analysis.brdf.reduction.speckle`): a static sample's frozen pattern, or the
    average of the patterns a spinning sample sweeps in the point's exposure; None under
    an incoherent source (the stored profile's ``[source] coherence``)."""
    profile = run.profile()
    light = profile.get("source", {})
    if light.get("coherence", "incoherent") != "laser":
        return None
    wavelength = light.get("wavelength_nm",
                           profile.get("simulation", {}).get("source", {}).get("wavelength_nm"))
    if wavelength is None:
        raise ValueError("the bench's source is a laser, whose speckle grain depends on its "
                         "wavelength: set [source] wavelength_nm in the bench profile")
    beam, _ = _beam_radius(run, opts)
    if beam is None:
        raise ValueError("the bench's source is a laser, whose speckle depends on the beam's "
                         "size on the sample: give --beam-radius-mm")
    ti, pi_, tr, pr = angles
    patterns = (spin_patterns(ti, pi_, tr, pr, spin_deg_s=spin_deg_s, exposure_s=exposure_s,
                              wavelength_nm=float(wavelength), beam_radius_mm=beam,
                              solid_angle_sr=solid_angle_sr)
                if spin_deg_s > 0 else 1.0)
    return speckle_rel(ti, tr, wavelength_nm=float(wavelength), beam_radius_mm=beam,
                       solid_angle_sr=solid_angle_sr, patterns=patterns)


def _beam_divergence_rad(run: RunData, opts: ReductionOptions) -> tuple[float, str]:
    if opts.beam_divergence_mrad is not None:
        return 1e-3 * float(opts.beam_divergence_mrad), "option"
    for table, where in ((run.calibration, "run calibration"), (run.geometry, "bench geometry")):
        if "beam_divergence_mrad" in table:
            return 1e-3 * float(table["beam_divergence_mrad"]), where
    if "source" in run.profile().get("simulation", {}):
        return 0.0, "simulated source (collimated)"
    return 0.0, "not declared (taken as collimated: set geometry.beam_divergence_mrad)"


def _sample_radius(run: RunData, opts: ReductionOptions) -> tuple[float | None, str]:
    if opts.sample_radius_mm is not None:
        return float(opts.sample_radius_mm), "option"
    if "sample_radius_mm" in run.geometry:
        return float(run.geometry["sample_radius_mm"]), "bench geometry"
    scene = run.profile().get("simulation", {}).get("scene")
    if isinstance(scene, dict) and scene.get("kind", "goniometer") == "goniometer":
        # the simulated goniometer scene's sample disk (hw_mocks GoniometerScene default)
        return float(scene.get("sample_radius_mm", 12.5)), "simulated scene (bench profile)"
    return None, ("not declared (the sample is taken as larger than the footprint: set "
                  "geometry.sample_radius_mm)")


def instrument_function(run: RunData, rows: np.ndarray, opts: ReductionOptions,
                        cal: CameraCalibration | None = None
                        ) -> tuple[ReceiverGeometry | None, dict[str, Any]]:
    """What each reading integrated: the camera pupil, the meter aperture or the lock-in's
    photodiode aperture (module docstring of :mod:`analysis.brdf.reduction`), with the
    solid angle the reduction uses, and the rest of the instrument function from the run's
    stored profile: the beam's radius and divergence, the sample's radius and the axes'
    set-point uncertainty. One forward model for every detector.

    Camera: Ω = A_pupil/R², the étendue of its calibration (camera equation); power meter
    and photodiode: the aperture's cone solid angle. The receiver factor corrects either to
    what the receiver integrates.
    """
    distance, dist_src = _receiver_distance(run, rows, opts)
    if opts.detector == "camera":
        assert cal is not None
        aperture = cal.pupil_diameter_mm
        omega, u_omega = camera_solid_angle_sr(aperture, distance,
                                               u_diameter_mm=opts.u_aperture_mm or 0.0,
                                               u_distance_mm=opts.u_distance_mm or 0.0)
        sampled = not cal.chief_ray_only
    else:
        aperture = opts.aperture_diameter_mm
        if aperture is None and opts.detector == "lockin":
            aperture = run.profile().get("photodiode", {}).get("aperture_diameter_mm")
        if aperture is None:
            aperture = run.geometry.get("detector_aperture_mm", 5.0)
        aperture = float(aperture)
        omega, u_omega = solid_angle_sr(aperture, distance,
                                        u_diameter_mm=opts.u_aperture_mm or 0.0,
                                        u_distance_mm=opts.u_distance_mm or 0.0)
        sampled = True
    w, w_src = _beam_radius(run, opts)
    div, div_src = _beam_divergence_rad(run, opts)
    radius, radius_src = _sample_radius(run, opts)
    ang = _angular(run, opts)
    info: dict[str, Any] = {"solid_angle_sr": omega, "u_solid_angle_sr": u_omega,
                            "receiver_aperture_mm": aperture, "receiver_distance_mm": distance,
                            "receiver_distance_source": dist_src, "beam_radius_mm": w,
                            "beam_radius_source": w_src, "beam_divergence_mrad": 1e3 * div,
                            "beam_divergence_source": div_src, "sample_radius_mm": radius,
                            "sample_radius_source": radius_src}
    if w is None or not opts.receiver_geometry:
        info["receiver_model"] = "none (point spot, point receiver)"
        return None, info
    rg = ReceiverGeometry(w, distance, aperture, omega, sample_aperture=sampled,
                          beam_divergence_rad=div, sample_radius_mm=radius,
                          sigma_theta_i_rad=ang.sigma_theta_i_rad,
                          sigma_theta_r_rad=ang.sigma_theta_r_rad)
    info["receiver_model"] = (
        "instrument function: Gaussian footprint"
        + (" clipped by the sample's edge" if radius is not None else "")
        + (" × aperture integrated" if sampled else " × chief ray through the pupil centre")
        + (f" × beam divergence {1e3 * div:g} mrad" if div > 0 else "")
        + f" × read-back spread σθi = {math.degrees(ang.sigma_theta_i_rad):.2g}°, "
        f"σθr = {math.degrees(ang.sigma_theta_r_rad):.2g}°"
        + "; quadrature refined per point until below 0.1σ")
    return rg, info


def _angular(run: RunData, opts: ReductionOptions) -> AngularModel:
    """σθi, σθr of the recorded (read-back) angles: the option, or the stages' read-back
    resolution and repeatability (:mod:`instrument.bench.angles`)."""
    if opts.sigma_theta_deg is not None:
        s = math.radians(opts.sigma_theta_deg)
        return AngularModel(s, s, (), ())
    return angular_model(run.profile())


def reduce_run(path: str | Path, options: ReductionOptions | None = None) -> Reduced:
    """Reduce the scattering points of a run to BRDF values (module docstring).

    Raises
    ------
    ValueError
        Missing calibration, reference or dark data (the message says what to give).
    """
    opts = options or ReductionOptions()
    if opts.method not in ("absolute", "relative"):
        raise ValueError("method must be 'absolute' or 'relative'")
    if opts.detector not in ("camera", "power_meter"):
        raise ValueError("detector must be 'camera' or 'power_meter'")
    run = read_run(path)
    rows = run.brdf_rows()
    if rows.size == 0:
        raise ValueError(f"{path}: no measured scattering points")
    # a second pass of a two-pass lobe plan is reduced with its first pass
    parts: list[tuple[RunData, np.ndarray]] = [(run, rows)]
    first = first_pass_path(run)
    if first is not None:
        r1 = read_run(first)
        parts.append((r1, r1.brdf_rows()))
    cal = (run.camera_calibration(opts.camera_calibration)
           if opts.detector == "camera" else None)
    rad = np.radians

    def joined(attr: str) -> np.ndarray:
        return np.concatenate([getattr(r, attr)[rw] for r, rw in parts])

    ti, pi_ = rad(joined("theta_i")), rad(joined("phi_i"))
    tr, pr = rad(joined("theta_r")), rad(joined("phi_r"))
    ang = _angular(run, opts)
    sig_i, sig_r = ang.sigma_theta_i_rad, ang.sigma_theta_r_rad
    flat, flat_src, n_flat = _flat_for(run, opts) if cal is not None else (None, "none", 0)
    # the pixel-response error left in the summed signal: PRNU without a flat, the flat's
    # own noise with one (shared between points that image the spot onto the same pixels,
    # in either pass)
    u_resp = 0.0
    if cal is not None:
        u_resp = (_flat_residual_rel(flat, n_flat, cal) if flat is not None
                  else cal.prnu_rel)
    sig = _Signals.join([_signals(r, rw, opts, cal, flat, u_response_rel=u_resp)
                         for r, rw in parts])
    p_s, u_s, cov_rel, n_clipped = (sig.power_w, sig.u_power_w, sig.covariance(u_resp),
                                    sig.clipped)
    # readings through a neutral-density filter: divided by its transmission, whose error
    # is shared by every point read through the same filter (in either pass)
    nd_table, nd_warnings = nd_transmissions(run, opts.nd_calibration,
                                             opts.camera_calibration)
    slots = np.concatenate([nd_slots(r, rw) for r, rw in parts])
    p_s, u_s, cov_nd = apply_nd(p_s, u_s, slots, nd_table)
    if cov_nd is not None:
        cov_rel = cov_nd if cov_rel is None else cov_rel + cov_nd
    prov: dict[str, Any] = {"run_id": run.run_id, "method": opts.method,
                            "detector": opts.detector,
                            "sigma_theta_i_deg": math.degrees(sig_i),
                            "sigma_theta_r_deg": math.degrees(sig_r),
                            "angular_model": (ang.describe() if ang.stages else
                                              "option --sigma-theta-deg"),
                            "options": asdict(opts)}
    if first is not None:
        prov["first_pass"] = f"{parts[1][0].run_id} ({parts[1][1].size} points, {first})"
    if cal is not None:
        prov["camera_calibration"] = cal.source
        prov["flat_field"] = flat_src
        prov["pixel_response_u_rel"] = u_resp
    receiver, rinfo = instrument_function(run, rows, opts, cal)
    prov.update(rinfo)
    warnings = _receiver_warnings(rinfo) + list(ang.warnings) + nd_warnings
    if (slots >= 0).any():
        prov["nd_filters"] = [
            f"{nd_table[int(k)].describe()}: {int(np.sum(slots == k))} point(s)"
            for k in np.unique(slots[slots >= 0])]
    if sig.dark is not None:
        prov["detector_dark"] = sig.dark.describe("nW", 1e9)
        noise = _meter_relative_noise(run, opts)
        prov["power_meter_relative_noise"] = noise.source
        warnings.extend(_dark_warnings(sig.dark, noise))
        if noise.warning:
            warnings.append(noise.warning)
    spin = float(run.acquisition.get("spin_deg_s", 0.0))
    exposure_s = np.concatenate([_light_seconds(r, rw) for r, rw in parts])
    speckle = _speckle_rel(run, opts, (ti, pi_, tr, pr), exposure_s,
                           float(rinfo["solid_angle_sr"]), spin)
    if speckle is not None:
        # a frozen pattern per geometry: an error of each value, independent between points
        u_s = np.hypot(u_s, p_s * speckle)
        sample = (f"sample spun at {spin:g} °/s" if spin > 0 else "static sample")
        prov["speckle"] = (f"laser source, {sample}: {speckle.min():.2%} to "
                           f"{speckle.max():.2%} of each value")
    scale_unknown: list[str] = []
    if opts.method == "absolute":
        p_i, u_pi_rel, src = _incident_power(run, opts)
        if u_pi_rel is None:
            scale_unknown.append(f"the incident power ({p_i:.4g} W, {src}; set it with "
                                 "--incident-power-u)")
        if opts.u_distance_mm is None and opts.u_aperture_mm is None:
            scale_unknown.append("the receiver distance (set it with --distance-u-mm)")
        pts = absolute_brdf(
            p_s, u_s, ti, pi_, tr, pr, incident_power_w=p_i,
            u_incident_power_w=p_i * (u_pi_rel or 0.0),
            solid_angle=rinfo["solid_angle_sr"],
            u_solid_angle=rinfo["u_solid_angle_sr"],
            u_responsivity_rel=cal.u_responsivity_rel if cal is not None else 0.0,
            sigma_theta_i=sig_i, sigma_theta_r=sig_r, cosine_corrected=opts.cosine_corrected,
            receiver=receiver, cov_power_rel=cov_rel)
        prov.update(incident_power_w=p_i, incident_power_source=src)
    else:
        if opts.reference_run is None:
            raise ValueError("the relative method needs --reference RUN (a reference-standard "
                             "run at the same geometry)")
        ref_run = read_run(opts.reference_run)
        ref_cal = (ref_run.camera_calibration(opts.camera_calibration)
                   if opts.detector == "camera" else None)
        # same geometry, same pixels: the pixel response cancels in the ratio
        ref_rows = [_match_rows(r, rw, ref_run) for r, rw in parts]
        ref = _Signals.join([_signals(ref_run, rr, opts, ref_cal) for rr in ref_rows])
        ref_table, _ = nd_transmissions(ref_run, None, opts.camera_calibration)
        ref_p, ref_u, ref_nd = apply_nd(
            ref.power_w, ref.u_power_w,
            np.concatenate([nd_slots(ref_run, rr) for rr in ref_rows]), ref_table)
        if ref_nd is not None:  # the standard's readings: the filter's error on each
            ref_u = np.hypot(ref_u, ref_p * np.sqrt(np.diag(ref_nd)))
        if speckle is not None:  # the standard speckles under the same laser
            ref_u = np.hypot(ref_u, ref_p * speckle)
        ref = replace(ref, power_w=ref_p, u_power_w=ref_u)
        std = _reference_standard(ref_run, opts)
        pts = relative_brdf(p_s, u_s, ref.power_w, ref.u_power_w, ti, pi_, tr, pr,
                            reference=std, sigma_theta_i=sig_i, sigma_theta_r=sig_r,
                            cosine_corrected=opts.cosine_corrected)
        # the ratio to a diffuse standard read through the same receiver is already the
        # normalised average of f over it: keep the geometry for the fit
        pts = replace(pts, receiver=receiver)
        prov.update(reference_run=ref_run.run_id, reference_standard=std.name)
        n_clipped = n_clipped + ref.clipped
        if opts.reference_table is None:
            scale_unknown.append("the reference standard's reflectance (set it with "
                                 "--reference-table, a CSV with a u_rel column)")
    arm = np.concatenate([r.position("detector_theta")[rw] for r, rw in parts])
    if opts.signature_run is not None:
        pts = _subtract_signature(arm, pts, opts)
        prov["signature_run"] = str(opts.signature_run)
    if scale_unknown:
        prov["common_scale_unknown"] = "; ".join(scale_unknown)
        known = (f"the ± values include only its known part, {pts.u_scale_rel:.2%}"
                 if pts.u_scale_rel > 0 else "the ± values leave it out")
        warnings.append(f"common scale uncertainty unknown ({known}): no uncertainty was "
                        "given for " + " or for ".join(scale_unknown))
    clipped = n_clipped > 0
    pts = replace(pts, clipped=clipped)
    all_rows = np.concatenate([rw for _, rw in parts])
    index = np.concatenate([r.index[rw] for r, rw in parts])
    source = np.concatenate([np.full(rw.size, k) for k, (_, rw) in enumerate(parts)])
    red = Reduced(pts, all_rows, arm, prov, point_index=index, source=source,
                  sources=tuple(r.run_id for r, _ in parts), warnings=tuple(warnings),
                  scale_unknown=tuple(scale_unknown))
    if clipped.any():
        prov["clipped_points"] = [
            f"{red.point_label(k)} (θi={math.degrees(ti[k]):.1f}°, "
            f"θr={math.degrees(tr[k]):.1f}°): {int(n_clipped[k])} pixels saturated even in "
            "its shortest exposure" for k in np.flatnonzero(clipped)]
    return red


def _receiver_warnings(rinfo: dict[str, Any]) -> list[str]:
    """The receiver assumptions that change the BRDF's scale or shape, in words."""
    out = []
    src = str(rinfo["receiver_distance_source"])
    if "assumed" in src:
        out.append(f"receiver distance {rinfo['receiver_distance_mm']:g} mm: {src}")
    if rinfo["beam_radius_mm"] is None:
        out.append(f"beam radius {rinfo['beam_radius_source']}")
    return out


def _dark_warnings(dark: PointDark, noise: MeterNoise) -> list[str]:
    """The power meter's dark in words when it was not measured, or its noise not."""
    if not dark.measured:
        return ["power-meter dark not measured: every reading still holds the photodiode's "
                "dark current and any ambient light; set [acquisition] dark = \"per_point\" "
                "(or \"start\") in the plan so that it is read with the light off and "
                "subtracted"]
    if dark.noise_floor is None:
        held = (f"the profile's noise_floor_w ({noise.floor_w:.3g} W) is taken"
                if noise.floor_w is not None else
                f"each reading's σ is its relative noise alone ({noise.relative:.2%})")
        return [f"power-meter noise floor not measured ({dark.n_readings} dark reading(s), "
                f"fewer than 3): {held}; dark = \"per_point\" measures it"]
    return []


def _match_rows(run: RunData, rows: np.ndarray, other: RunData, *, tol_deg: float = 0.05
                ) -> np.ndarray:
    """Rows of ``other`` at the same (θi, φi, θr, φr) as ``rows`` of ``run``."""
    cand = other.brdf_rows()
    a = np.stack([other.theta_i, other.phi_i, other.theta_r, other.phi_r], -1)[cand]
    out = np.empty(rows.size, dtype=int)
    for k, r in enumerate(rows):
        want = np.array([run.theta_i[r], run.phi_i[r], run.theta_r[r], run.phi_r[r]])
        d = np.abs(np.angle(np.exp(1j * np.radians(a - want))))
        hit = np.flatnonzero(np.all(np.degrees(d) <= tol_deg, axis=1))
        if hit.size == 0:
            raise ValueError(f"run {other.run_id} has no point at θi={want[0]:g}°, "
                             f"θr={want[2]:g}° (φr={want[3]:g}°)")
        out[k] = cand[hit[0]]
    return out


def _reference_standard(ref_run: RunData, opts: ReductionOptions) -> ReferenceStandard:
    if opts.reference_table is not None:
        return load_reference_table(opts.reference_table)
    scan = tomllib.loads(ref_run.plan_text).get("scan", {}) if ref_run.plan_text else {}
    if "reflectance" not in scan:
        raise ValueError("give the standard's BRDF table (--reference-table CSV); the "
                         "reference run declares no reflectance either")
    name = str(scan.get("reference_name", "reference"))
    # a declared reflectance alone: the ideal-diffuser table (state it in the report)
    return ReferenceStandard.uniform(f"{name} (ideal diffuser, ρ={scan['reflectance']})",
                                     float(scan["reflectance"]))


def load_reference_table(path: str | Path) -> ReferenceStandard:
    """A reference standard from CSV rows ``theta_i_deg,theta_r_deg,brdf,u_rel`` (header
    line optional; a rectilinear grid; θr signed as in plan files)."""
    rows = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        parts = [x.strip() for x in line.split(",")]
        if len(parts) < 3 or not parts[0] or parts[0].startswith("#"):
            continue
        try:
            rows.append([float(x) for x in parts[:4]] + ([0.0] if len(parts) < 4 else []))
        except ValueError:
            continue  # header
    arr = np.array(rows)
    ti, tr = np.unique(arr[:, 0]), np.unique(arr[:, 1])
    f = np.full((ti.size, tr.size), np.nan)
    u = np.zeros_like(f)
    for a, b, v, w in arr:
        i, j = np.searchsorted(ti, a), np.searchsorted(tr, b)
        f[i, j], u[i, j] = v, w
    if np.any(np.isnan(f)):
        raise ValueError(f"{path}: the table is not a full (θi, θr) grid")
    return ReferenceStandard(Path(path).stem, ti, tr, f, u)


def _subtract_signature(arm: np.ndarray, pts: BRDFPoints,
                        opts: ReductionOptions) -> BRDFPoints:
    """Signature run reduced like the sample, interpolated in the detector-arm angle
    ``arm`` (deg, per point)."""
    assert opts.signature_run is not None
    sig = reduce_run(opts.signature_run, replace(opts, signature_run=None))
    order = np.argsort(sig.detector_theta)
    x = sig.detector_theta[order]
    f = np.interp(arm, x, sig.points.brdf[order])
    u = np.interp(arm, x, sig.points.u_point[order])
    return subtract_signature(pts, f, u)
