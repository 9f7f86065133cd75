"""BRDF models, integration, fitting and model selection (pure numerics on arrays).

Angle conventions are stated once in :mod:`analysis.brdf.geometry`.
"""

from analysis.brdf.fit import FitResult, fit_brdf, prediction_band
from analysis.brdf.geometry import Geometry, make_geometry
from analysis.brdf.instrument import convolve_instrument
from analysis.brdf.integrate import dhr
from analysis.brdf.model import BRDFModel, ParamSpec, sum_models
from analysis.brdf.registry import available_models, get_model, parse_model_list
from analysis.brdf.selection import SelectionResult, select_model

__all__ = [
    "BRDFModel",
    "FitResult",
    "Geometry",
    "ParamSpec",
    "SelectionResult",
    "available_models",
    "convolve_instrument",
    "dhr",
    "fit_brdf",
    "get_model",
    "make_geometry",
    "parse_model_list",
    "prediction_band",
    "select_model",
    "sum_models",
]
