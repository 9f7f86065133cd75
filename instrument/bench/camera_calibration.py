"""The camera's radiometric calibration: EMVA 1288 constants, pupil and optics.

Shared by the BRDF and sphere pipelines (camera frames → power or radiance) and by the
speed/accuracy planner (predicted noise). The numbers come from a JSON file the operator
gives (a calibrated real camera), from the file named in the run's ``calibration`` table,
or — for a simulated camera (``simcam://`` URL in the bench profile) — from the simulator
itself, as a perfect calibration would give it. The simulator is reached only by the
string entry point keyed on the URL scheme (:data:`instrument.bench.devices.SIM_ENTRY_POINTS`),
never by an import (docs/architecture.md import rules).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from analysis.brdf.reduction import DetectorNoise
from instrument.bench.devices import sim_entry_point
from instrument.bench.driver_registry import driver_registry

__all__ = ["CameraCalibration", "camera_calibration_for", "camera_spec",
           "camera_url", "simulated_camera_calibration"]


@dataclass(frozen=True)
class CameraCalibration:
    """What the absolute camera method needs (EMVA 1288 constants and the pupil).

    Attributes
    ----------
    noise : DetectorNoise
    quantum_efficiency : float
    wavelength_nm : float
    pupil_diameter_mm : float
        Entrance-pupil diameter (the receiver aperture of the absolute method).
    u_responsivity_rel : float
        Relative standard uncertainty of Kη (calibration).
    source : str
        Where the numbers came from (reported).
    pixel_pitch_um, focal_length_mm : float or None
        Optics, for planning (the footprint's image size); optional.
    n_pixels : int or None
        Pixels summed per point (the frame), for planning; optional.
    chief_ray_only : bool
        True for a camera model that takes each pixel's radiance along its chief ray
        through the pupil centre (a simulated camera with ``pupil=chief``); False for a
        real lens, and the default simulated camera, which average the scene over the
        pupil. Decides whether the receiver model integrates the pupil
        (:class:`analysis.brdf.reduction.ReceiverGeometry`).
    prnu_rel : float
        Photo-response non-uniformity (EMVA 1288 R3.1 §4: relative σ of one pixel's
        response); without a flat-field correction it is an error of the summed signal
        shared between points (:func:`analysis.brdf.reduction.pixel_response_covariance`).
    """

    noise: DetectorNoise
    quantum_efficiency: float
    wavelength_nm: float
    pupil_diameter_mm: float
    u_responsivity_rel: float = 0.0
    source: str = ""
    pixel_pitch_um: float | None = None
    focal_length_mm: float | None = None
    n_pixels: int | None = None
    chief_ray_only: bool = False
    prnu_rel: float = 0.0

    @classmethod
    def from_json(cls, path: str | Path) -> CameraCalibration:
        """Keys: system_gain_dn_per_e, read_noise_e, saturation_dn, dark_current_e_per_s,
        quantum_efficiency, wavelength_nm, pupil_diameter_mm, u_responsivity_rel;
        optional pixel_pitch_um, focal_length_mm, n_pixels, chief_ray_only, prnu_rel."""
        d = json.loads(Path(path).read_text(encoding="utf-8"))
        noise = DetectorNoise(float(d["system_gain_dn_per_e"]), float(d["read_noise_e"]),
                              float(d["saturation_dn"]),
                              float(d.get("dark_current_e_per_s", 0.0)))
        opt = {k: d[k] for k in ("pixel_pitch_um", "focal_length_mm", "n_pixels",
                                 "chief_ray_only", "prnu_rel") if k in d}
        return cls(noise, float(d["quantum_efficiency"]), float(d["wavelength_nm"]),
                   float(d["pupil_diameter_mm"]), float(d.get("u_responsivity_rel", 0.0)),
                   source=str(path), **opt)


def camera_spec(profile: dict[str, Any]) -> tuple[str, dict[str, Any]] | None:
    """(role, device table) of the camera a bench profile (parsed TOML) names, if any."""
    for role, spec in profile.get("devices", {}).items():
        driver = spec.get("driver")
        is_camera = isinstance(driver, str) and driver_registry().kind_of(driver) == "camera"
        if is_camera or str(spec.get("url", "")).startswith("simcam://"):
            return role, spec
    return None


def camera_url(profile: dict[str, Any]) -> str | None:
    """URL of the camera named in a bench profile (parsed TOML), if any."""
    found = camera_spec(profile)
    return None if found is None else str(found[1].get("url", ""))


def simulated_camera_calibration(url: str, *, wavelength_nm: float = 633.0,
                                 gain_db: float = 0.0, bits: int = 12) -> CameraCalibration:
    """The exact calibration of a ``simcam://`` camera (string entry point on the scheme)."""
    cam = sim_entry_point("simcam")(url)
    try:
        p = cam.sensor.params
        noise = DetectorNoise(p.system_gain(gain_db, bits), p.read_noise_e,
                              cam.sensor.saturation_dn(gain_db=gain_db, bits=bits),
                              p.dark_current_e_per_s)
        return CameraCalibration(noise, p.quantum_efficiency, wavelength_nm,
                                 cam.optics.aperture_diameter_mm, 0.0,
                                 source=f"simulated camera {url} (exact)",
                                 pixel_pitch_um=p.pixel_pitch_um,
                                 focal_length_mm=cam.optics.focal_length_mm,
                                 n_pixels=p.width * p.height,
                                 # a pinhole unless it integrates its pupil (the default)
                                 chief_ray_only=cam.optics.pupil == "chief",
                                 prnu_rel=p.prnu)
    finally:
        cam.close()


def camera_calibration_for(profile: dict[str, Any], *,
                           calibration_file: str | Path | None = None,
                           stored_file: str | Path | None = None,
                           gain_db: float = 0.0,
                           pixel_format: str | None = None) -> CameraCalibration:
    """The camera calibration of a bench: ``calibration_file`` if given, else the file a
    run recorded (``stored_file``), else the simulator's truth for a ``simcam://`` camera
    at ``gain_db`` and the bit depth of ``pixel_format`` (``MONO12`` …).

    Raises
    ------
    ValueError
        A real camera without a calibration file.
    """
    if calibration_file is not None:
        return CameraCalibration.from_json(calibration_file)
    if stored_file is not None:
        return CameraCalibration.from_json(stored_file)
    url = camera_url(profile)
    if url is None or not url.startswith("simcam://"):
        raise ValueError("the absolute camera method needs a camera calibration file "
                         "(--camera-calibration); or use the relative method")
    bits = 12
    if pixel_format and pixel_format.upper().startswith("MONO") and \
            pixel_format[4:].isdigit():
        bits = int(pixel_format[4:])
    wl = float(profile.get("simulation", {}).get("source", {}).get("wavelength_nm", 633.0))
    return simulated_camera_calibration(url, wavelength_nm=wl, gain_db=gain_db, bits=bits)
