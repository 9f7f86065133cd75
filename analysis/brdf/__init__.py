"""BRDF models, integration, fitting and model selection (pure numerics on arrays).

Angle conventions are stated once in :mod:`analysis.brdf.geometry`.
"""

from analysis.brdf.geometry import Geometry, make_geometry
from analysis.brdf.model import BRDFModel, ParamSpec, sum_models
from analysis.brdf.registry import available_models, get_model, parse_model_list

__all__ = [
    "BRDFModel",
    "Geometry",
    "ParamSpec",
    "available_models",
    "get_model",
    "make_geometry",
    "parse_model_list",
    "sum_models",
]
