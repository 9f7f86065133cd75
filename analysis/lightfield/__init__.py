"""Light fields from scattered light: data types, operators, reconstruction, localisation.

Implements the flatland plenoptic analysis of hidden objects of T. Sasaki, *Information
extraction from non-line-of-sight objects using plenoptic data from scattered light*, PhD
thesis, University of Minnesota, 2020 ("Sasaki 2020"; equation numbers as there, eq. 2-14
is chapter 2's fourteenth): propagation and scattering of light fields, the unfolded forward
model (eqs. 2-3, 2-6), the per-scattering-point reconstruction (eqs. 2-13 … 2-38) with
diagnostics and regularisation, and localisation by (radiance-preserving) refocusing and
depth filtering (ch. 3).
"""

from .brdf import MATERIALS, FlatlandBRDF, SpatiallyVaryingBRDF, material
from .diagnostics import (
    Diagnostics,
    NoiseEstimate,
    degree_of_specularity,
    noise_psd_from_coefficients,
    noise_psd_from_frames,
    relative_noise_error,
)
from .field import LightField2D, LightField4D, theta_grid, uniform_grid
from .forward import UnfoldedScene
from .localize import (
    QUALITY_FLAGS,
    Detection,
    FocalStack,
    Resolution,
    depth_interval,
    depth_profile,
    detect_objects,
    effective_p_max,
    point_response,
    refocus,
    refocus_4d,
    theoretical_resolution,
)
from .propagate import (
    project,
    project_4d,
    propagate,
    propagate_4d,
    sample_along_curves,
)
from .reconstruct import CurveSolution, Reconstruction, reconstruct, solve_curves
from .regularize import RegularizationResult, regularize, truncation_level_mse
from .scatter import scatter
from .search_range import at_far_edge, detect_widening
from .spectral import (
    SeparableSpectra,
    brdf_fourier_matrix,
    coefficients,
    fourier_orders,
    separable_spectra,
    synthesize,
)

__all__ = [
    "MATERIALS",
    "QUALITY_FLAGS",
    "CurveSolution",
    "Detection",
    "Diagnostics",
    "FlatlandBRDF",
    "FocalStack",
    "LightField2D",
    "LightField4D",
    "NoiseEstimate",
    "Reconstruction",
    "RegularizationResult",
    "Resolution",
    "SeparableSpectra",
    "SpatiallyVaryingBRDF",
    "UnfoldedScene",
    "at_far_edge",
    "brdf_fourier_matrix",
    "coefficients",
    "degree_of_specularity",
    "depth_interval",
    "depth_profile",
    "detect_objects",
    "detect_widening",
    "effective_p_max",
    "fourier_orders",
    "material",
    "noise_psd_from_coefficients",
    "noise_psd_from_frames",
    "point_response",
    "project",
    "project_4d",
    "propagate",
    "propagate_4d",
    "reconstruct",
    "refocus",
    "refocus_4d",
    "regularize",
    "relative_noise_error",
    "sample_along_curves",
    "scatter",
    "separable_spectra",
    "solve_curves",
    "synthesize",
    "theoretical_resolution",
    "theta_grid",
    "truncation_level_mse",
    "uniform_grid",
]
