"""A polarimetric run file → Mueller matrices, decompositions, the pBRDF fit, the report
and the results file (what ``scatterlab fit`` does for a run with an optical train).

Steps: read and group the run (:mod:`~instrument.pipelines.polarimetry.readings`; a PEM
run's DC, 1f and 2f readings by :mod:`~instrument.pipelines.polarimetry.pem_readings`,
ADR 0106), choose the calibration of the run's polarimeter (a DRR's or a PEM's, ADR 0113;
:mod:`~instrument.pipelines.polarimetry.calibration`), reduce every geometry
(:mod:`~instrument.pipelines.polarimetry.reduce`), fit the pBRDF to every matrix with its
full covariance (the variant the data need,
:func:`analysis.polarimetry.pbrdf_selection.select_pbrdf`, ADR 0107, judged by the
goodness-of-fit gate of ADR 0051), draw the report
(:mod:`~instrument.pipelines.polarimetry.report`) and write ``results.h5``
(:mod:`~instrument.pipelines.polarimetry.results`), all under ``DIR/RUN/fit/`` next to the
run file ``DIR/RUN.h5`` (ADR 0013). The run file is only read.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis.brdf.reduction.receiver import ReceiverGeometry
from analysis.polarimetry.pbrdf import PBRDF_PARAMS, PbrdfFit, fit_pbrdf, pbrdf
from analysis.polarimetry.pbrdf_selection import PBRDF_VARIANTS, select_pbrdf
from analysis.polarimetry.validation import PolarimetryInputError
from instrument.pipelines.brdf.reduce import (
    ReductionOptions,
    first_pass_path,
    instrument_function,
)
from instrument.pipelines.polarimetry.calibration import (
    CalibrationError,
    PolarimeterCalibration,
    find_calibration,
    load_calibration,
)
from instrument.pipelines.polarimetry.readings import PolarimetricRun, read_polarimetric
from instrument.pipelines.polarimetry.reduce import (
    MuellerPoint,
    Scale,
    reduce_group,
    source_scale,
)
from instrument.pipelines.polarimetry.report import series, write_report
from instrument.pipelines.polarimetry.results import (
    write_into_run,
    write_polarimetric_results,
)
from instrument.run.paths import results_dir
from instrument.run.runfile import check_run_file

__all__ = ["DEFAULT_START", "UNCALIBRATED", "UNCALIBRATED_PEM", "PolarimetricFit",
           "PolarimetricReduction", "fit_polarimetric_run", "polarimetric_options",
           "receiver_geometry", "reduce_polarimetric"]

#: Start values (n, k, alpha, albedo, frame_deg) of the pBRDF fit: a rough dielectric in
#: the polarimeter's nominal frame.
DEFAULT_START = (1.5, 0.0, 0.2, 0.1, 0.0)

#: What the report and the console say when no calibration is used.
UNCALIBRATED = ("uncalibrated: Mueller elements may be biased by the polarimeter's own "
                "misalignment; run scatterlab calibrate polarimeter")
#: ... for a PEM run.
UNCALIBRATED_PEM = ("uncalibrated PEM run, reduced with the nominal optical train (DC, 1f "
                    "and 2f rows at the modulator's amplitude; the mounts' read-back "
                    "angles): elements may be biased by the train's own misalignment; run "
                    "scatterlab calibrate polarimeter on the PEM bench, or name a PEM "
                    "calibration with --calibration (pem=NAME in a batch of both modes)")


@dataclass(frozen=True)
class PolarimetricFit:
    """What :func:`fit_polarimetric_run` produced."""

    points: tuple[MuellerPoint, ...]
    summary: dict[str, Any]
    calibration: PolarimeterCalibration | None
    report: Path | None
    results: Path | None


def choose_calibration(path: str | Path, bench: str, calibration: str | Path | None,
                       mode: str = "drr") -> PolarimeterCalibration | None:
    """The calibration to use: ``"none"`` none, a file that one, else the newest valid
    one of the bench and the polarimeter ``mode`` beside the run (:func:`find_calibration`).

    Raises
    ------
    CalibrationError
        A named file that is not a usable calibration, or one of the other polarimeter
        mode (a DRR's for a PEM run or the reverse).
    """
    if calibration is None:
        return find_calibration(path, bench, mode)
    if str(calibration) == "none":
        return None
    cal = load_calibration(calibration)
    if cal.mode != mode:
        names = {"drr": "a dual rotating retarder", "pem": "a PEM polarimeter"}
        raise CalibrationError(f"{cal.path} calibrates {names[cal.mode]} (mode "
                               f"{cal.mode!r}); the run {path} is a {mode!r} run: name a "
                               f"calibration of its own mode, or --calibration none")
    return cal


def polarimetric_options(calibration: PolarimeterCalibration | None,
                         start: Sequence[float], fixed: Sequence[str] | None,
                         distribution: str) -> dict[str, Any]:
    """The options :func:`fit_polarimetric_run` records in ``results.h5`` (a batch compares
    them to tell whether a run is already done)."""
    used = "none" if calibration is None or calibration.path is None else str(
        calibration.path)
    return {"calibration": used, "start": [float(v) for v in start],
            "fixed": "select" if fixed is None else list(fixed),
            "distribution": distribution}


def receiver_geometry(prun: PolarimetricRun, scale: Scale
                      ) -> tuple[ReceiverGeometry | None, str]:
    """What each polarimetric reading integrated (the scalar fit's instrument function,
    :func:`instrument.pipelines.brdf.reduce.instrument_function`: the beam's footprint,
    the receiver's aperture, the axes' read-back spread) with the solid angle the
    reduction divided by, and that model in words. None where the beam's radius is
    unknown: the pBRDF is then fitted as a point receiver sees it, and the words say so."""
    rg, info = instrument_function(prun.run, np.zeros(0, dtype=int),
                                   ReductionOptions(detector="power_meter"))
    if rg is None:
        return None, ("point receiver at the nominal angles: the beam's radius is unknown "
                      f"({info['beam_radius_source']}); set [geometry] beam_radius_mm")
    rg = replace(rg, solid_angle_sr=scale.solid_angle_sr)
    return rg, (f"the pBRDF averaged over the beam's footprint (1/e² radius "
                f"{rg.beam_radius_mm:g} mm, {info['beam_radius_source']}) seen through the "
                f"{rg.aperture_diameter_mm:g} mm receiver at {rg.distance_mm:g} mm, in the "
                "receiver's frames")


def _pbrdf_fit(points: Sequence[MuellerPoint], start: Sequence[float],
               fixed: Sequence[str] | None, distribution: str,
               receiver: ReceiverGeometry | None = None) -> dict[str, Any] | None:
    """The pBRDF fit: with ``fixed`` None the variant the data need (ADR 0107), else the
    one model with those parameters held; ``receiver``: the finite receiver's model
    (:func:`analysis.polarimetry.pbrdf.pbrdf_on_receiver`), None a point receiver."""
    use = [p for p in points if p.brdf.normalised_valid and not p.group.transmitted]
    if not use:
        return None
    ang = [np.radians([getattr(p.group, name) for p in use])
           for name in ("theta_i", "phi_i", "theta_r", "phi_r")]
    m = np.array([p.brdf.m for p in use])
    cov = np.array([p.brdf.cov for p in use])
    selection: dict[str, Any] | None = None
    fit: PbrdfFit
    if fixed is None:
        sel = select_pbrdf(m, cov, *ang, start=start, distribution=distribution,
                           receiver=receiver)
        fit = sel.chosen_fit
        held = list(dict.fromkeys(PBRDF_VARIANTS[sel.chosen]))
        variant = sel.chosen
        selection = {"criterion": sel.criterion, "rule": sel.rule,
                     "table": [asdict(r) for r in sel.table]}
    else:
        fit = fit_pbrdf(m, cov, *ang, start=start, fixed=fixed, distribution=distribution,
                        receiver=receiver)
        held, variant = list(fixed), "fixed by the user"
    gof = fit.goodness
    return {"param_names": list(PBRDF_PARAMS), "params": fit.params.tolist(),
            "stderr": fit.sigma.tolist(), "covariance": fit.cov.tolist(),
            "fixed": held, "distribution": distribution, "variant": variant,
            "selection": selection,
            "adequate": bool(gof.adequate), "verdict": gof.verdict(), "chi2": gof.chi2,
            "dof": gof.dof, "p_value": gof.p_value,
            "receiver_level": -1 if fit.receiver_level is None else fit.receiver_level,
            "quadrature_error_sigma": fit.quadrature_error}


def _model_curves(points: Sequence[MuellerPoint], fit: dict[str, Any]
                  ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The fitted pBRDF along each series' θr range (for the grid figure)."""
    out = {}
    for label, pts in series(points).items():
        g0 = pts[0].group
        lo, hi = min(p.group.theta_r for p in pts), max(p.group.theta_r for p in pts)
        tr = np.linspace(lo - 2.0, hi + 2.0, 60) if hi > lo else np.array([lo])
        tr = np.clip(tr, 0.0, 89.0)
        f = pbrdf(fit["params"], math.radians(g0.theta_i), math.radians(g0.phi_i),
                  np.radians(tr), math.radians(g0.phi_r), distribution=fit["distribution"])
        out[label] = (tr, f)
    return out


@dataclass(frozen=True)
class PolarimetricReduction:
    """One run's Mueller matrices and what they were reduced with
    (:func:`reduce_polarimetric`)."""

    prun: PolarimetricRun
    calibration: PolarimeterCalibration | None
    scale: Scale
    points: tuple[MuellerPoint, ...]
    pem: bool
    notes: tuple[str, ...]


def reduce_polarimetric(path: str | Path, calibration: str | Path | None = None
                        ) -> PolarimetricReduction:
    """Read a polarimetric run and reduce every geometry to its Mueller matrix with
    covariance (``calibration`` as for :func:`fit_polarimetric_run`).

    Raises
    ------
    RunFileError
        Not a readable polarimetric run.
    CalibrationError
        A named calibration that cannot be used, one of another bench, or one of the other
        polarimeter mode (a DRR's for a PEM run, a PEM's for a DRR run).
    ValueError
        No readings, unknown noise or receiver geometry, or too few steps per geometry.
    """
    check_run_file(path, "fit")
    prun = read_polarimetric(path)
    bench = str(prun.run.profile().get("bench", {}).get("name", ""))
    pem = prun.polarimetry.get("mode") == "pem"
    cal = choose_calibration(path, bench, calibration, "pem" if pem else "drr")
    notes: list[str] = []
    if cal is not None and cal.bench != bench:
        raise CalibrationError(f"{cal.path} calibrates bench {cal.bench!r}, the run was "
                               f"taken on {bench!r}")
    if cal is not None and not cal.valid:
        notes.append(f"the calibration {cal.path} failed its quality gate ({cal.quality}); "
                     "used because it was named")
    scale = source_scale(prun, cal)
    points = []
    for g in prun.groups:
        try:
            points.append(reduce_group(prun, g, cal, scale))
        except PolarimetryInputError as err:
            raise ValueError(f"{g.label()}: {g.rows.size} steps do not determine the "
                             f"Mueller matrix ({err})") from None
    return PolarimetricReduction(prun, cal, scale, tuple(points), pem, tuple(notes))


def fit_polarimetric_run(path: str | Path, *, calibration: str | Path | None = None,
                         start: Sequence[float] = DEFAULT_START,
                         fixed: Sequence[str] | None = None, distribution: str = "beckmann",
                         report_dir: str | Path | None = None, report: bool = True,
                         write: bool = True, into_run: bool = False,
                         receiver_model: bool = True) -> PolarimetricFit:
    """Reduce a polarimetric run to Mueller matrices and fit the pBRDF (module docstring).

    ``calibration``: a calibration file, ``"none"`` for the nominal optics, or ``None``
    for the newest valid calibration of the run's bench beside the run. The second pass of
    a two-pass lobe plan (its plan's ``first_pass``) is fitted with its first pass's
    geometries, each run reduced with its own source scale. ``into_run`` also
    writes the results into the run file's ``/entry/analysis``. ``fixed`` None (the
    default) chooses the pBRDF variant the data need
    (:func:`analysis.polarimetry.pbrdf_selection.select_pbrdf`); a list of parameter
    names fits the one model with those held at ``start``. ``receiver_model`` fits the
    pBRDF as the finite receiver reads it (:func:`receiver_geometry`; False: a point
    receiver at the nominal angles, the model before ADR 0106's amendment "The pBRDF as
    the receiver reads it").

    Raises
    ------
    RunFileError, CalibrationError, ValueError
        As :func:`reduce_polarimetric`.
    """
    red = reduce_polarimetric(path, calibration)
    prun, cal, scale, notes = red.prun, red.calibration, red.scale, list(red.notes)
    pem = red.pem
    cal_text = ((UNCALIBRATED_PEM if pem else UNCALIBRATED) if cal is None else
                f"calibrated with {cal.path} ({cal.date}): {cal.describe()}")
    points = list(red.points)
    first = first_pass_path(prun.run)
    if first is not None:
        # the second pass of a two-pass lobe plan: both runs' geometries are fitted
        # together (as reduce_run joins a scalar first pass), each with its own scale
        red1 = reduce_polarimetric(first, calibration)
        points = list(red1.points) + points
        notes.append(f"with the first pass {red1.prun.run.run_id} ({len(red1.points)} "
                     f"geometries, {first.name}) of the two-pass lobe plan")
    flagged = [p.group.label() for p in points if p.realizability.flagged]
    if flagged:
        notes.append(f"not physically realizable within σ (kept as measured, not "
                     f"projected): {', '.join(flagged)}")
    if any(p.group.transmitted for p in points):
        notes.append("straight-through groups (detector arm in the beam) are transmittance "
                     "matrices (unitless), not BRDFs, and are left out of the pBRDF fit")
    notes.append("m00 in 1/sr through the source scale " + scale.source
                 + " and the receiver's solid angle (point receiver); m_ij/m00 does not "
                 "depend on either")
    receiver, receiver_text = (receiver_geometry(prun, scale) if receiver_model else
                               (None, "point receiver at the nominal angles (as asked)"))
    notes.append("pBRDF model: " + receiver_text)
    fit = _pbrdf_fit(points, start, fixed, distribution, receiver)
    summary: dict[str, Any] = {
        "calibrated": cal is not None,
        "calibration": "" if cal is None or cal.path is None else str(cal.path),
        "calibration_text": cal_text, "scale_source": scale.source,
        "source_scale_w": scale.source_w, "solid_angle_sr": scale.solid_angle_sr,
        "noise": prun.noise_source, "notes": notes, "pbrdf": fit,
        "pbrdf_receiver": receiver_text,
    }
    folder = Path(report_dir) if report_dir is not None else results_dir(path, "fit")
    run = prun.run
    page = None
    if report:
        page = write_report(folder, points,
                            title=f"Mueller-matrix BRDF of {run.sample_name or run.run_id} "
                            f"(run {run.run_id})", summary=summary,
                            model=_model_curves(points, fit) if fit else None)
    saved = None
    if write:
        options = polarimetric_options(cal, start, fixed, distribution)
        saved = write_polarimetric_results(path, points, summary, run_id=run.run_id,
                                           options=options, folder=folder)
    if into_run:
        write_into_run(path, points, summary)
    return PolarimetricFit(points=tuple(points), summary=summary, calibration=cal,
                           report=page, results=saved)
