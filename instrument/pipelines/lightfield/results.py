"""Light-field results: what a reconstruction and a localisation produced, and their storage.

Results go into the results file ``DIR/RUN/lightfield/results.h5`` next to the run file
``DIR/RUN.h5`` (ADR 0013) — into the run file itself only with ``--into-run`` — under
``/entry/analysis/lightfield`` (an ``NXprocess``). A reconstruction writes a new results
file; a localisation writes one holding the stored reconstruction and its own group::

    measured/        radiance (N_y, N_θ), y_mm, theta_rad, cell_pixels (N_θ,) ; attrs
                     units, domain_rad, sigma_rows (noise of one cell from the row spread)
    reconstruction/  incident_radiance (R, N_θ), points_mm, theta_rad, filter_factors,
                     orders, signal_power, noise_power, gamma, snr_eff, delta_p,
                     valid_fraction ; attrs method, parameter_name, parameter,
                     effective_dof, residual_ratio, recoverable, message, solver, p_hat,
                     solvable_domain_rad, noise_sigma, noise_method
    localisation/    positions_mm (K, 2), brightness_rp, brightness_conventional,
                     transverse_mm, depth_mm, depth_profiles (K, N_z), stack_y_mm,
                     stack_z_mm, stack_conventional, stack_rp, depth_interval_mm (K, 2)
                     with depth_interval_open (K, 2) (an open end is the search edge, not
                     a measured bound), across_interval_mm (K, 2) (the y bounds the data
                     allow), significance (K,) in σ, false_alarm (K,) per scan,
                     below_positions_mm (M, 2), below_significance (M,) (candidates that
                     did not clear the threshold) ; attrs count, p_hat, threshold_sigma,
                     resolution_cells, saturated_points, notes
    attrs: program, version, date, geometry (JSON), brdf (JSON)
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import h5py
import numpy as np
from numpy.typing import NDArray

from analysis.lightfield import (
    Detection,
    FlatlandBRDF,
    Reconstruction,
)
from instrument.pipelines.lightfield.geometry import LightFieldGeometry
from instrument.pipelines.lightfield.scan import Assembled
from instrument.run.paths import results_path
from instrument.run.results import (
    analysis_group,
    open_for_results,
    replace_group,
    write_results_file,
)
from instrument.run.runfile import as_text
from instrument.version import software_version

__all__ = [
    "GROUP",
    "LocalisationResult",
    "ReconstructionResult",
    "median_delta_p",
    "read_reconstruction",
    "stored_options",
    "write_localisation",
    "write_reconstruction",
]


GROUP = "entry/analysis/lightfield"
PROGRAM = {"reconstruct": "scatterlab reconstruct", "locate": "scatterlab locate"}


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


def _brdf_dict(b: FlatlandBRDF) -> dict[str, Any]:
    return {"name": b.name, "specular_reflectance": b.specular_reflectance,
            "specular_width_rad": b.specular_width_rad,
            "diffuse_reflectance": b.diffuse_reflectance,
            "window_exponent": b.window_exponent}


def write_reconstruction(path: str | Path, r: ReconstructionResult, *, run_id: str = "",
                         options: dict[str, Any] | None = None,
                         folder: str | Path | None = None, into_run: bool = False) -> Path:
    """Store a reconstruction: a new results file (in ``folder``, default
    ``DIR/RUN/lightfield/``), whose earlier localisation it makes stale; with ``into_run``
    in the run file instead. Returns the file written."""
    if into_run:
        with open_for_results(path) as f:
            _fill_reconstruction(analysis_group(f, "lightfield"), r)
        return Path(path)
    with write_results_file(path, "lightfield", run_id=run_id, program=PROGRAM["reconstruct"],
                            options={"reconstruct": options or {}}, folder=folder) as g:
        _fill_reconstruction(analysis_group(g.file, "lightfield"), r)
    return results_path(path, "lightfield", folder)


def _fill_reconstruction(g: h5py.Group, r: ReconstructionResult) -> None:
    rec = r.reconstruction
    reg = rec.regularization
    diag = rec.diagnostics
    lf = r.measured.field
    g.attrs["program"] = PROGRAM["reconstruct"]
    g.attrs["version"] = software_version()
    g.attrs["date"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    g.attrs["geometry"] = json.dumps(r.geometry.as_dict())
    g.attrs["brdf"] = json.dumps(_brdf_dict(r.brdf))
    g.attrs["notes"] = json.dumps(list(r.notes))
    m = replace_group(g, "measured", "NXdata")
    m["radiance"] = lf.radiance
    m["radiance"].attrs["units"] = "DN/us (cos^4-corrected, proportional to radiance)"
    m["y_mm"] = lf.y_mm
    m["theta_rad"] = lf.theta_rad
    m["cell_pixels"] = r.measured.cell_pixels
    m.attrs["domain_rad"] = lf.domain_rad
    m.attrs["d2_mm"] = lf.z_mm
    m.attrs["sigma_rows"] = r.measured.sigma_rows
    m.attrs["signal"] = "radiance"
    c = replace_group(g, "reconstruction", "NXdata")
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


def read_reconstruction(path: str | Path) -> dict[str, Any] | None:
    """The reconstruction stored in ``path`` (a light-field results file, or a run file
    analysed ``--into-run``), or None when it holds none."""
    if not Path(path).is_file():
        return None
    with h5py.File(path, "r") as f:
        if f"{GROUP}/reconstruction" not in f:
            return None
        c = f[f"{GROUP}/reconstruction"]
        g = f[GROUP]
        out = {k: c[k][()] for k in ("incident_radiance", "points_mm", "theta_rad",
                                     "filter_factors", "orders", "noise_power")}
        out.update({k: c.attrs[k] for k in ("p_hat", "solvable_domain_rad", "domain_rad",
                                            "recoverable", "message")})
        out["geometry"] = json.loads(as_text(g.attrs["geometry"]))
        out["notes"] = tuple(json.loads(as_text(g.attrs.get("notes", "[]"))))
    return out


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


#: How :mod:`.scan` notes a point whose every exposure saturated.
SATURATED_NOTE = "every exposure saturated"


def saturated_points(notes: tuple[str, ...]) -> int:
    """How many scan points the notes say were saturated in every exposure."""
    return sum(SATURATED_NOTE in n for n in notes)


def stored_options(path: str | Path) -> dict[str, Any]:
    """The options recorded in a light-field results file (``{}`` when none)."""
    if not Path(path).is_file():
        return {}
    try:
        with h5py.File(path, "r") as f:
            # a JSON object: written by this module
            return cast(dict[str, Any],
                        json.loads(as_text(f["entry"].attrs.get("options_json", "{}"))))
    except (OSError, KeyError, ValueError):
        return {}


def write_localisation(path: str | Path, det: Detection, p_hat: float, message: str, *,
                       run_id: str = "", options: dict[str, Any] | None = None,
                       folder: str | Path | None = None, into_run: bool = False) -> Path:
    """Store a localisation. In a results file (in ``folder``, default
    ``DIR/RUN/lightfield/``): a new file holding the reconstruction it was made from
    (copied from the current results file) and the localisation; with ``into_run`` in the
    run file next to its reconstruction. Returns the file written."""
    if into_run:
        with open_for_results(path) as f:
            _fill_localisation(analysis_group(f, "lightfield"), det, p_hat, message)
        return Path(path)
    old = results_path(path, "lightfield", folder)
    recorded = {"reconstruct": stored_options(old).get("reconstruct", {}),
                "locate": options or {}}
    with write_results_file(path, "lightfield", run_id=run_id, program=PROGRAM["locate"],
                            options=recorded, folder=folder) as g:
        lf = analysis_group(g.file, "lightfield")
        if old.is_file():
            with h5py.File(old, "r") as src:
                if GROUP in src:
                    for key, value in src[GROUP].attrs.items():
                        lf.attrs[key] = value
                    for name in ("measured", "reconstruction"):
                        if name in src[GROUP]:
                            src.copy(src[GROUP][name], lf, name)
        _fill_localisation(lf, det, p_hat, message)
    return old


def _fill_localisation(g: h5py.Group, det: Detection, p_hat: float, message: str) -> None:
    loc = replace_group(g, "localisation", "NXdata")
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
    loc["depth_interval_open"] = det.depth_open
    loc["depth_interval_open"].attrs["columns"] = "far_open, near_open"
    # the y bounds the data allow (a near-threshold object's position region, ADR 0109)
    across = (det.across_interval_mm if det.across_interval_mm.shape[0] == det.count
              else np.repeat(det.positions_mm[:, :1], 2, axis=1))
    loc["across_interval_mm"] = across
    loc["across_interval_mm"].attrs["columns"] = "low_mm, high_mm"
    loc["quality"] = np.array(det.quality, dtype=h5py.string_dtype())
    # how far each object stands out of the noise, and what did not (never dropped silently)
    loc["extent_mm"] = det.extent_mm
    loc["extent_mm"].attrs["columns"] = "across_mm, depth_mm"
    loc["significance"] = det.significance
    loc["significance"].attrs["units"] = "standard deviations"
    loc["false_alarm"] = det.false_alarm
    loc["below_positions_mm"] = det.below_positions_mm
    loc["below_positions_mm"].attrs["columns"] = "y_mm, z_mm"
    loc["below_significance"] = det.below_significance
    loc["stack_y_mm"] = det.stack.y_mm
    loc["stack_z_mm"] = det.stack.z_mm
    loc["stack_conventional"] = det.stack.conventional
    loc["stack_rp"] = det.stack.radiance_preserving
    loc.attrs.update({"count": det.count, "p_hat": p_hat, "message": message,
                      "saturated_points": saturated_points(det.notes),
                      "signal": "stack_rp", "threshold_sigma": det.threshold_sigma,
                      "resolution_cells": det.resolution_cells,
                      "notes": json.dumps(list(det.notes))})
