"""Mueller-matrix polarimetry: elements, DRR/PEM reduction, calibration and analysis.

Pure numerics on arrays (no I/O, no other project package). Conventions (Stokes
(I, Q, U, V), angles, handedness, row-major ``vec``) are stated once in
:mod:`analysis.polarimetry.elements` and in ADR 0102.
"""

from analysis.polarimetry.calibration import (
    DrrCalibration,
    ReferenceScan,
    calibrate_drr,
    reduce_calibrated,
)
from analysis.polarimetry.decomposition import PolarDecomposition, decompose
from analysis.polarimetry.drr import (
    MuellerEstimate,
    analyser_row,
    condition_number,
    drr_angles,
    estimate,
    generator_stokes,
    instrument_matrix,
    normalise,
    pem_instrument_rows,
    reduce,
)
from analysis.polarimetry.ecm import (
    EcmCalibration,
    ReferenceSample,
    ecm_calibrate,
    retarder_diattenuator,
)
from analysis.polarimetry.elements import (
    depolariser,
    diattenuator,
    linear_polariser,
    linear_retarder,
    rotated,
    rotation,
    stokes_dop,
)
from analysis.polarimetry.pbrdf import PBRDF_PARAMS, PbrdfFit, fit_pbrdf, fresnel_mueller, pbrdf
from analysis.polarimetry.realizability import (
    Realizability,
    coherency_matrix,
    mueller_from_coherency,
    realizability,
)
from analysis.polarimetry.validation import PolarimetryInputError

__all__ = [
    "PBRDF_PARAMS",
    "DrrCalibration",
    "EcmCalibration",
    "MuellerEstimate",
    "PbrdfFit",
    "PolarDecomposition",
    "PolarimetryInputError",
    "Realizability",
    "ReferenceSample",
    "ReferenceScan",
    "analyser_row",
    "calibrate_drr",
    "coherency_matrix",
    "condition_number",
    "decompose",
    "depolariser",
    "diattenuator",
    "drr_angles",
    "ecm_calibrate",
    "estimate",
    "fit_pbrdf",
    "fresnel_mueller",
    "generator_stokes",
    "instrument_matrix",
    "linear_polariser",
    "linear_retarder",
    "mueller_from_coherency",
    "normalise",
    "pbrdf",
    "pem_instrument_rows",
    "realizability",
    "reduce",
    "reduce_calibrated",
    "retarder_diattenuator",
    "rotated",
    "rotation",
    "stokes_dop",
]
