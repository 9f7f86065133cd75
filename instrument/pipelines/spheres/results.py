"""Sphere-capture results in the run file: images, SH coefficients, relighting, the summary.

``/entry/analysis`` (NXprocess, replaced whole): ``results_json`` (:func:`summary`),
``images/`` (merged radiance, variance, validity per [lighting, object]), ``sh/`` (the
images' SH coefficients, the BRDF transfer γ_l, the estimated lighting) and ``relight/``
(the rendered and measured last image).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from instrument.pipelines.spheres.analyse import CONSISTENCY_LIMIT, SphereAnalysis
from instrument.pipelines.spheres.capture import SphereCapture
from instrument.run.results import open_for_results, replace_group
from instrument.run.runfile import as_text

__all__ = ["read_sphere_results", "summary", "write_sphere_analysis"]


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
            "calibration": "parametric bootstrap at the images' fit-residual level",
            "threshold_scale": result.threshold_scale,
            "limit": CONSISTENCY_LIMIT if result.threshold_scale == 1.0 else None,
        },
    }


def write_sphere_analysis(path: str | Path, capture: SphereCapture,
                          result: SphereAnalysis) -> None:
    """Write ``/entry/analysis`` (NXprocess, replacing an earlier analysis)."""
    with open_for_results(path) as f:
        g = replace_group(f["entry"], "analysis", "NXprocess")
        g.attrs["program"] = "scatterlab spheres"
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
    """The ``results_json`` a sphere analysis stored in a run file, or None."""
    with h5py.File(path, "r") as f:
        g = f.get("entry/analysis")
        if g is None or g.attrs.get("program") != "scatterlab spheres":
            return None
        raw = g["results_json"][()]
        return json.loads(as_text(raw))
