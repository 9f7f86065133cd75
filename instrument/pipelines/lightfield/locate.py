"""Localisation of the hidden objects of a light-field run from its reconstruction.

:func:`locate_run` refocuses the stored reconstruction over a (y, z) grid and detects the
objects (:func:`analysis.lightfield.detect_objects`: focal stack, radiance-preserving
refocusing, depth filter, iterative subtraction of point responses) with their theoretical
resolution.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis.lightfield import (
    LightField2D,
    at_far_edge,
    detect_objects,
    detect_widening,
    theoretical_resolution,
)
from instrument.pipelines.lightfield.figures import localisation_figures
from instrument.pipelines.lightfield.reconstruct import reconstruct_run
from instrument.pipelines.lightfield.results import (
    LocalisationResult,
    read_reconstruction,
    saturated_points,
    write_localisation,
)
from instrument.run.paths import results_path
from instrument.run.runfile import as_text, check_run_file, read_summary

__all__ = ["locate_options", "locate_run", "resolution_at"]


def locate_options(*, y_range_mm: tuple[float, float] | None = None,
                   z_range_mm: tuple[float, float] = (-400.0, -60.0), y_step_mm: float = 0.5,
                   z_step_mm: float = 1.0, false_alarm: float = 0.01,
                   min_measure_fraction: float = 0.1) -> dict[str, Any]:
    """The options of :func:`locate_run` that change its result (besides the
    reconstruction's), as recorded in the results file."""
    return {"y_range_mm": None if y_range_mm is None else list(y_range_mm),
            "z_range_mm": list(z_range_mm), "y_step_mm": y_step_mm, "z_step_mm": z_step_mm,
            "false_alarm": false_alarm, "min_measure_fraction": min_measure_fraction}


def locate_run(
    path: str | Path,
    *,
    y_range_mm: tuple[float, float] | None = None,
    z_range_mm: tuple[float, float] = (-400.0, -60.0),
    y_step_mm: float = 0.5,
    z_step_mm: float = 1.0,
    false_alarm: float = 0.01,
    min_measure_fraction: float = 0.1,
    write: bool = True,
    figures_dir: str | Path | None = None,
    out_dir: str | Path | None = None,
    into_run: bool = False,
    **reconstruct_options: Any,
) -> LocalisationResult:
    """Locate the hidden objects of a light-field run (reconstructing it first if needed).

    The trial grid covers ``y_range_mm`` (default: the reconstructed wall points ± 60 mm)
    and ``z_range_mm`` (z < 0, in front of the wall, unfolded).  Trial points seen through
    less than ``min_measure_fraction`` of the solvable angle domain are not searched: a
    light-field bench's wall aperture W limits that fraction to about
    ``W / (|z| (B − A))``, so the default is lower than the analysis default (0.25), which
    would hide everything beyond ~230 mm on the 100 mm emulated stage.  ``false_alarm``:
    the probability per scan that noise alone yields a reported object; each object carries
    its significance (σ) from the reconstruction's noise model, and the candidates below
    the threshold are counted (:func:`analysis.lightfield.detect_objects`).  Points the
    scan saturated in every exposure are counted into the message: their brightness is
    clipped, so brightness is underestimated (positions are not affected).

    The reconstruction is read from the light-field results file (in ``out_dir``, default
    ``DIR/RUN/lightfield/``) and made there first when it holds none or
    ``reconstruct_options`` are given. Results go to
    ``/entry/analysis/lightfield/localisation`` of the same file (with ``into_run``, of
    the run file as well).
    """
    check_run_file(path, "locate")
    store = results_path(path, "lightfield", out_dir)
    for name, rng in (("y_range_mm", y_range_mm), ("z_range_mm", z_range_mm)):
        if rng is not None and not (len(rng) == 2 and float(rng[0]) < float(rng[1])):
            raise ValueError(f"{name} {tuple(rng)} must be (low, high) with low < high (mm)")
    if not 0.0 < false_alarm < 1.0:
        raise ValueError(f"false_alarm {false_alarm:g} must be in (0, 1): the probability "
                         f"per scan that noise alone gives a reported object")
    stored = None if reconstruct_options else read_reconstruction(store)
    if stored is None:
        reconstruct_run(path, write=True, out_dir=out_dir, into_run=into_run,
                        **reconstruct_options)
        stored = read_reconstruction(store)
        if stored is None:  # pragma: no cover - written just above
            raise RuntimeError("the reconstruction was not stored")
    dom = tuple(float(x) for x in stored["domain_rad"])
    # dom has two entries (the stored domain's ends); mypy sees a tuple of any length
    field_ = LightField2D(stored["incident_radiance"], stored["points_mm"],
                          stored["theta_rad"], dom, 0.0)  # type: ignore[arg-type]
    p_hat = float(stored["p_hat"])
    pts = stored["points_mm"]
    y_lo, y_hi = y_range_mm or (float(pts[0]) - 60.0, float(pts[-1]) + 60.0)
    ys = np.arange(y_lo, y_hi + 0.5 * y_step_mm, y_step_mm)
    zs = np.arange(z_range_mm[0], z_range_mm[1] + 0.5 * z_step_mm, z_step_mm)
    if np.any(zs >= 0):
        raise ValueError("z_range_mm must lie in front of the wall (z < 0)")
    solvable = tuple(float(x) for x in stored["solvable_domain_rad"])
    recoverable = bool(stored["recoverable"])
    if recoverable:
        det, searched = detect_widening(
            field_, z_mm=zs, p_max=p_hat, y_mm=ys,
            solvable_domain_rad=solvable, filter_factors=stored["filter_factors"],
            noise_power=stored["noise_power"], false_alarm=false_alarm,
            min_measure_fraction=min_measure_fraction)
        message = (f"{det.count} object(s) found above {det.threshold_sigma:.1f}σ (false-alarm "
                   f"probability {false_alarm:g} per scan: the search's tail is that of "
                   f"{det.resolution_cells:.0f} independent trials; highest recovered angular "
                   f"order {p_hat:g})")
        if searched[0] < zs[0]:
            message += (f"; the depth range was widened to {searched[0]:.0f} mm: an object sat "
                        f"at its far end ({zs[0]:.0f} mm)")
        if det.count and at_far_edge(det, float(searched[0])).any():
            message += (f"; an object still sits at the far end ({searched[0]:.0f} mm): it may "
                        f"lie beyond, widen --z-range")
        if det.below_significance.size:
            yb, zb = det.below_positions_mm[0]
            message += (f"; {det.below_significance.size} more candidate(s) below the "
                        f"threshold, the strongest at y = {yb:.1f}, z = {zb:.1f} mm "
                        f"({det.below_significance[0]:.1f}σ)")
        for note in det.notes:
            message += f"; {note}"
    else:
        # solvable: two angles, as above
        det = detect_objects(field_, p_max=0.0, y_mm=ys, z_mm=zs,
                             solvable_domain_rad=solvable,  # type: ignore[arg-type]
                             max_objects=0)
        message = f"nothing located: {as_text(stored['message'])}"
    n_sat = saturated_points(tuple(stored["notes"]))
    if n_sat:
        message += (f"; {n_sat} scan point(s) saturated in every exposure: brightness is "
                    f"underestimated (clipped), positions are not affected — shorten the "
                    f"exposure")
    det = replace(det, notes=det.notes + tuple(stored["notes"]))
    if write:
        write_localisation(path, det, p_hat, message, run_id=read_summary(path).run_id,
                           options=locate_options(
                               y_range_mm=y_range_mm, z_range_mm=z_range_mm,
                               y_step_mm=y_step_mm, z_step_mm=z_step_mm,
                               false_alarm=false_alarm,
                               min_measure_fraction=min_measure_fraction),
                           folder=out_dir)
    if into_run:
        write_localisation(path, det, p_hat, message, into_run=True)
    figs: tuple[Path, ...] = ()
    if figures_dir is not None:
        figs = tuple(localisation_figures(det, p_hat, figures_dir))
    return LocalisationResult(det, p_hat, recoverable, message, figs)


def resolution_at(p_hat: float, depth_mm: float, *, domain_rad: tuple[float, float],
                  aperture_mm: float,
                  solvable_domain_rad: tuple[float, float] | None = None) -> tuple[float, float]:
    """(transverse, depth) theoretical blur in mm for an object ``depth_mm`` from the wall
    (:func:`analysis.lightfield.theoretical_resolution`)."""
    r = theoretical_resolution(p_hat, domain_rad=domain_rad, distance_mm=abs(depth_mm),
                               aperture_mm=aperture_mm, solvable_domain_rad=solvable_domain_rad)
    return r.transverse_mm, r.depth_mm
