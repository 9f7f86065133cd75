"""Spectral BRDF runs: reduce and fit per wavelength, plot the parameters against λ.

A run with a wavelength axis (a filter wheel stepping through filters) has, per point, the
filter's centre wavelength ``wavelength_nm``, its width ``bandwidth_nm`` and the wheel's
``filter_position`` (:class:`instrument.run.runfile.RunData`). :func:`fit_spectral` groups
the scattering points by filter (:func:`wavelength_groups`), reduces each group with the
run's detector (:func:`detector_of`):

* **lock-in** (a chopped photodiode): :mod:`analysis.brdf.reduction.lockin`, the absolute
  route through the photodiode's responsivity R(λ) at the filter's centre wavelength and
  the incident power at that filter, or the ratio route against a direct-beam reading of
  the same photodiode at that filter (responsivity and chopper factor cancel);
* **camera**: the run's camera reduction
  (:func:`instrument.pipelines.brdf.reduce.reduce_run`), rescaled per filter for the photon
  energy at the filter's wavelength
  (the camera converts counts to watts with hν at its calibration wavelength) and the
  incident power at that filter;

fits the models per wavelength (:func:`instrument.pipelines.brdf.analyse.analyse`, default
``lambert+ggx_fresnel``: ρ, n, α) and writes ``DIR/RUN/fit/`` (ADR 0013): ``spectral.png``
(the fitted parameters against λ with ±1σ bars), one report per wavelength in
``<λ>nm/index.html``, an ``index.html`` linking them, and ``results.h5`` with
``/entry/analysis/spectral`` (the parameter table) and one analysis group per wavelength.

Reading run files written before the wavelength columns existed: the columns are read
with ``getattr`` and read as NaN / -1 when absent (one group, no wavelength), so a run
without a wavelength axis is refused with a message pointing at ``scatterlab fit``.
"""

from __future__ import annotations

import html
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis.brdf.reduction import BRDFPoints
from analysis.brdf.reduction.lockin import (
    Photodiode,
    lockin_brdf_absolute,
    lockin_brdf_ratio,
    photodiode_from_profile,
    pooled_reading_sigma,
)
from instrument.bench.angles import AngularModel, angular_model
from instrument.pipelines.brdf.analyse import AnalysisResult, analyse
from instrument.pipelines.brdf.attenuation import apply_nd, nd_slots, nd_transmissions
from instrument.pipelines.brdf.dark import lockin_dark, net_lockin_r
from instrument.pipelines.brdf.reduce import (
    Reduced,
    ReductionOptions,
    instrument_function,
    reduce_run,
)
from instrument.pipelines.brdf.report import write_report
from instrument.pipelines.brdf.results import PROGRAM, fill_analysis
from instrument.run.paths import results_dir, results_path
from instrument.run.results import put, replace_group, write_results_file
from instrument.run.runfile import RunData, check_run_file, read_run

__all__ = [
    "DEFAULT_SPECTRAL_MODELS",
    "SpectralFit",
    "SpectralOptions",
    "WavelengthFit",
    "WavelengthGroup",
    "analyse_spectral",
    "detector_of",
    "fit_spectral",
    "has_wavelength_axis",
    "plot_parameters_vs_wavelength",
    "reduce_group",
    "reduce_spectral",
    "single_wavelength_group",
    "wavelength_groups",
    "write_spectral_report",
    "write_spectral_results",
]

#: Diffuse albedo plus a GGX lobe whose level is the Fresnel reflectance of n.
DEFAULT_SPECTRAL_MODELS = ("lambert+ggx_fresnel",)
_LOCKIN_COLUMNS = ("lockin_r_v", "lockin_u_r_v", "lockin_sensitivity_v", "lockin_overload")


