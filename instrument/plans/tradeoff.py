"""Speed against accuracy of a BRDF scan: predict σ(parameters) and duration, find the fastest.

For a candidate scan — angular density (θr step), exposure cap and frames averaged — the
planner predicts

* the **duration** with the engine's own estimator
  (:meth:`instrument.plans.build.Plan.estimate` for the motion along the optimised route, and
  :meth:`~instrument.plans.commands.AcquisitionPolicy.estimated_seconds` per point at the
  exposure that point will get);
* the **parameter uncertainties** of a fit of a *prior* model (what the sample is expected
  to be: the simulated scene, or an earlier fit) from the Fisher information
  C = (JᵀWJ)⁻¹, W = diag(1/σ_f²) (Cramér–Rao bound of the weighted least-squares fit; the
  closed-loop tests show the fit reaches it,
  tests/instrument/pipelines/brdf/test_closed_loop.py), with the per-point noise σ_f of
  the camera method of :mod:`analysis.brdf.reduction`:

  - collected power P_s = f·P_i·Ω·cos θr (Nicodemus 1977; Ω the camera pupil's solid angle),
    i.e. R = P_s·η/hν electrons per second over the footprint's image;
  - exposure t = min(t_max, fill·FW / (R·q)), q the fraction of R on the brightest pixel:
    a Gaussian footprint of 1/e² radius w seen at θr from incidence θi has peak fraction
    q = 2a²/(π w² cos θr / cos θi) for pixels of size a on the sample (the auto-exposure
    keeps the brightest pixel below saturation; ``fill`` defaults to the policy's
    target fraction divided by √hdr_factor, the middle of the engine's exposure ladder);
  - var(S) = S/F + N_pix σ_pix²(t, F) electrons², S = R·t, F frames averaged, N_pix summed
    pixels and σ_pix the signal-independent noise of a light−dark difference
    (:meth:`analysis.brdf.reduction.DetectorNoise.difference_noise_dn`).

Angular and scale uncertainties are left out of the prediction (the first is negligible at
stage tolerances, the second does not change with the scan). The search returns the
fastest candidate whose predicted σ of the chosen parameter is ≤ the target; the Pareto
front is the set of candidates no other candidate beats in both time and σ.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol, TypeVar

import numpy as np

from analysis.brdf import get_model
from analysis.brdf.geometry import make_geometry
from analysis.brdf.reduction import solid_angle_sr
from analysis.radiometry import PLANCK_J_S, SPEED_OF_LIGHT_M_S
from instrument.bench.camera_calibration import (
    CameraCalibration,
    camera_url,
    simulated_camera_calibration,
)
from instrument.bench.profile import BenchProfile
from instrument.plans.build import build_plan
from instrument.plans.planfile import PlanSpec

__all__ = [
    "DetectorSetup",
    "OptionResult",
    "Prior",
    "ScanOption",
    "Traded",
    "default_options",
    "fastest_for_target",
    "pareto_front",
    "predict",
    "setup_from_profile",
    "sweep",
]


@dataclass(frozen=True)
class ScanOption:
    """One candidate: θr step (deg), exposure cap (µs), frames averaged per exposure."""

    theta_r_step_deg: float
    max_exposure_us: float
    frames: int

    def label(self) -> str:
        return (f"Δθr={self.theta_r_step_deg:g}°, t≤{self.max_exposure_us:g} µs, "
                f"{self.frames} frame{'s' if self.frames > 1 else ''}")


@dataclass(frozen=True)
class Prior:
    """The model expected to describe the sample, and its parameters."""

    model: str
    params: tuple[float, ...]


@dataclass(frozen=True)
class DetectorSetup:
    """Camera, source and geometry for the noise prediction."""

    camera: CameraCalibration
    incident_power_w: float
    distance_mm: float
    beam_radius_mm: float
    fill: float
    min_exposure_us: float = 10.0
    readout_s: float = 0.0


@dataclass(frozen=True)
class OptionResult:
    """Prediction for one :class:`ScanOption`.

    Attributes
    ----------
    duration_s, motion_s, acquisition_s : float
        The engine's estimate (motion along the optimised route + exposures).
    sigma : dict str → float
        Predicted standard uncertainty of every prior-model parameter.
    """

    option: ScanOption
    n_points: int
    motion_s: float
    acquisition_s: float
    sigma: dict[str, float]

    @property
    def duration_s(self) -> float:
        return self.motion_s + self.acquisition_s


def spec_for(spec: PlanSpec, option: ScanOption) -> PlanSpec:
    """``spec`` with the option's θr step, exposure cap and frames (angles range kept)."""
    scan = dict(spec.scan)
    tr = scan.get("theta_r")
    if tr is None:
        raise ValueError(f"the trade-off search varies theta_r of in-plane plans; "
                         f"{spec.kind!r} plans have none")
    if isinstance(tr, dict):
        scan["theta_r"] = {**tr, "step": float(option.theta_r_step_deg)}
    else:
        lo, hi = min(tr), max(tr)
        scan["theta_r"] = {"start": lo, "stop": hi, "step": float(option.theta_r_step_deg)}
    acq = replace(spec.acquisition, max_exposure_us=float(option.max_exposure_us),
                  exposure_us=min(spec.acquisition.exposure_us, float(option.max_exposure_us)),
                  frames=int(option.frames))
    return replace(spec, scan=scan, acquisition=acq)


