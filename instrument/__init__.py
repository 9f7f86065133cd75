"""scatterlab's instrument layer, and the public facade for scripts and notebooks::

    from instrument import open_bench, plans, open_run, fit

    with open_bench("sim") as bench:
        run = bench.run(plans.in_plane(theta_i=[20, 40], theta_r=range(-70, 81, 5),
                                       sample="grey paint")).result()
    ds = run.to_xarray()          # the reduced BRDF with θ, φ coordinates and σ
    result = fit(run.path)        # what `scatterlab fit` does, as objects

The names below are the supported surface (the user guide's chapter "Scripting scans in
Python"); they are loaded on first use, so importing a sub-package stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Public name → the module that defines it.
_FACADE = {
    "open_bench": "instrument.scripting.bench",
    "connect": "instrument.scripting.remote",
    "open_run": "instrument.scripting.results",
    "fit": "instrument.scripting.results",
    "reconstruct": "instrument.scripting.results",
    "locate": "instrument.scripting.results",
    "spheres": "instrument.scripting.results",
    "Run": "instrument.scripting.results",
    "RunHandle": "instrument.scripting.handle",
    "RunTimeout": "instrument.scripting.handle",
    "ScriptBench": "instrument.scripting.bench",
    "DryRun": "instrument.scripting.bench",
}

__all__ = ["plans", *_FACADE]


def __getattr__(name: str) -> Any:
    if name == "plans":  # the sub-package (builders: plans.in_plane, plans.load, ...)
        return importlib.import_module("instrument.plans")
    if name in _FACADE:
        return getattr(importlib.import_module(_FACADE[name]), name)
    raise AttributeError(f"module 'instrument' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