@dataclass(frozen=True)
class SpectralOptions:
    """How to reduce and fit a spectral run.

    Attributes
    ----------
    detector : {"lockin", "camera"} or None
        None: the plan's ``[acquisition] detectors`` (lock-in when listed), else the lock-in
        when the run has lock-in readings, else the camera.
    route : {"absolute", "ratio"}
        Lock-in only: through the photodiode's responsivity and the incident power, or the
        ratio to a direct-beam reading (``reference_r_v``).
    incident_power_w : mapping of filter position → W, or None
        The incident power at each filter (absolute route, camera); default: the run's
        calibration ``incident_power_w.<position>``, else on a simulated bench the
        profile's source power through the profile's filter.
    u_incident_power_rel : float or None
        Its relative standard uncertainty (None: unknown, reported).
    reference_r_v : mapping of filter position → (R V rms, u(R) V, sensitivity V), or None
        Direct-beam lock-in readings (ratio route); default: the run's points labelled
        ``direct_beam`` at that filter.
    receiver_distance_mm, aperture_diameter_mm : float or None
        The photodiode's distance from the sample and aperture; default the profile's
        ``[photodiode]`` ``distance_mm``/``aperture_diameter_mm``, else the bench geometry.
    sigma_theta_deg : float or None
        Angular standard uncertainty of the recorded angles; default the stages' read-back
        resolution and repeatability (:mod:`instrument.bench.angles`), as the camera's.
    models : sequence of str
        Candidate models fitted at every wavelength.
    reduction : ReductionOptions or None
        Camera route: the options of the camera reduction.
    receiver_geometry : bool
        Lock-in: the instrument function of the camera and the power meter
        (:func:`instrument_function`: beam footprint and divergence, the photodiode's
        aperture, the read-back spread), its receiver factor divided out and the models
        fitted as the receiver sees them; False: a point spot and a point receiver.
    wavelength_nm : float or None
        Lock-in run without a wavelength axis: the light's wavelength (for R(λ)); default
        the profile's ``[photodiode] wavelength_nm``, else a simulated source's.
    """

    detector: str | None = None
    route: str = "absolute"
    incident_power_w: Mapping[int, float] | None = None
    u_incident_power_rel: float | None = None
    reference_r_v: Mapping[int, tuple[float, float, float]] | None = None
    receiver_distance_mm: float | None = None
    aperture_diameter_mm: float | None = None
    sigma_theta_deg: float | None = None
    models: tuple[str, ...] = DEFAULT_SPECTRAL_MODELS
    reduction: ReductionOptions | None = None
    receiver_geometry: bool = True
    wavelength_nm: float | None = None


@dataclass(frozen=True)
class WavelengthGroup:
    """The scattering rows of one filter: centre and width in nm, wheel position."""

    wavelength_nm: float
    bandwidth_nm: float
    filter_position: int
    rows: np.ndarray

    @property
    def label(self) -> str:
        return f"{self.wavelength_nm:g} nm"

    @property
    def folder(self) -> str:
        return f"{self.wavelength_nm:g}nm"


@dataclass(frozen=True)
class WavelengthFit:
    """One wavelength's reduction and analysis."""

    group: WavelengthGroup
    reduced: Reduced
    result: AnalysisResult


