"""BRDF results: the reduced points, the fits and the chosen model, in HDF5 groups.

The results file ``DIR/RUN/fit/results.h5`` (ADR 0013) holds them under ``/entry/analysis``;
with ``--into-run`` the same group is written into the run file as well. The group (an
NXprocess, replaced whole by a new fit) holds ``reduced/`` (NXdata: the BRDF per point with
its uncertainty columns, angles in degrees, and which readings were clipped),
``provenance_json``, ``results_json`` (every fit, the selection table, the goodness-of-fit
verdicts and the checks,
:meth:`instrument.pipelines.brdf.analyse.AnalysisResult.to_dict`) and ``chosen/`` (the
chosen model's parameters, standard errors and covariance as arrays; its verdict,
χ², dof, p-value, the σ inflation factor and the disagreeing points, docs/decisions/0051).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from instrument.pipelines.brdf.reduce import Reduced
from instrument.run.paths import results_path
from instrument.run.results import (
    open_for_results,
    put,
    put_json,
    replace_group,
    write_results_file,
)

__all__ = ["fill_analysis", "write_analysis", "write_fit_results"]

PROGRAM = "scatterlab fit"


def fill_analysis(g: h5py.Group, reduced: Reduced, results: dict[str, Any]) -> None:
    """Fill an empty analysis group ``g`` (see the module docstring).

    ``results`` is plain data (``AnalysisResult.to_dict()``): stored as JSON text in
    ``results_json`` and, for the chosen model, as arrays under ``chosen/``.
    """
    pts = reduced.points
    g.attrs["NX_class"] = "NXprocess"
    g.attrs["program"] = PROGRAM
    g.attrs["method"] = pts.method
    g.attrs["cosine_corrected"] = pts.cosine_corrected
    g.attrs["u_scale_rel"] = pts.u_scale_rel
    g.attrs["references"] = ("Nicodemus et al. 1977 (NBS Monograph 160); ASTM E2387; "
                             "see analysis.brdf.reduction")
    red = replace_group(g, "reduced", "NXdata")
    red.attrs["signal"] = "brdf"
    for name in ("theta_i", "phi_i", "theta_r", "phi_r"):
        red.create_dataset(name, data=np.degrees(getattr(pts, name))).attrs["units"] = "deg"
    for name in ("brdf", "u_stat", "u_angle", "u_ref"):
        red.create_dataset(name, data=getattr(pts, name)).attrs["units"] = "1/sr"
    red.create_dataset("u_total", data=pts.u_total).attrs["units"] = "1/sr"
    red.create_dataset("point_index", data=reduced.rows)
    red.create_dataset("clipped", data=~pts.valid)
    if len(reduced.sources) > 1:  # a two-pass lobe run, reduced with its first pass
        red.create_dataset("source_run", data=np.array(
            [reduced.sources[k] for k in reduced.source], dtype=object),
            dtype=h5py.string_dtype())
    put(g, "provenance_json", json.dumps(reduced.provenance, default=str))
    put_json(g, "results_json", results)
    chosen = results.get("selection", {}).get("chosen")
    fits = results.get("fits", {})
    if chosen in fits:
        c = g.create_group("chosen")
        fit = fits[chosen]
        c.attrs["model"] = chosen
        # the goodness-of-fit gate (docs/decisions/0051): whether the model describes the
        # data, and the factor its σ were inflated by when it does not
        gof = results.get("goodness", {}).get(chosen)
        if gof is not None:
            c.attrs["model_adequate"] = bool(gof["adequate"])
            c.attrs["verdict"] = str(gof["verdict"])
            for key in ("chi2", "dof", "p_value", "expected_spread"):
                c.attrs[key] = gof[key]
            c.attrs["stderr_inflation"] = float(results.get("inflation", {}).get(chosen, 1.0))
            c.create_dataset("disagreeing_points",
                             data=np.asarray(gof["disagreeing_points"], dtype=int))
        for key in ("params", "stderr", "covariance"):
            c.create_dataset(key, data=np.asarray(fit[key], dtype=float))
        c.create_dataset("param_names", data=np.array(fit["param_names"], dtype=object),
                         dtype=h5py.string_dtype())


def write_fit_results(path: str | Path, reduced: Reduced, results: dict[str, Any], *,
                      run_id: str, options: Mapping[str, Any],
                      folder: str | Path | None = None) -> Path:
    """Write ``results.h5`` of the fit next to the run (or into ``folder``); returns its
    path. The run file is not touched."""
    with write_results_file(path, "fit", run_id=run_id, program=PROGRAM, options=options,
                            folder=folder) as g:
        fill_analysis(g, reduced, results)
    return results_path(path, "fit", folder)


def write_analysis(path: str | Path, reduced: Reduced, results: dict[str, Any]) -> None:
    """Write ``/entry/analysis`` into the run file itself (``--into-run``), replacing an
    earlier one."""
    with open_for_results(path) as f:
        fill_analysis(replace_group(f["entry"], "analysis", "NXprocess"), reduced, results)
