"""Calibration of a PEM polarimeter's hidden parameters on reference samples.

A PEM polarimeter (:mod:`analysis.polarimetry.pem`) measures, per reference sample, the
3·S readings ``W · vec(M)`` of its S fixed settings (DC, 1f and 2f each). Its generator
and analyser are separable (``B = A · M · G``, the analyser's four first rows A and the
generator's six channel Stokes vectors G), but G is 4×6 of rank 4 only over *both*
generator settings, and the 1f/2f channels of the 45° setting are zero: the 24 readings
do not form the square, full-rank ``B`` whose eigenvalues the eigenvalue calibration
method (Compain, Poirier & Drévillon 1999, Appl. Opt. 38, 3490, eqs. 4–9) needs. The
equivalent used here is the route :mod:`analysis.polarimetry.calibration` takes for the
dual rotating retarder: the train's physical parameters are fitted to the reference
readings by weighted least squares
(:func:`~analysis.polarimetry.calibration.fit_references`), with each reference's own
azimuth (and retardance) and a source scale as nuisance parameters, and their covariance
``(JᵀJ)⁻¹``.

The five parameters (:data:`PEM_PARAMS`), in the frame whose azimuth 0 is the source
polariser's true axis at mount 0:

* ``amplitude_factor``: the true peak retardation over the one the modulator was set
  to (a PEM head's calibration, nm per drive unit, is known to a few per cent);
* ``pem_axis_offset_deg``: the modulator's fast axis less its nominal orientation;
* ``psa_retarder_offset_deg``: the analyser retarder's axis at mount 0;
* ``psa_retardance``: its retardance, radians;
* ``psa_polariser_offset_deg``: the analyser polariser's axis at mount 0.

The polarisers' extinction ratios are known (the profile's ``[optics]``) and held, as for
the DRR (ADR 0108's amendment). The lock-in's phase is taken as the reference's (its 1f and
2f in-phase outputs signed as :func:`~analysis.polarimetry.drr.pem_instrument_rows` says).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from analysis.polarimetry.calibration import (
    FittedPolarimeter,
    fit_references,
    reduce_propagated,
)
from analysis.polarimetry.drr import MuellerEstimate, check_extinction
from analysis.polarimetry.pem import CHANNELS, PemSetting, pem_design
from analysis.polarimetry.validation import PolarimetryInputError, check_array

__all__ = ["PEM_PARAMS", "PemCalibration", "PemReferenceScan", "calibrate_pem"]

#: Names of ``PemCalibration.params``, in order (module docstring).
PEM_PARAMS = ("amplitude_factor", "pem_axis_offset_deg", "psa_retarder_offset_deg",
              "psa_retardance", "psa_polariser_offset_deg")


@dataclass(frozen=True)
class PemReferenceScan:
    """One PEM run of a reference sample: its S settings' DC, 1f and 2f readings
    (shape (S, 3)) with σ, the settings (element axes the mounts reached, the modulator at
    its nominal axis), the amplitude the modulator was set to (rad at the light's
    wavelength), and the reference's nominal azimuth (deg) and retardance (rad)."""

    kind: str
    readings: NDArray[np.float64]
    sigmas: NDArray[np.float64]
    settings: tuple[PemSetting, ...]
    amplitude_rad: float
    angle_deg: float = 0.0
    retardance: float = math.pi / 2

    def __post_init__(self) -> None:
        shape = (len(self.settings), CHANNELS)
        y = check_array("readings", self.readings, shape=shape)
        s = check_array("sigmas", self.sigmas, shape=shape)
        if np.any(s <= 0):
            raise PolarimetryInputError("sigmas", "must be > 0")
        if not math.isfinite(self.amplitude_rad) or self.amplitude_rad <= 0:
            raise PolarimetryInputError("amplitude_rad", f"must be > 0, got "
                                        f"{self.amplitude_rad!r}")
        object.__setattr__(self, "readings", y)
        object.__setattr__(self, "sigmas", s)


@dataclass(frozen=True)
class PemCalibration(FittedPolarimeter):
    """Fitted PEM parameters (:data:`PEM_PARAMS`); the covariance, each reference's
    nuisance parameters, χ², dof and the extinctions the fit held are
    :class:`~analysis.polarimetry.calibration.FittedPolarimeter`'s."""

    def design(self, settings: Sequence[PemSetting], amplitude_rad: float
               ) -> NDArray[np.float64]:
        """The calibrated instrument matrix (3·S × 16) for the nominal settings and the
        amplitude the modulator was set to."""
        amp, pem_off, ret_off, ret, pol_off = (float(v) for v in self.params)
        true = [replace(s, pem_axis_deg=s.pem_axis_deg + pem_off,
                        analyser_retarder_deg=s.analyser_retarder_deg + ret_off,
                        analyser_polariser_deg=s.analyser_polariser_deg + pol_off)
                for s in settings]
        return pem_design(true, amplitude_rad=amp * amplitude_rad,
                          analyser_retardance_rad=ret, psg_extinction=self.psg_extinction,
                          psa_extinction=self.psa_extinction)

    def reduce(self, readings: NDArray[np.float64], sigmas: NDArray[np.float64],
               settings: Sequence[PemSetting], amplitude_rad: float) -> MuellerEstimate:
        """One geometry's Mueller matrix through :meth:`design`, the calibration's
        covariance propagated
        (:func:`~analysis.polarimetry.calibration.reduce_propagated`)."""
        return reduce_propagated(
            np.ravel(readings), np.ravel(sigmas), self.params, self.cov,
            lambda p: replace(self, params=p).design(settings, amplitude_rad))


def calibrate_pem(scans: Sequence[PemReferenceScan], *, analyser_retardance: float,
                  psg_extinction: float = 0.0, psa_extinction: float = 0.0
                  ) -> PemCalibration:
    """Fit the PEM's hidden parameters to reference runs (module docstring).

    ``analyser_retardance``: the analyser retarder's nominal retardance, radians (start
    value); the extinctions are held.

    Raises
    ------
    PolarimetryInputError
        No air scan, too few readings, or an extinction outside [0, 1).
    """
    if not any(s.kind == "air" for s in scans):
        raise PolarimetryInputError("scans", "must include an air scan (no sample)")
    e_g = check_extinction("psg_extinction", psg_extinction)
    e_a = check_extinction("psa_extinction", psa_extinction)
    x0 = [1.0, 0.0, 0.0, float(analyser_retardance), 0.0]
    lo = [0.5, -30.0, -30.0, 0.0, -30.0]
    hi = [1.5, 30.0, 30.0, math.pi, 30.0]

    def model(x: NDArray[np.float64], k: int) -> NDArray[np.float64]:
        cal = PemCalibration(params=x, cov=np.zeros((5, 5)), psg_extinction=e_g,
                             psa_extinction=e_a)
        return cal.design(scans[k].settings, scans[k].amplitude_rad)

    fit = fit_references([(s.kind, s.readings.ravel(), s.sigmas.ravel(), s.angle_deg,
                           s.retardance) for s in scans], model, x0, lo, hi)
    return PemCalibration(params=fit.params, cov=fit.cov, sample_params=fit.sample_params,
                          chi2=fit.chi2, dof=fit.dof, psg_extinction=e_g, psa_extinction=e_a)