@dataclass(frozen=True)
class SpectralFit:
    """What :func:`fit_spectral` produced; ``report`` and ``results`` are paths or None."""

    run: RunData
    detector: str
    fits: tuple[WavelengthFit, ...]
    report: Path | None = None
    results: Path | None = None
    notes: tuple[str, ...] = field(default=())

    @property
    def wavelength_nm(self) -> np.ndarray:
        return np.array([f.group.wavelength_nm for f in self.fits])

    def parameter(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(value, standard uncertainty) of the chosen model's parameter ``name`` per
        wavelength (the short name, e.g. "n", or the full one, "ggx_fresnel.n"); NaN where
        the chosen model has no such parameter."""
        vals, errs = [], []
        for f in self.fits:
            fit = f.result.chosen_fit
            names = list(fit.param_names)
            short = [p.split(".")[-1] for p in names]
            k = names.index(name) if name in names else (
                short.index(name) if name in short else -1)
            vals.append(fit.params[k] if k >= 0 else np.nan)
            errs.append(fit.stderr[k] if k >= 0 else np.nan)
        return np.array(vals, dtype=float), np.array(errs, dtype=float)

    def parameter_names(self) -> tuple[str, ...]:
        """Short parameter names of the chosen models, in first-seen order."""
        out: list[str] = []
        for f in self.fits:
            for p in f.result.chosen_fit.param_names:
                s = p.split(".")[-1]
                if s not in out:
                    out.append(s)
        return tuple(out)


# ---------------------------------------------------------------------------- the run
def _column(run: RunData, name: str, fill: float) -> np.ndarray:
    """A per-point column of the run, or ``fill`` everywhere for a run file written
    before it existed."""
    value = getattr(run, name, None)
    if value is None:
        return np.full(run.n_points, fill)
    return np.asarray(value)


def has_wavelength_axis(run: RunData) -> bool:
    """Whether the run's scattering points carry a wavelength."""
    rows = run.brdf_rows()
    return bool(rows.size and np.any(np.isfinite(_column(run, "wavelength_nm",
                                                         np.nan)[rows].astype(float))))


def wavelength_groups(run: RunData, rows: np.ndarray | None = None
                      ) -> tuple[WavelengthGroup, ...]:
    """The scattering rows grouped by filter (wheel position, or the wavelength when no
    position was recorded), in order of wavelength."""
    rows = run.brdf_rows() if rows is None else np.asarray(rows)
    lam = _column(run, "wavelength_nm", np.nan).astype(float)
    bw = _column(run, "bandwidth_nm", np.nan).astype(float)
    pos = _column(run, "filter_position", -1).astype(int)
    keys: dict[tuple[int, float], list[int]] = {}
    for r in rows:
        key = (int(pos[r]), round(float(lam[r]), 3) if np.isfinite(lam[r]) else math.nan)
        keys.setdefault(key, []).append(int(r))
    groups = [WavelengthGroup(float(np.nanmean(lam[rw])) if np.isfinite(lam[rw]).any()
                              else math.nan,
                              float(np.nanmean(bw[rw])) if np.isfinite(bw[rw]).any()
                              else math.nan, p, np.array(rw))
              for (p, _), rw in keys.items()]
    return tuple(sorted(groups, key=lambda g: (math.isnan(g.wavelength_nm),
                                               g.wavelength_nm)))


def single_wavelength_group(run: RunData, opts: SpectralOptions) -> WavelengthGroup:
    """Every scattering point of a lock-in run without a wavelength axis, as one group at
    the light's wavelength (:class:`SpectralOptions` ``wavelength_nm``); points read
    through a neutral-density filter stay in it (their slot is divided out)."""
    profile = run.profile()
    src = profile.get("simulation", {}).get("source", {})
    lam = opts.wavelength_nm or profile.get("photodiode", {}).get("wavelength_nm") or (
        src.get("wavelength_nm"))
    if lam is None:
        raise ValueError(f"{run.path}: the light's wavelength is unknown (the run has no "
                         "wavelength axis): set [photodiode] wavelength_nm in the bench "
                         "profile for the photodiode's responsivity")
    return WavelengthGroup(float(lam), float(src.get("bandwidth_nm", math.nan)), -1,
                           run.brdf_rows())


def _plan_table(run: RunData) -> dict[str, Any]:
    try:
        return tomllib.loads(run.plan_text) if run.plan_text else {}
    except tomllib.TOMLDecodeError:
        return {}


def detector_of(run: RunData, requested: str | None = None) -> str:
    """"lockin" or "camera" for this run (see :class:`SpectralOptions`)."""
    if requested is not None:
        if requested not in ("lockin", "camera"):
            raise ValueError(f"detector must be 'lockin' or 'camera', got {requested!r}")
        return requested
    listed = _plan_table(run).get("acquisition", {}).get("detectors", [])
    if "lockin" in listed:
        return "lockin"
    if "camera" in listed:
        return "camera"
    r = _column(run, "lockin_r_v", np.nan).astype(float)[run.brdf_rows()]
    return "lockin" if r.size and np.all(np.isfinite(r)) else "camera"


# ------------------------------------------------------------------ incident power
def _filter_table(run: RunData) -> dict[int, dict[str, float]]:
    """Filter position → its simulated band (``[simulation.filter_wheel] filters``)."""
    sim = run.profile().get("simulation", {})
    wheel = sim.get("filter_wheel", {})
    filters = wheel.get("filters", {}) if isinstance(wheel, dict) else {}
    return {int(k): v for k, v in filters.items() if isinstance(v, dict) and v}


def _simulated_incident_power(run: RunData, position: int) -> float | None:
    """On a simulated bench: the source power through the flat-top filter of the profile
    (the simulated bench's filter model, hw_mocks/sim/filters.py's docstring)."""
    src = run.profile().get("simulation", {}).get("source", {})
    if "power_w" not in src:
        return None
    p = float(src["power_w"])
    band = _filter_table(run).get(position)
    if band is None:
        return p
    lam0, bw0 = float(src.get("wavelength_nm", 633.0)), float(src.get("bandwidth_nm", 0.0))
    lo = float(band["center_nm"]) - 0.5 * float(band["bandwidth_nm"])
    hi = float(band["center_nm"]) + 0.5 * float(band["bandwidth_nm"])
    peak, block = float(band.get("peak_transmission", 1.0)), float(band.get("blocking", 0.0))
    if bw0 <= 0:
        return p * (peak if lo <= lam0 <= hi else block)
    passed = max(min(hi, lam0 + bw0 / 2) - max(lo, lam0 - bw0 / 2), 0.0)
    frac = passed / bw0
    return p * (peak * frac + block * (1.0 - frac))


def _incident_power(run: RunData, group: WavelengthGroup, opts: SpectralOptions
                    ) -> tuple[float, str]:
    pos = group.filter_position
    if opts.incident_power_w is not None and pos in opts.incident_power_w:
        return float(opts.incident_power_w[pos]), "option"
    key = f"incident_power_w.{pos}"
    if key in run.calibration:
        return float(run.calibration[key]), "run calibration"
    sim = _simulated_incident_power(run, pos)
    if sim is not None:
        return sim, "simulated source through the profile's filter"
    raise ValueError(f"no incident power for filter {pos} ({group.label}): give it per "
                     "filter (incident_power_w) or use the ratio route with a direct-beam "
                     "reading")


# ----------------------------------------------------------------------- reductions
def _lockin_reduction_options(opts: SpectralOptions) -> ReductionOptions:
    """The camera's and power meter's reduction options, as the lock-in's photodiode uses
    them: one instrument function (:func:`instrument_function`) for every detector."""
    base = opts.reduction or ReductionOptions()
    return replace(base, detector="lockin",
                   receiver_distance_mm=(opts.receiver_distance_mm
                                         or base.receiver_distance_mm),
                   aperture_diameter_mm=(opts.aperture_diameter_mm
                                         or base.aperture_diameter_mm),
                   sigma_theta_deg=(opts.sigma_theta_deg if opts.sigma_theta_deg is not None
                                    else base.sigma_theta_deg),
                   receiver_geometry=opts.receiver_geometry and base.receiver_geometry)


def _lockin_noise(run: RunData, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """σ of each point's mean R and of its dark component from the noise model fitted to
    every lock-in reading of the run (:func:`pooled_reading_sigma`), and its description."""
    all_rows = run.brdf_rows()
    r = _column(run, "lockin_r_v", np.nan).astype(float)
    u = _column(run, "lockin_u_r_v", np.nan).astype(float)
    du = _column(run, "lockin_dark_u_v", np.nan).astype(float)
    n = _snapshots(run)
    ok = all_rows[np.isfinite(r[all_rows]) & np.isfinite(u[all_rows])]
    _, a, b = pooled_reading_sigma(r[ok], u[ok], n, dark_u_v=du[ok], n_dark_readings=n)
    if a == 0.0 and b == 0.0:
        return u[rows], du[rows], "each point's own spread (no spread recorded)"
    sig = np.sqrt((a + b * np.abs(r[rows])) / n)
    sig_dark = np.where(np.isfinite(du[rows]), math.sqrt(a / n), np.nan)
    return sig, sig_dark, (f"noise model of the run's {ok.size} points: var(R) = "
                           f"({math.sqrt(a) * 1e9:.3g} nV)² + {b * 1e9:.3g} nV·R per snapshot, "
                           f"{n} snapshots a point")


def _snapshots(run: RunData) -> int:
    """Snapshots the engine averaged per lock-in point (``frames``, at least 4)."""
    return max(int(dict(run.acquisition).get("frames", 4) or 4), 4)


def _lockin_points(run: RunData, group: WavelengthGroup, opts: SpectralOptions,
                   photodiode: Photodiode) -> tuple[BRDFPoints, dict[str, Any], list[str]]:
    rows = group.rows
    r, _, s, o = (_column(run, c, np.nan if c != "lockin_overload" else 0).astype(float)[rows]
                  for c in _LOCKIN_COLUMNS)
    u, u_dark, noise = _lockin_noise(run, rows)
    # the lock-in's reading with the light off (a coherent offset), subtracted as a phasor
    dark = lockin_dark(run, rows)
    if dark.measured:
        if dark.policy == "per_point":
            dark = replace(dark, u_level=u_dark)
        x = _column(run, "lockin_x_v", np.nan).astype(float)[rows]
        y = _column(run, "lockin_y_v", np.nan).astype(float)[rows]
        r, u = net_lockin_r(x, y, u, dark)
    # readings through a neutral-density filter: divided by its transmission (ADR 0018)
    red_opts = _lockin_reduction_options(opts)
    nd_table, warnings = nd_transmissions(run, red_opts.nd_calibration,
                                          red_opts.camera_calibration)
    slots = nd_slots(run, rows)
    r, u, cov_nd = apply_nd(r, u, slots, nd_table)
    rad = np.radians
    angles = (rad(run.theta_i[rows]), rad(run.phi_i[rows]), rad(run.theta_r[rows]),
              rad(run.phi_r[rows]))
    receiver, prov = instrument_function(run, rows, red_opts)
    ang = (AngularModel(math.radians(opts.sigma_theta_deg),
                        math.radians(opts.sigma_theta_deg), (), ())
           if opts.sigma_theta_deg is not None else angular_model(run.profile()))
    warnings += list(ang.warnings)
    common = {"solid_angle": prov["solid_angle_sr"], "u_solid_angle": prov["u_solid_angle_sr"],
              "overload": o > 0, "sigma_theta_i": ang.sigma_theta_i_rad,
              "sigma_theta_r": ang.sigma_theta_r_rad, "receiver": receiver,
              "cov_extra_rel": cov_nd}
    prov["detector_dark"] = dark.describe("µV", 1e6)
    prov["lockin_noise"] = noise
    if (slots >= 0).any():
        prov["nd_filters"] = [
            f"{nd_table[int(k)].describe()}: {int(np.sum(slots == k))} point(s)"
            for k in np.unique(slots[slots >= 0])]
    if opts.route == "absolute":
        p_i, src = _incident_power(run, group, opts)
        u_rel = opts.u_incident_power_rel
        pts = lockin_brdf_absolute(r, u, s, *angles, photodiode=photodiode,
                                   wavelength_nm=group.wavelength_nm, incident_power_w=p_i,
                                   u_incident_power_w=p_i * (u_rel or 0.0), **common)
        prov.update(incident_power_w=p_i, incident_power_source=src,
                    responsivity_a_per_w=photodiode.responsivity(group.wavelength_nm))
    elif opts.route == "ratio":
        r_ref, u_ref, s_ref = _direct_beam(run, group, opts)
        pts = lockin_brdf_ratio(r, u, s, *angles, reference_r_v=r_ref,
                                u_reference_r_v=u_ref, reference_sensitivity_v=s_ref,
                                **common)
        prov.update(reference_r_v=r_ref, u_reference_r_v=u_ref)
    else:
        raise ValueError(f"route must be 'absolute' or 'ratio', got {opts.route!r}")
    return pts, prov, warnings


def _direct_beam(run: RunData, group: WavelengthGroup, opts: SpectralOptions
                 ) -> tuple[float, float, float]:
    pos = group.filter_position
    if opts.reference_r_v is not None and pos in opts.reference_r_v:
        r, u, s = opts.reference_r_v[pos]
        return float(r), float(u), float(s)
    pos_col = _column(run, "filter_position", -1).astype(int)
    rows = np.flatnonzero((run.label == "direct_beam") & (pos_col == pos))
    if rows.size:
        r = _column(run, "lockin_r_v", np.nan).astype(float)[rows]
        u = _column(run, "lockin_u_r_v", np.nan).astype(float)[rows]
        s = _column(run, "lockin_sensitivity_v", np.nan).astype(float)[rows]
        return float(np.mean(r)), float(np.sqrt(np.sum(u**2)) / rows.size), float(s[0])
    raise ValueError(f"the ratio route needs a direct-beam lock-in reading at filter {pos} "
                     f"({group.label}): points labelled direct_beam, or reference_r_v")


def _rescaled(pts: BRDFPoints, factor: float, u_scale_rel: float) -> BRDFPoints:
    cov = None if pts.cov_corr is None else pts.cov_corr * factor**2
    return replace(pts, brdf=pts.brdf * factor, u_stat=pts.u_stat * factor,
                   u_angle=pts.u_angle * factor, u_ref=pts.u_ref * factor,
                   u_scale_rel=u_scale_rel, cov_corr=cov)


def reduce_group(run: RunData, group: WavelengthGroup, opts: SpectralOptions, *,
                 detector: str, camera: Reduced | None = None) -> Reduced:
    """Reduce one wavelength's points (module docstring). ``camera`` is the whole run's
    camera reduction at an incident power of 1 W (:func:`fit_spectral` makes it once)."""
    if not np.isfinite(group.wavelength_nm):
        raise ValueError(f"{run.path}: points without a wavelength (filter position "
                         f"{group.filter_position}); a run without a wavelength axis is "
                         "analysed by scatterlab fit without --per-wavelength")
    prov: dict[str, Any] = {"run_id": run.run_id, "detector": detector,
                            "wavelength_nm": group.wavelength_nm,
                            "bandwidth_nm": group.bandwidth_nm,
                            "filter_position": group.filter_position}
    warnings: list[str] = []
    if detector == "lockin":
        photodiode = photodiode_from_profile(run.profile().get("photodiode", {}),
                                             where="the bench profile's [photodiode]")
        pts, extra, lockin_warnings = _lockin_points(run, group, opts, photodiode)
        prov.update(extra, method=pts.method, route=opts.route)
        warnings.extend(f"{group.label}: {w}" for w in lockin_warnings)
        if extra["detector_dark"].startswith("none"):
            warnings.append(f"{group.label}: lock-in dark not measured (a coherent offset at "
                            "the chopper frequency stays in every reading); set "
                            "[acquisition] dark = \"per_point\" to read it with the shutter "
                            "closed and subtract it")
    else:
        assert camera is not None
        idx = np.flatnonzero(np.isin(camera.rows, group.rows) & (camera.source == 0))
        p_i, src = _incident_power(run, group, opts)
        cal_nm = float(camera.provenance.get("camera_wavelength_nm", group.wavelength_nm))
        # counts → W used hν at the calibration wavelength: photons of this filter carry
        # hc/λ, so P scales by λ_cal/λ; the quantum efficiency is the calibration's
        factor = cal_nm / group.wavelength_nm / p_i
        u_pi = opts.u_incident_power_rel or 0.0
        sub = camera.points.take(idx)
        scale = math.sqrt(max(sub.u_scale_rel**2 + u_pi**2, 0.0))
        pts = _rescaled(sub, factor, scale)
        prov.update(camera.provenance, incident_power_w=p_i, incident_power_source=src)
        if abs(cal_nm - group.wavelength_nm) > 0.5 * max(group.bandwidth_nm, 1.0):
            warnings.append(f"{group.label}: the camera's quantum efficiency is that of its "
                            f"calibration at {cal_nm:g} nm (no spectral QE known)")
    if opts.u_incident_power_rel is None and not (detector == "lockin"
                                                  and opts.route == "ratio"):
        warnings.append(f"{group.label}: the incident power's uncertainty is unknown "
                        "(left out of the common scale)")
    return Reduced(pts, group.rows, run.position("detector_theta")[group.rows], prov,
                   point_index=run.index[group.rows],
                   source=np.zeros(group.rows.size, dtype=int), sources=(run.run_id,),
                   warnings=tuple(warnings))


# ------------------------------------------------------------------------- the fit
def reduce_spectral(run: RunData, options: SpectralOptions | None = None
                    ) -> tuple[str, tuple[tuple[WavelengthGroup, Reduced], ...]]:
    """The detector used and each wavelength's reduction, in order of wavelength (nothing
    fitted, nothing written).

    Raises
    ------
    ValueError
        The run has no wavelength axis, or as :func:`reduce_group`.
    """
    opts = options or SpectralOptions()
    detector = detector_of(run, opts.detector)
    groups = wavelength_groups(run)
    if not has_wavelength_axis(run):
        if detector != "lockin":
            raise ValueError(f"{run.path}: the run has no wavelength axis (no wavelength_nm "
                             "per point); fit it with scatterlab fit")
        groups = (single_wavelength_group(run, opts),)
    camera = None
    if detector == "camera":
        red_opts = replace(opts.reduction or ReductionOptions(), incident_power_w=1.0,
                           u_incident_power_rel=0.0, method="absolute", detector="camera")
        camera = reduce_run(run.path, red_opts)
        cal = run.camera_calibration(red_opts.camera_calibration)
        camera.provenance["camera_wavelength_nm"] = cal.wavelength_nm
    return detector, tuple((g, reduce_group(run, g, opts, detector=detector, camera=camera))
                           for g in groups)


def analyse_spectral(run: RunData, options: SpectralOptions | None = None, *,
                     criterion: str = "bic", seed: int = 0) -> SpectralFit:
    """Group, reduce and fit a run already read (no report, nothing written): the
    per-wavelength fits of :func:`fit_spectral`, callable on any :class:`RunData`.

    Raises
    ------
    ValueError
        As :func:`fit_spectral`.
    """
    opts = options or SpectralOptions()
    detector, groups = reduce_spectral(run, opts)
    fits = []
    for group, reduced in groups:
        result = analyse(reduced.points, opts.models, criterion=criterion, run_cv=False,
                         seed=seed, wavelength_nm=group.wavelength_nm,
                         instrument_aware=reduced.points.receiver is not None)
        fits.append(WavelengthFit(group, reduced, result))
    return SpectralFit(run, detector, tuple(fits))


def fit_spectral(
    path: str | Path,
    options: SpectralOptions | None = None,
    *,
    report_dir: str | Path | None = None,
    report: bool = True,
    write: bool = True,
    criterion: str = "bic",
    seed: int = 0,
) -> SpectralFit:
    """Reduce and fit a spectral run per wavelength; write the report and results
    (module docstring). Returns the per-wavelength fits.

    Raises
    ------
    RunFileError
        Not a readable BRDF run.
    ValueError
        No wavelength axis, a missing photodiode section, incident power or direct-beam
        reading (the message names what to give).
    """
    check_run_file(path, "fit")
    opts = options or SpectralOptions()
    done = analyse_spectral(read_run(path), opts, criterion=criterion, seed=seed)
    folder = Path(report_dir) if report_dir is not None else results_dir(path, "fit")
    page = write_spectral_report(folder, done) if report else None
    saved = write_spectral_results(path, done, folder=folder, options=opts) if write else None
    return replace(done, report=page, results=saved)


# ------------------------------------------------------------------ report and results
#: Parameter names in words, with their unit, for the axes.
_AXIS = {"rho": "diffuse albedo ρ", "n": "refractive index n", "k": "extinction k",
         "alpha": "GGX roughness α"}


def plot_parameters_vs_wavelength(fit: SpectralFit, path: str | Path,
                                  truth: Mapping[str, Sequence[float]] | None = None) -> Path:
    """One panel per parameter of the chosen models against λ (nm), ±1σ error bars;
    ``truth`` (name → values per wavelength) is drawn as a line when given."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    names = fit.parameter_names()
    lam = fit.wavelength_nm
    fig, axes = plt.subplots(len(names), 1, figsize=(6.0, 2.2 * len(names) + 0.6),
                             sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        val, err = fit.parameter(name)
        ax.errorbar(lam, val, yerr=err, fmt="o", capsize=4, label="fit ±1σ")
        if truth is not None and name in truth:
            ax.plot(lam, truth[name], "k--", lw=1, label="truth")
            ax.legend(fontsize=8)
        ax.set_ylabel(f"{_AXIS.get(name, name)} (1)")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("wavelength λ (nm)")
    fig.suptitle(f"Fitted parameters against wavelength ({fit.detector})", fontsize=10)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def write_spectral_report(folder: str | Path, fit: SpectralFit) -> Path:
    """``spectral.png``, one report per wavelength and an ``index.html`` linking them."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    plot_parameters_vs_wavelength(fit, out / "spectral.png")
    rows = []
    for wf in fit.fits:
        write_report(out / wf.group.folder, wf.reduced.points, wf.result,
                     title=f"BRDF at {wf.group.label} (run {fit.run.run_id})",
                     provenance=wf.reduced.provenance,
                     point_labels=[wf.reduced.point_label(k)
                                   for k in range(wf.reduced.points.n)],
                     warnings=wf.reduced.warnings)
        cells = "".join(
            f"<td>{v:.5g} ± {e:.2g}</td>"
            for v, e in (fit_param(wf, n) for n in fit.parameter_names()))
        rows.append(f"<tr><td><a href='{wf.group.folder}/index.html'>{wf.group.label}</a>"
                    f"</td><td>{wf.group.bandwidth_nm:g}</td><td>{wf.reduced.points.n}</td>"
                    f"<td>{html.escape(wf.result.chosen)}</td>{cells}"
                    f"<td>{html.escape(wf.result.verdict)}</td></tr>")
    head = "".join(f"<th>{html.escape(_AXIS.get(n, n))}</th>" for n in fit.parameter_names())
    page = out / "index.html"
    page.write_text(
        "<!doctype html><meta charset='utf-8'><title>Spectral BRDF</title>"
        f"<h1>Spectral BRDF of run {html.escape(fit.run.run_id)} ({fit.detector})</h1>"
        "<p>Per wavelength: the chosen model's parameters ± standard uncertainty.</p>"
        "<img src='spectral.png' alt='fitted parameters against wavelength'>"
        "<table border=1 cellpadding=4><tr><th>λ</th><th>Δλ (nm)</th><th>points</th>"
        f"<th>model</th>{head}<th>verdict</th></tr>{''.join(rows)}</table>",
        encoding="utf-8")
    return page


def fit_param(wf: WavelengthFit, name: str) -> tuple[float, float]:
    """(value, σ) of parameter ``name`` (short name) of one wavelength's chosen fit."""
    fit = wf.result.chosen_fit
    for k, p in enumerate(fit.param_names):
        if p.split(".")[-1] == name:
            return float(fit.params[k]), float(fit.stderr[k])
    return math.nan, math.nan


def write_spectral_results(path: str | Path, fit: SpectralFit, *, options: SpectralOptions,
                           folder: str | Path | None = None) -> Path:
    """``results.h5`` (ADR 0013): ``/entry/analysis/spectral`` with ``wavelength_nm``,
    ``bandwidth_nm``, ``filter_position``, ``param_names`` and ``params``/``stderr`` of
    shape (wavelengths, parameters), and one analysis group per wavelength
    (``/entry/analysis/wl_<λ>nm``, the layout of :func:`fill_analysis`)."""
    import h5py

    opts = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in asdict(options).items()}
    with write_results_file(path, "fit", run_id=fit.run.run_id, program=PROGRAM,
                            options={"spectral": opts}, folder=folder) as g:
        s = replace_group(g, "spectral", "NXprocess")
        s.attrs["detector"] = fit.detector
        names = fit.parameter_names()
        s.create_dataset("wavelength_nm", data=fit.wavelength_nm).attrs["units"] = "nm"
        s.create_dataset("bandwidth_nm", data=[f.group.bandwidth_nm for f in fit.fits]
                         ).attrs["units"] = "nm"
        s.create_dataset("filter_position", data=[f.group.filter_position for f in fit.fits])
        s.create_dataset("param_names", data=np.array(names, dtype=object),
                         dtype=h5py.string_dtype())
        table = np.array([[fit_param(f, n) for n in names] for f in fit.fits])
        s.create_dataset("params", data=table[..., 0])
        s.create_dataset("stderr", data=table[..., 1])
        put(s, "models", ",".join(f.result.chosen for f in fit.fits))
        for wf in fit.fits:
            grp = replace_group(g, f"wl_{wf.group.folder}", "NXprocess")
            fill_analysis(grp, wf.reduced, wf.result.to_dict())
            grp.attrs["wavelength_nm"] = wf.group.wavelength_nm
    return results_path(path, "fit", folder)
