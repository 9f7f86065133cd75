"""A photon-transfer run file → EMVA 1288 evaluation → camera-calibration JSON.

The run is a ``photon_transfer`` plan (:mod:`instrument.plans.build`): at every exposure,
pairs of frames of a uniform target (label ``ptc``, light on) and a dark pair (label
``dark``, light off). The frames are read one pair at a time (a sweep's frames need not fit
in memory), reduced to pair statistics (:func:`analysis.photon_transfer.pair_statistics`)
and evaluated by :func:`analysis.emva1288.characterize`; the frames at the exposure nearest
half the saturation signal are read again and averaged for the non-uniformities.

The JSON written holds every key
:meth:`instrument.bench.camera_calibration.CameraCalibration.from_json` reads, and the
EMVA numbers with their uncertainties under ``"emva1288"`` (which ``from_json`` ignores).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from analysis.emva1288 import (
    CameraCharacterization,
    SweepStatistics,
    Uniformity,
    characterize,
    uniformity_exposure_index,
)
from analysis.photon_transfer import pair_statistics
from instrument.bench.camera_calibration import camera_url, simulated_camera_calibration
from instrument.run.runfile import RunData, RunFileError

__all__ = ["CameraOptics", "calibration_json", "characterize_run", "optics_for",
           "sweep_frames", "write_calibration"]

STATUS_OK = 0


@dataclass(frozen=True)
class CameraOptics:
    """What the calibration file needs beyond EMVA 1288: the light and the lens."""

    wavelength_nm: float
    pupil_diameter_mm: float
    pixel_pitch_um: float | None = None
    focal_length_mm: float | None = None
    chief_ray_only: bool = False


def sweep_frames(run: RunData) -> dict[float, tuple[list[int], list[int]]]:
    """Exposure (µs) → (light frame indices, dark frame indices) of a photon-transfer run,
    in acquisition order.

    Raises
    ------
    RunFileError
        Not a photon-transfer run, or an exposure without a light pair or a dark pair.
    """
    if run.plan_kind != "photon_transfer":
        raise RunFileError(f"{run.path} is a {run.plan_kind!r} run; camera characterization "
                           "needs a photon_transfer run (examples/calibration_ptc.toml)")
    by_exposure: dict[float, tuple[list[int], list[int]]] = {}
    for row in np.flatnonzero(run.point_status == STATUS_OK):
        if run.label[row] not in ("ptc", "dark"):
            continue
        n0, n = int(run.frame_start[row]), int(run.n_frames[row])
        for j in range(n0, n0 + n):
            key = round(float(run.frame_exposure_us[j]), 3)
            light, dark = by_exposure.setdefault(key, ([], []))
            (light if bool(run.frame_light[j]) else dark).append(j)
    short = [e for e, (lt, dk) in by_exposure.items() if len(lt) < 2 or len(dk) < 2]
    if short:
        raise RunFileError(f"{run.path}: exposure(s) {sorted(short)[:5]} µs lack a light pair "
                           "or a dark pair (was the run stopped early? resume it)")
    if len(by_exposure) < 3:
        raise RunFileError(f"{run.path}: {len(by_exposure)} exposure(s); the photon-transfer "
                           "evaluation needs at least 3 (EMVA 1288 asks for 50)")
    return dict(sorted(by_exposure.items()))


def _read_statistics(run: RunData, groups: dict[float, tuple[list[int], list[int]]]
                     ) -> SweepStatistics:
    p = min(len(lt) for lt, _ in groups.values()) // 2
    q = min(len(dk) for _, dk in groups.values()) // 2
    mean = np.empty((len(groups), p))
    var = np.empty_like(mean)
    dmean = np.empty((len(groups), q))
    dvar = np.empty_like(dmean)
    with run.frames() as ds:
        n_pixels = int(np.prod(ds.shape[1:]))
        for i, (light, dark) in enumerate(groups.values()):
            for k in range(p):
                mean[i, k], var[i, k] = pair_statistics(
                    np.stack([ds[light[2 * k]], ds[light[2 * k + 1]]]))
            for k in range(q):
                dmean[i, k], dvar[i, k] = pair_statistics(
                    np.stack([ds[dark[2 * k]], ds[dark[2 * k + 1]]]))
    return SweepStatistics(np.array(list(groups)), mean, var, dmean, dvar, n_pixels)


def _average(run: RunData, indices: list[int]) -> np.ndarray:
    with run.frames() as ds:
        acc = np.zeros(ds.shape[1:], dtype=np.float64)
        for j in indices:
            acc += ds[j]
    return acc / len(indices)


def characterize_run(run: RunData, *, photons_per_pixel_per_s: float | None = None,
                     u_photons_rel: float = 0.0, n_bootstrap: int = 400
                     ) -> CameraCharacterization:
    """Evaluate a photon-transfer run (module docstring)."""
    groups = sweep_frames(run)
    stats = _read_statistics(run, groups)
    j = uniformity_exposure_index(stats)
    light, dark = list(groups.values())[j]
    uni = Uniformity(_average(run, light), _average(run, dark), len(light), len(dark),
                     float(stats.exposures_us[j]))
    return characterize(stats, uni, photons_per_pixel_per_s=photons_per_pixel_per_s,
                        u_photons_rel=u_photons_rel, n_bootstrap=n_bootstrap)


def optics_for(run: RunData, *, wavelength_nm: float | None = None,
               pupil_diameter_mm: float | None = None, pixel_pitch_um: float | None = None,
               focal_length_mm: float | None = None) -> CameraOptics:
    """The optics for the calibration file: the values given; for a simulated camera
    (``simcam://``) the missing ones from the simulator's lens and source; for a real
    camera the wavelength and the pupil must be given.

    Raises
    ------
    ValueError
        A real camera without ``wavelength_nm`` or ``pupil_diameter_mm``.
    """
    profile = run.profile()
    url = camera_url(profile) or ""
    if url.startswith("simcam://"):
        wl = float(profile.get("simulation", {}).get("source", {}).get("wavelength_nm",
                                                                        633.0))
        sim = simulated_camera_calibration(url, wavelength_nm=wl)
        return CameraOptics(
            wavelength_nm if wavelength_nm is not None else sim.wavelength_nm,
            pupil_diameter_mm if pupil_diameter_mm is not None else sim.pupil_diameter_mm,
            pixel_pitch_um if pixel_pitch_um is not None else sim.pixel_pitch_um,
            focal_length_mm if focal_length_mm is not None else sim.focal_length_mm,
            sim.chief_ray_only)
    missing = [opt for opt, v in (("--wavelength-nm", wavelength_nm),
                                  ("--pupil-diameter-mm", pupil_diameter_mm)) if v is None]
    if missing:
        raise ValueError(f"the camera of {run.path} is not simulated: give "
                         f"{' and '.join(missing)} (the source's wavelength and the lens's "
                         "entrance-pupil diameter, from its data sheet)")
    assert wavelength_nm is not None and pupil_diameter_mm is not None
    return CameraOptics(wavelength_nm, pupil_diameter_mm, pixel_pitch_um, focal_length_mm)


def calibration_json(result: CameraCharacterization, optics: CameraOptics, *,
                     quantum_efficiency: float | None = None,
                     u_quantum_efficiency: float | None = None,
                     source: str = "", settings: dict[str, Any] | None = None
                     ) -> dict[str, Any]:
    """The calibration file's content (module docstring).

    η is the measured one when the sweep's photon count was known, else the one given (a
    data sheet's); without either it cannot be written. ``settings`` (the camera's gain and
    pixel format during the sweep) are recorded: the calibration holds for them only.

    Raises
    ------
    ValueError
        Neither a measured nor a given quantum efficiency.
    """
    qe, u_qe = result.quantum_efficiency, result.u_quantum_efficiency
    qe_from = "measured from the given photon count"
    if qe is None:
        if quantum_efficiency is None:
            raise ValueError("the quantum efficiency is unknown: give --photons-per-pixel-s "
                             "(the sweep's photon count from a calibrated photodiode) to "
                             "measure it, or --quantum-efficiency from the data sheet")
        qe, u_qe, qe_from = quantum_efficiency, u_quantum_efficiency, "given (data sheet)"
    u_resp = math.hypot(result.u_system_gain_dn_per_e / result.system_gain_dn_per_e,
                        (u_qe or 0.0) / qe)
    out: dict[str, Any] = {
        "system_gain_dn_per_e": result.system_gain_dn_per_e,
        "read_noise_e": result.dark_noise_e,
        "saturation_dn": result.saturation_dn,
        "dark_current_e_per_s": max(result.dark_current_e_per_s, 0.0),
        "quantum_efficiency": qe,
        "wavelength_nm": optics.wavelength_nm,
        "pupil_diameter_mm": optics.pupil_diameter_mm,
        "u_responsivity_rel": u_resp,
        "prnu_rel": result.prnu_rel,
        "chief_ray_only": optics.chief_ray_only,
    }
    if optics.pixel_pitch_um is not None:
        out["pixel_pitch_um"] = optics.pixel_pitch_um
    if optics.focal_length_mm is not None:
        out["focal_length_mm"] = optics.focal_length_mm
    r = result
    out["emva1288"] = {
        "standard": "EMVA 1288 Release 4.0 Linear",
        "source": source,
        "camera_settings": dict(settings or {}),
        "system_gain_dn_per_e": [r.system_gain_dn_per_e, r.u_system_gain_dn_per_e],
        "dark_noise_e": [r.dark_noise_e, r.u_dark_noise_e],
        "dark_noise_dn": r.dark_noise_dn,
        "saturation_dn": [r.saturation_dn, r.u_saturation_dn],
        "saturation_capacity_e": [r.saturation_capacity_e, r.u_saturation_capacity_e],
        "linearity_error_percent": [r.linearity_error_percent, r.u_linearity_error_percent],
        "linearity_error_unbiased_percent": r.linearity_error_unbiased_percent,
        "dark_current_e_per_s": [r.dark_current_e_per_s, r.u_dark_current_e_per_s],
        "dsnu_e": [r.dsnu_e, r.u_dsnu_e],
        "prnu_rel": [r.prnu_rel, r.u_prnu_rel],
        "quantum_efficiency": [qe, u_qe],
        "quantum_efficiency_from": qe_from,
        "uniformity_exposure_us": r.uniformity_exposure_us,
        "exposures": int(r.exposures_us.size),
        "pixels": r.n_pixels,
        "warnings": list(r.warnings),
        "uncertainties": "standard (k = 1): [value, u]",
    }
    return out


def write_calibration(content: dict[str, Any], path: str | Path) -> Path:
    """Write the calibration JSON (parent folders created)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(content, indent=2) + "\n", encoding="utf-8")
    return out
