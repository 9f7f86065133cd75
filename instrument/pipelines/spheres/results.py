"""Sphere-capture results: images, SH coefficients, relighting, the summary.

The results file ``DIR/RUN/spheres/results.h5`` (ADR 0013) holds them under
``/entry/analysis``; with ``--into-run`` the same group goes into the run file as well.
``/entry/analysis`` (NXprocess, replaced whole): ``results_json`` (:func:`summary`),
``images/`` (merged radiance, variance, validity per [lighting, object]), ``sh/`` (the
images' SH coefficients, the BRDF transfer γ_l, the estimated lighting) and ``relight/``
(the rendered and measured last image).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, cast

import h5py
import numpy as np

from instrument.pipelines.spheres.analyse import CONSISTENCY_LIMIT, SphereAnalysis
from instrument.pipelines.spheres.capture import SphereCapture
from instrument.run.paths import results_path
from instrument.run.results import open_for_results, replace_group, write_results_file
from instrument.run.runfile import as_text

__all__ = ["fill_sphere_analysis", "read_sphere_results", "summary", "write_sphere_analysis",
           "write_sphere_results"]

PROGRAM = "scatterlab spheres"


def summary(capture: SphereCapture, result: SphereAnalysis) -> dict[str, Any]:
    """Plain-data summary of an analysis (what ``results_json`` and the CLI report)."""
    rep = result.consistency
    return {
        "objects": list(capture.objects),
        "lighting_deg": list(capture.lighting_deg),
        "lighting_role": capture.lighting_role,
        "selector": capture.selector,
        "units": capture.units,
        "lmax": result.lmax,
        "center_px": list(result.center),
        "radius_px": result.radius,
        "relight": {
            "target": {"lighting_deg": capture.lighting_deg[-1], "object": capture.objects[-1]},
            "route": "brdf",
            "l1_error": result.relight_l1,
            "n_pixels": int(result.observed.sum()),
        },
        "gamma": result.gamma.tolist(),
        "identities": {name: {"orders": e.orders.tolist(), "error": e.error.tolist(),
                              "defined": e.defined.tolist()}
                       for name, e in result.identities.items()},
        "lighting_object": result.lighting_object,
        "consistency": {
            "identity": "M21",
            "orders": rep.orders.tolist(),
            "error": rep.error.tolist(),
            "noise_error": rep.noise_error.tolist(),
            "z": rep.z.tolist(),
            "statistic": rep.statistic,
            "threshold": rep.threshold,
            "false_alarm": rep.false_alarm,
            "inconsistent": bool(rep.inconsistent),
            "verdict": rep.verdict,
            "no_test_reason": rep.no_test_reason,
            "calibration": "parametric bootstrap at the images' fit-residual level",
            "threshold_scale": result.threshold_scale,
            "limit": CONSISTENCY_LIMIT if result.threshold_scale == 1.0 else None,
        },
    }


def write_sphere_results(path: str | Path, capture: SphereCapture, result: SphereAnalysis,
                         *, run_id: str, options: dict[str, Any],
                         folder: str | Path | None = None) -> Path:
    """Write ``results.h5`` of the sphere analysis next to the run (or into ``folder``);
    returns its path. The run file is not touched."""
    with write_results_file(path, "spheres", run_id=run_id, program=PROGRAM, options=options,
                            folder=folder) as g:
        fill_sphere_analysis(g, capture, result)
    return results_path(path, "spheres", folder)


def write_sphere_analysis(path: str | Path, capture: SphereCapture,
                          result: SphereAnalysis) -> None:
    """Write ``/entry/analysis`` into the run file itself (``--into-run``), replacing an
    earlier analysis."""
    with open_for_results(path) as f:
        fill_sphere_analysis(replace_group(f["entry"], "analysis", "NXprocess"), capture,
                             result)


def fill_sphere_analysis(g: h5py.Group, capture: SphereCapture,
                         result: SphereAnalysis) -> None:
    """Fill an empty analysis group ``g`` (module docstring)."""
    g.attrs["NX_class"] = "NXprocess"
    g.attrs["program"] = PROGRAM
    g.attrs["references"] = ("Ramamoorthi & Hanrahan 2001; Mahajan, Ramamoorthi & "
                             "Curless, ECCV 2006 / PAMI 2008 (identities: their eqs. 10-25)")
    g.create_dataset("results_json", data=json.dumps(summary(capture, result)),
                     dtype=h5py.string_dtype())
    img = replace_group(g, "images", "NXdata")
    img.attrs["signal"] = "radiance"
    img.attrs["axes_order"] = "lighting, object, row, column"
    img.create_dataset("radiance", data=capture.radiance, compression="gzip")
    img["radiance"].attrs["units"] = capture.units
    img.create_dataset("variance", data=capture.variance, compression="gzip")
    img.create_dataset("valid", data=capture.valid, compression="gzip")
    img.create_dataset("point_row", data=capture.rows)
    img.create_dataset("lighting_deg", data=np.array(capture.lighting_deg))
    img.create_dataset("objects", data=np.array(capture.objects, dtype=object),
                       dtype=h5py.string_dtype())
    sh = replace_group(g, "sh", "NXdata")
    sh.attrs["convention"] = ("real orthonormal, Condon-Shortley phase, theta colatitude "
                              "from +z (towards the camera); docs/decisions/0040")
    sh.create_dataset("coeffs", data=result.coeffs)
    sh.create_dataset("gamma", data=result.gamma)
    if result.lighting is not None:
        sh.create_dataset("lighting", data=result.lighting)
        sh["lighting"].attrs["from_object"] = str(result.lighting_object)
    rel = replace_group(g, "relight", "NXdata")
    rel.attrs["signal"] = "predicted"
    rel.create_dataset("predicted", data=result.predicted)
    rel.create_dataset("measured", data=result.measured)
    rel.create_dataset("observed", data=result.observed)
    rel.attrs["l1_error"] = result.relight_l1


def read_sphere_results(path: str | Path) -> dict[str, Any] | None:
    """The ``results_json`` of a sphere analysis in ``path`` (its results file, or a run
    file analysed ``--into-run``), or None."""
    if not Path(path).is_file():
        return None
    with h5py.File(path, "r") as f:
        g = f.get("entry/analysis")
        if g is None or g.attrs.get("program") != PROGRAM:
            return None
        raw = g["results_json"][()]
        return cast(dict[str, Any], json.loads(as_text(raw)))  # a JSON object: written here
