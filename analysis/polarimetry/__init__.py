"""Mueller-matrix polarimetry: elements, DRR/PEM reduction, calibration and analysis.

Pure numerics on arrays (no I/O, no other project package). Conventions (Stokes
(I, Q, U, V), angles, handedness, row-major ``vec``) are stated once in
:mod:`analysis.polarimetry.elements` and in ADR 0098.
"""

from analysis.polarimetry.drr import (
    MuellerEstimate,
    analyser_row,
    condition_number,
    drr_angles,
    generator_stokes,
    instrument_matrix,
    normalise,
    pem_instrument_rows,
    reduce,
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
from analysis.polarimetry.validation import PolarimetryInputError

__all__ = [
    "MuellerEstimate",
    "PolarimetryInputError",
    "analyser_row",
    "condition_number",
    "depolariser",
    "diattenuator",
    "drr_angles",
    "generator_stokes",
    "instrument_matrix",
    "linear_polariser",
    "linear_retarder",
    "normalise",
    "pem_instrument_rows",
    "reduce",
    "rotated",
    "rotation",
    "stokes_dop",
]