def peak_electron_rate(f: np.ndarray, ti: np.ndarray, tr: np.ndarray, det: DetectorSetup
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(electrons per second over the footprint's image, electrons per second on its
    brightest pixel) of readings of BRDF ``f`` at incidence ``ti`` and view ``tr`` (radians;
    module docstring: P_s = f·P_i·Ω·cos θr and the peak fraction q of the footprint)."""
    cam = det.camera
    omega, _ = solid_angle_sr(cam.pupil_diameter_mm, det.distance_mm)
    photon_j = PLANCK_J_S * SPEED_OF_LIGHT_M_S / (cam.wavelength_nm * 1e-9)
    rate_e = f * det.incident_power_w * omega * np.cos(tr) / photon_j * cam.quantum_efficiency
    pitch = cam.pixel_pitch_um if cam.pixel_pitch_um is not None else 5.5
    focal = cam.focal_length_mm if cam.focal_length_mm is not None else 50.0
    a = pitch * 1e-3 * det.distance_mm / focal
    q = np.minimum(1.0, 2.0 * a * a / (math.pi * det.beam_radius_mm**2
                                       * np.maximum(np.cos(tr), 1e-3) / np.cos(ti)))
    return rate_e, rate_e * q


def full_well_e(det: DetectorSetup) -> float:
    """Electrons at which the camera's brightest pixel saturates."""
    noise = det.camera.noise
    return float(noise.saturation_dn / noise.system_gain_dn_per_e)


def _point_noise(f: np.ndarray, ti: np.ndarray, tr: np.ndarray, option: ScanOption,
                 det: DetectorSetup, transmission: np.ndarray | float = 1.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(relative σ of f, exposure µs) per point (module docstring), the light attenuated by
    ``transmission`` (a neutral-density filter in the beam; 1: open)."""
    cam = det.camera
    rate_e, peak_e = peak_electron_rate(f, ti, tr, det)
    rate_e = rate_e * transmission
    peak_e = peak_e * transmission
    t_us = det.fill * full_well_e(det) / np.maximum(peak_e, 1e-30) * 1e6
    t_us = np.clip(t_us, det.min_exposure_us, option.max_exposure_us)
    s = rate_e * t_us * 1e-6
    n_pix = cam.n_pixels if cam.n_pixels is not None else 1024 * 1024
    k = cam.noise.system_gain_dn_per_e
    pix = np.array([cam.noise.difference_noise_dn(float(e), n_averaged=option.frames,
                                                  n_dark_averaged=option.frames) / k
                    for e in np.ravel(t_us)]).reshape(np.shape(t_us))
    var = s / option.frames + n_pix * pix**2
    return np.sqrt(var) / np.maximum(s, 1e-300), t_us


def predict(spec: PlanSpec, profile: BenchProfile, option: ScanOption, *, prior: Prior,
            det: DetectorSetup) -> OptionResult:
    """Duration and predicted parameter σ of ``spec`` changed by ``option``."""
    plan = build_plan(spec_for(spec, option), profile)
    pts = [p for p in plan.points if p.angles is not None]
    # pts holds only points with angles (filtered just above)
    ang = np.radians(np.array([p.angles.as_tuple() for p in pts]))  # type: ignore[union-attr]
    model = get_model(prior.model)
    g = make_geometry(ang[:, 0], ang[:, 1], ang[:, 2], ang[:, 3])
    p = np.array(prior.params, dtype=float)
    f = model.evaluate_geometry(p, g)
    rel, t_us = _point_noise(f, ang[:, 0], ang[:, 2], option, det)
    jac = model.jacobian_geometry(p, g).reshape(-1, p.size)
    w = 1.0 / (rel * f) ** 2
    cov = np.linalg.pinv(jac.T @ (jac * w[:, None]), rcond=1e-12)
    sigma = dict(zip(model.param_names, np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist(),
                     strict=True))
    pol = plan.spec.acquisition
    if det.readout_s != pol.readout_s:
        pol = replace(pol, readout_s=det.readout_s)
    acq = float(sum(pol.estimated_seconds(float(e)) for e in t_us))
    est = plan.estimate()
    return OptionResult(option, len(plan.points), est.motion_s, acq, sigma)


def default_options() -> list[ScanOption]:
    """The sweep grid: θr steps 5–30°, exposure caps 0.1–100 ms, 1–8 frames."""
    return [ScanOption(step, cap, frames)
            for step in (5.0, 10.0, 15.0, 20.0, 30.0)
            for cap in (100.0, 1_000.0, 10_000.0, 100_000.0)
            for frames in (1, 2, 4, 8)]


def _predict_option(option: ScanOption, *, spec: PlanSpec, profile: BenchProfile,
                    prior: Prior, det: DetectorSetup) -> OptionResult:
    return predict(spec, profile, option, prior=prior, det=det)


def sweep(spec: PlanSpec, profile: BenchProfile, options: Iterable[ScanOption], *,
          prior: Prior, det: DetectorSetup,
          mapper: Callable[..., Sequence[OptionResult]] | None = None) -> list[OptionResult]:
    """:func:`predict` for every option, in order.

    ``mapper(fn, items, **shared)`` must return ``[fn(item, **shared) for item in items]``
    in that order, e.g. on a Dask cluster (``instrument.batch.cluster.cluster_map``);
    the predictions are deterministic, so the results equal the loop's. Default: the loop.
    """
    options = list(options)
    if mapper is None:
        return [predict(spec, profile, o, prior=prior, det=det) for o in options]
    return list(mapper(_predict_option, options, spec=spec, profile=profile, prior=prior,
                       det=det))


class Traded(Protocol):
    """A predicted candidate: its duration and σ per axis (an :class:`OptionResult`, or a
    :class:`instrument.plans.polarimetric_tradeoff.PolarimetricResult`)."""

    @property
    def duration_s(self) -> float: ...

    @property
    def sigma(self) -> dict[str, float]: ...


_T = TypeVar("_T", bound=Traded)


def pareto_front(results: Sequence[_T], param: str) -> list[_T]:
    """Candidates not beaten in both duration and σ(param), fastest first (the scalar
    scan's options and the polarimetric step counts alike)."""
    ordered = sorted(results, key=lambda r: (r.duration_s, r.sigma[param]))
    front: list[_T] = []
    best = math.inf
    for r in ordered:
        if r.sigma[param] < best:
            front.append(r)
            best = r.sigma[param]
    return front


def fastest_for_target(results: Sequence[_T], param: str, target: float) -> _T | None:
    """The fastest candidate with predicted σ(param) ≤ target (None if none reaches it;
    the scalar scan's options and the polarimetric step counts alike)."""
    ok = [r for r in results if r.sigma[param] <= target]
    return min(ok, key=lambda r: (r.duration_s, r.sigma[param])) if ok else None


def setup_from_profile(profile: BenchProfile, spec: PlanSpec, *, prior: Prior | None = None,
                       camera: CameraCalibration | None = None,
                       incident_power_w: float | None = None,
                       readout_s: float | None = None) -> tuple[Prior, DetectorSetup]:
    """Prior and detector from a (simulated) bench profile, unless given.

    The prior defaults to the simulated scene's ground truth, the camera to the simulated
    camera's exact calibration and the incident power to the simulated source's.
    """
    data = tomllib.loads(profile.source_text) if profile.source_text else {}
    sim = data.get("simulation", {})
    if prior is None:
        scene = sim.get("scene")
        if not scene:
            raise ValueError("give a prior model (--prior MODEL:p1,p2,...): the bench "
                             "simulates no scene to take it from")
        model = get_model(str(scene.get("brdf", "lambert")))
        params = scene.get("params", [0.5])
        if isinstance(params, dict):
            params = [float(params.get(n, s)) for n, s in
                      zip(model.param_names, model.start, strict=True)]
        prior = Prior(model.name, tuple(float(v) for v in params))
    if camera is None:
        url = camera_url(data)
        if url is None or not url.startswith("simcam://"):
            raise ValueError("the planner needs the camera's calibration on a real bench")
        wl = float(sim.get("source", {}).get("wavelength_nm", 633.0))
        camera = simulated_camera_calibration(url, wavelength_nm=wl)
    source = sim.get("source", {})
    p_i = incident_power_w if incident_power_w is not None else float(
        source.get("power_w", 1e-3))
    pol = spec.acquisition
    det = DetectorSetup(
        camera=camera, incident_power_w=p_i,
        distance_mm=profile.geometry.detector_distance_mm,
        beam_radius_mm=float(source.get("beam_radius_mm", 2.0)),
        fill=pol.target_fraction / math.sqrt(pol.hdr_factor),
        min_exposure_us=pol.min_exposure_us,
        readout_s=pol.readout_s if readout_s is None else readout_s)
    return prior, det
