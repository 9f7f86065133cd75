"""The polarimetric fit's results in ``DIR/RUN/fit/results.h5`` under ``/entry/analysis``.

The group (NXprocess, ``program = "scatterlab fit"``, ``kind = "polarimetric"``) holds:

* attributes ``calibrated``, ``calibration`` (the file used, or ``""``),
  ``calibration_text``, ``scale_source``, ``source_scale_w``, ``solid_angle_sr``;
* ``mueller/`` (NXdata, one row per geometry): ``theta_i``, ``phi_i``, ``theta_r``,
  ``phi_r`` (deg), ``wavelength_nm``, ``m`` (N, 4, 4, 1/sr), ``covariance`` (N, 16, 16,
  row-major vec), ``sigma``, ``m_normalised`` and ``sigma_normalised`` (m_ij/m00), ``chi2``,
  ``dof``, ``condition_number``, ``steps``;
* ``decomposition/``: ``params`` and ``sigma`` (N, 5; names in ``param_names``: m00, D,
  R in rad, retardance axis in deg, Δ), ``valid`` and ``note`` (why a matrix has none);
* ``realizability/``: ``eigenvalues`` and ``sigma`` (N, 4) of the coherency matrix,
  ``p_value``, ``flagged`` (flagged matrices are kept as measured, never projected);
* ``pbrdf/`` (when fitted): ``params``, ``stderr``, ``covariance``, ``param_names``
  (n, k, alpha, albedo, frame_deg), ``fixed``; attributes ``distribution``, ``variant``
  (the chosen variant, ADR 0107), the goodness-of-fit gate's ``adequate``, ``verdict``,
  ``chi2``, ``dof``, ``p_value``; ``selection_json`` (criterion, rule and every
  variant's scores) when the variant was chosen from the data.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from analysis.polarimetry.decomposition import PARAMETERS
from instrument.pipelines.polarimetry.reduce import MuellerPoint
from instrument.run.paths import results_path
from instrument.run.results import (
    open_for_results,
    put_json,
    replace_group,
    write_results_file,
)

__all__ = ["PROGRAM", "write_into_run", "write_polarimetric_results"]

PROGRAM = "scatterlab fit"


def _strings(g: h5py.Group, name: str, values: Sequence[str]) -> None:
    g.create_dataset(name, data=np.array(list(values), dtype=object),
                     dtype=h5py.string_dtype())


def fill(g: h5py.Group, points: Sequence[MuellerPoint], summary: Mapping[str, Any]) -> None:
    """Fill the analysis group (module docstring)."""
    g.attrs["NX_class"] = "NXprocess"
    g.attrs["program"] = PROGRAM
    g.attrs["kind"] = "polarimetric"
    for key in ("calibrated", "calibration", "calibration_text", "scale_source",
                "source_scale_w", "solid_angle_sr"):
        g.attrs[key] = summary[key]
    g.attrs["references"] = ("Goldstein 1992 (Appl. Opt. 31, 6676); Lu & Chipman 1996 "
                             "(JOSA A 13, 1106); Cloude 1986; Priest & Germer 2000")
    m = g.create_group("mueller")
    m.attrs["NX_class"] = "NXdata"
    m.attrs["signal"] = "m"
    for name in ("theta_i", "phi_i", "theta_r", "phi_r"):
        m.create_dataset(name, data=[getattr(p.group, name) for p in points]
                         ).attrs["units"] = "deg"
    m.create_dataset("wavelength_nm", data=[p.group.wavelength_nm for p in points]
                     ).attrs["units"] = "nm"
    for name, attr, unit in (("m", "m", "1/sr"), ("covariance", "cov", "1/sr^2"),
                             ("sigma", "sigma", "1/sr"), ("m_normalised", "m_normalised", "1"),
                             ("sigma_normalised", "sigma_normalised", "1")):
        m.create_dataset(name, data=np.array([getattr(p.brdf, attr) for p in points])
                         ).attrs["units"] = unit
    m.create_dataset("chi2", data=[p.brdf.chi2 for p in points])
    m.create_dataset("dof", data=[p.brdf.dof for p in points])
    m.create_dataset("condition_number", data=[p.condition for p in points])
    m.create_dataset("steps", data=[p.group.rows.size for p in points])
    d = g.create_group("decomposition")
    _strings(d, "param_names", PARAMETERS)
    nan5 = np.full(5, np.nan)
    d.create_dataset("params", data=np.array(
        [p.decomposition.params if p.decomposition else nan5 for p in points]))
    d.create_dataset("sigma", data=np.array(
        [p.decomposition.sigma if p.decomposition and p.decomposition.sigma is not None
         else nan5 for p in points]))
    d.create_dataset("valid", data=[p.decomposition is not None for p in points])
    _strings(d, "note", [p.decomposition_note for p in points])
    r = g.create_group("realizability")
    r.create_dataset("eigenvalues", data=np.array([p.realizability.eigenvalues
                                                   for p in points]))
    r.create_dataset("sigma", data=np.array([p.realizability.sigma for p in points]))
    r.create_dataset("p_value", data=[p.realizability.p_value for p in points])
    r.create_dataset("flagged", data=[p.realizability.flagged for p in points])
    fit = summary.get("pbrdf")
    if fit is not None:
        f = g.create_group("pbrdf")
        _strings(f, "param_names", fit["param_names"])
        _strings(f, "fixed", fit["fixed"])
        for key in ("params", "stderr", "covariance"):
            f.create_dataset(key, data=np.asarray(fit[key], dtype=float))
        for key in ("distribution", "adequate", "verdict", "chi2", "dof", "p_value",
                    "variant"):
            f.attrs[key] = fit[key]
        # the forward model: the finite receiver's quadrature level (−1: point receiver)
        # and its error bound in σ (ADR 0106, amendment "The pBRDF as the receiver reads it")
        for key in ("receiver_level", "quadrature_error_sigma"):
            if key in fit:
                f.attrs[key] = fit[key]
        if "pbrdf_receiver" in summary:
            f.attrs["receiver_model"] = summary["pbrdf_receiver"]
        if fit.get("selection"):
            put_json(f, "selection_json", fit["selection"])
    put_json(g, "summary_json", dict(summary))


def write_polarimetric_results(path: str | Path, points: Sequence[MuellerPoint],
                               summary: Mapping[str, Any], *, run_id: str,
                               options: Mapping[str, Any],
                               folder: str | Path | None = None) -> Path:
    """Write ``results.h5`` next to the run (or into ``folder``); returns its path."""
    with write_results_file(path, "fit", run_id=run_id, program=PROGRAM, options=options,
                            folder=folder) as g:
        fill(g, points, summary)
    return results_path(path, "fit", folder)


def write_into_run(path: str | Path, points: Sequence[MuellerPoint],
                   summary: Mapping[str, Any]) -> None:
    """Write ``/entry/analysis`` into the run file itself (``--into-run``), replacing an
    earlier one."""
    with open_for_results(path) as f:
        fill(replace_group(f["entry"], "analysis", "NXprocess"), points, summary)
