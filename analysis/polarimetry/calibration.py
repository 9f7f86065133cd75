"""Calibration of a dual rotating retarder's hidden parameters on reference samples.

A DRR (:mod:`analysis.polarimetry.drr`) is not a separable ``A · M · W`` polarimeter —
each step moves the generator and the analyser together — so the eigenvalue calibration
method (:mod:`analysis.polarimetry.ecm`) does not apply to its K×16 instrument matrix.
Its instrument matrix is, however, fixed by five numbers: the zero offsets of the two
retarders' fast axes, their two retardances and the analyser polariser's axis relative to
the generator polariser (which defines the azimuth 0 of the measured matrices). Those
are fitted here by weighted non-linear least squares (Levenberg–Marquardt with bounds,
``scipy.optimize.least_squares``) to the DRR scans of the same reference samples ECM
uses — air, a polariser at one or two angles, a retarder — with the samples' own
parameters (polariser azimuth, retarder azimuth and retardance) and a source scale per
scan as nuisance parameters. Goldstein & Chipman 1990 (J. Opt. Soc. Am. A 7, 693) derive
the same retarder-offset and retardance errors of a DRR from the air measurement in closed
form to first order; the joint fit here needs no small-error assumption and also uses the
polariser and retarder scans. The covariance of the fitted parameters is
``(JᵀJ)⁻¹`` of the whitened residuals at the solution.

The two fixed polarisers' extinction ratios ε are known, not fitted: they come from the
polarisers' datasheets (the profile's ``[optics]``) and enter the model's W as partial
polarisers (:mod:`analysis.polarimetry.drr`). ε changes a reading by about ε of the
parallel intensity, a tenth of one reading's noise on a bench whose meter has a relative
noise of 10⁻⁴, so the reference scans would determine it only loosely (ADR 0108); held at
the datasheet value it shifts the five parameters without widening their covariance.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize

from analysis.polarimetry.drr import (
    MuellerEstimate,
    check_extinction,
    estimate,
    instrument_matrix,
    reduce,
)
from analysis.polarimetry.elements import linear_polariser, linear_retarder
from analysis.polarimetry.validation import PolarimetryInputError, check_array

__all__ = ["DrrCalibration", "FittedPolarimeter", "ReferenceFit", "ReferenceScan",
           "calibrate_drr", "fit_references", "reduce_calibrated", "reduce_propagated"]

_KINDS = ("air", "polariser", "retarder")

#: Names of ``DrrCalibration.params``, in order.
INSTRUMENT_PARAMS = ("psg_retarder_offset_deg", "psa_retarder_offset_deg", "psg_retardance",
                     "psa_retardance", "psa_polariser_deg")


@dataclass(frozen=True)
class ReferenceScan:
    """One DRR scan of a reference sample.

    Attributes
    ----------
    kind : str
        ``"air"``, ``"polariser"`` or ``"retarder"``.
    intensities, sigmas : ndarray of shape (K,)
        The readings at the scan's steps and their standard deviations.
    psg_retarder_deg, psa_retarder_deg : ndarray of shape (K,)
        The nominal retarder angles the stages were sent to (e.g. :func:`drr_angles`).
    angle_deg : float
        Nominal azimuth of the polariser's axis or the retarder's fast axis (start value).
    retardance : float
        Nominal retardance of a retarder sample, radians (start value).
    """

    kind: str
    intensities: NDArray[np.float64]
    sigmas: NDArray[np.float64]
    psg_retarder_deg: NDArray[np.float64]
    psa_retarder_deg: NDArray[np.float64]
    angle_deg: float = 0.0
    retardance: float = math.pi / 2

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise PolarimetryInputError("kind", f"must be one of {_KINDS}, got {self.kind!r}")
        y = check_array("intensities", self.intensities, ndim=1)
        shape = y.shape
        s = check_array("sigmas", self.sigmas)
        if s.ndim == 0:
            s = np.full(shape, float(s))
        if s.shape != shape or np.any(s <= 0):
            raise PolarimetryInputError("sigmas", f"must be > 0 with shape {shape}")
        g = check_array("psg_retarder_deg", self.psg_retarder_deg, shape=shape)
        a = check_array("psa_retarder_deg", self.psa_retarder_deg, shape=shape)
        for name, val in (("angle_deg", self.angle_deg), ("retardance", self.retardance)):
            if not math.isfinite(float(val)):
                raise PolarimetryInputError(name, f"must be finite, got {val!r}")
        object.__setattr__(self, "intensities", y)
        object.__setattr__(self, "sigmas", s)
        object.__setattr__(self, "psg_retarder_deg", g)
        object.__setattr__(self, "psa_retarder_deg", a)


@dataclass(frozen=True)
class FittedPolarimeter:
    """A polarimeter's fitted instrument parameters, what a DRR's and a PEM's calibration
    share (:class:`DrrCalibration`,
    :class:`~analysis.polarimetry.pem_calibration.PemCalibration`).

    Attributes
    ----------
    params : ndarray of shape (5,)
        The instrument parameters (the subclass names them).
    cov : ndarray of shape (5, 5)
        Their covariance.
    sample_params : tuple of tuple of float
        Per scan: ``(scale,)`` for air, ``(scale, angle_deg)`` for a polariser,
        ``(scale, angle_deg, retardance)`` for a retarder. The instrument matrix is for
        a unit source; the air scan's scale is the source intensity in the readings'
        units, by which a reduced matrix is divided to give transmittances.
    chi2 : float
        Weighted residual sum of squares.
    dof : int
        Number of readings minus fitted parameters.
    psg_extinction, psa_extinction : float
        The generator's and analyser's polariser extinction ratios the fit assumed
        (datasheet values, not fitted; 0 for ideal polarisers).
    """

    params: NDArray[np.float64]
    cov: NDArray[np.float64]
    sample_params: tuple[tuple[float, ...], ...] = field(default=())
    chi2: float = 0.0
    dof: int = 0
    psg_extinction: float = 0.0
    psa_extinction: float = 0.0

    def __post_init__(self) -> None:
        for name in ("psg_extinction", "psa_extinction"):
            object.__setattr__(self, name, check_extinction(name, getattr(self, name)))

    @property
    def sigma(self) -> NDArray[np.float64]:
        """Standard deviations of :attr:`params`."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


@dataclass(frozen=True)
class DrrCalibration(FittedPolarimeter):
    """Fitted DRR parameters; :meth:`instrument_matrix` is what a calibrated reduction uses.

    ``params`` are :data:`INSTRUMENT_PARAMS`: retarder offsets (deg, added to the commanded
    angles), retardances (rad), analyser polariser axis (deg; the generator polariser is
    0); the other fields are :class:`FittedPolarimeter`'s.
    """

    def instrument_matrix(self, psg_retarder_deg: ArrayLike,
                          psa_retarder_deg: ArrayLike) -> NDArray[np.float64]:
        """The calibrated instrument matrix (shape (K, 16)) for commanded retarder angles."""
        g_off, a_off, d_g, d_a, p_a = (float(v) for v in self.params)
        return instrument_matrix(check_array("psg_retarder_deg", psg_retarder_deg) + g_off,
                                 check_array("psa_retarder_deg", psa_retarder_deg) + a_off,
                                 psg_retardance=d_g, psa_retardance=d_a,
                                 psa_polariser_deg=p_a, psg_extinction=self.psg_extinction,
                                 psa_extinction=self.psa_extinction)


def _sample_matrix(kind: str, p: NDArray[np.float64]) -> NDArray[np.float64]:
    if kind == "air":
        return np.eye(4)
    if kind == "polariser":
        return linear_polariser(math.radians(float(p[0])))
    return linear_retarder(math.radians(float(p[0])), float(p[1]))


def calibrate_drr(scans: Sequence[ReferenceScan], *, psg_retardance: float,
                  psa_retardance: float, psg_extinction: float = 0.0,
                  psa_extinction: float = 0.0) -> DrrCalibration:
    """Fit the DRR's hidden parameters to reference scans (see the module docstring).

    Parameters
    ----------
    scans : sequence of ReferenceScan
        At least an air scan and one other reference; air + polariser + retarder
        determines all five instrument parameters.
    psg_retardance, psa_retardance : float
        Nominal retardances, radians (start values).
    psg_extinction, psa_extinction : float
        The polarisers' power extinction ratios in [0, 1), from their datasheets (held
        fixed; 0 models ideal polarisers).

    Raises
    ------
    PolarimetryInputError
        No scans, no air scan, too few readings for the parameters, or an extinction
        outside [0, 1).
    """
    if not scans:
        raise PolarimetryInputError("scans", "must hold at least an air scan")
    if not any(s.kind == "air" for s in scans):
        raise PolarimetryInputError("scans", "must include an air scan (no sample)")
    for name, val in (("psg_retardance", psg_retardance), ("psa_retardance", psa_retardance)):
        if not math.isfinite(float(val)):
            raise PolarimetryInputError(name, f"must be finite, got {val!r}")
    e_g = check_extinction("psg_extinction", psg_extinction)
    e_a = check_extinction("psa_extinction", psa_extinction)
    x0 = [0.0, 0.0, float(psg_retardance), float(psa_retardance), 0.0]
    lo = [-30.0, -30.0, 0.0, 0.0, -30.0]
    hi = [30.0, 30.0, math.pi, math.pi, 30.0]

    def model(x: NDArray[np.float64], k: int) -> NDArray[np.float64]:
        cal = DrrCalibration(params=x, cov=np.zeros((5, 5)), psg_extinction=e_g,
                             psa_extinction=e_a)
        return cal.instrument_matrix(scans[k].psg_retarder_deg, scans[k].psa_retarder_deg)

    fit = fit_references([(s.kind, s.intensities, s.sigmas, s.angle_deg, s.retardance)
                          for s in scans], model, x0, lo, hi)
    return DrrCalibration(params=fit.params, cov=fit.cov, sample_params=fit.sample_params,
                          chi2=fit.chi2, dof=fit.dof, psg_extinction=e_g,
                          psa_extinction=e_a)


@dataclass(frozen=True)
class ReferenceFit:
    """What :func:`fit_references` returns: the instrument parameters and their
    covariance, each scan's nuisance parameters, χ² and the degrees of freedom."""

    params: NDArray[np.float64]
    cov: NDArray[np.float64]
    sample_params: tuple[tuple[float, ...], ...]
    chi2: float
    dof: int


#: A reference scan as :func:`fit_references` takes it: (kind, readings, σ, nominal
#: azimuth in degrees, nominal retardance in radians).
Reference = tuple[str, NDArray[np.float64], NDArray[np.float64], float, float]


def fit_references(refs: Sequence[Reference],
                   design: Callable[[NDArray[np.float64], int], NDArray[np.float64]],
                   x0: Sequence[float], lo: Sequence[float], hi: Sequence[float]
                   ) -> ReferenceFit:
    """Weighted least squares of a polarimeter's instrument parameters to reference scans.

    ``design(params, k)`` is the instrument matrix (rows × 16, unit unpolarised source) of
    scan k for the instrument parameters ``params`` (start ``x0``, bounds ``lo``/``hi``).
    Each scan adds its nuisance parameters: a source scale, and the azimuth of a polariser
    or the azimuth and retardance of a retarder (the module docstring; the same for a DRR
    and a PEM polarimeter). Covariance ``(JᵀJ)⁻¹`` of the whitened residuals.

    Raises
    ------
    PolarimetryInputError
        Fewer readings than parameters.
    """
    n_inst = len(x0)
    n_extra = {"air": 0, "polariser": 1, "retarder": 2}
    x0, lo, hi = list(x0), list(lo), list(hi)
    slices = []
    for kind, y, _, angle, retardance in refs:
        start = len(x0)
        scale0 = float(np.max(np.abs(y))) or 1.0
        x0.append(scale0 * 2.0)
        lo.append(0.0)
        hi.append(np.inf)
        if kind in ("polariser", "retarder"):
            x0.append(float(angle))
            lo.append(float(angle) - 45.0)
            hi.append(float(angle) + 45.0)
        if kind == "retarder":
            x0.append(float(retardance))
            lo.append(0.0)
            hi.append(math.pi)
        slices.append(slice(start, start + 1 + n_extra[kind]))
    n_data = sum(r[1].size for r in refs)
    if n_data <= len(x0):
        raise PolarimetryInputError(
            "scans", f"hold {n_data} readings for {len(x0)} parameters; add steps or scans")

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        out = []
        for k, ((kind, y, s, _, _), sl) in enumerate(zip(refs, slices, strict=True)):
            p = x[sl]
            model = p[0] * (design(x[:n_inst], k) @ _sample_matrix(kind, p[1:]).ravel())
            out.append((model - y) / s)
        return np.concatenate(out)

    x0a = np.clip(np.array(x0), np.array(lo) + 1e-9, np.array(hi) - 1e-9)
    res = optimize.least_squares(residuals, x0a, bounds=(lo, hi), method="trf",
                                 x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    cov_full = np.linalg.pinv(res.jac.T @ res.jac)
    return ReferenceFit(params=np.asarray(res.x[:n_inst], dtype=float),
                        cov=cov_full[:n_inst, :n_inst],
                        sample_params=tuple(tuple(float(v) for v in res.x[sl])
                                            for sl in slices),
                        chi2=float(2.0 * res.cost), dof=n_data - len(x0))


def reduce_calibrated(intensities: ArrayLike, sigmas: ArrayLike, calibration: DrrCalibration,
                      psg_retarder_deg: ArrayLike, psa_retarder_deg: ArrayLike,
                      *, step: float = 1e-6) -> MuellerEstimate:
    """:func:`~analysis.polarimetry.drr.reduce` with the calibrated W and its uncertainty.

    The covariance is the readings' term plus the calibration's,
    ``cov = cov_noise + J C_cal Jᵀ`` with ``J = ∂vec(M)/∂params`` (central differences of
    the least-squares solution, step ``step`` in each parameter's unit) and ``C_cal`` the
    calibration's 5×5 covariance — first-order propagation (JCGM 100:2008, GUM, eq. 13).
    With reference scans as noisy as the sample's (one scan each of air, a polariser and
    a retarder), leaving the calibration's term out gave pulls of spread 1.21 (91 % inside
    2σ) over eight samples × 10 seeds; with it 1.02 (95 %).
    """
    g_ang = check_array("psg_retarder_deg", psg_retarder_deg)
    a_ang = check_array("psa_retarder_deg", psa_retarder_deg)
    return reduce_propagated(
        intensities, sigmas, calibration.params, calibration.cov,
        lambda p: replace(calibration, params=p).instrument_matrix(g_ang, a_ang), step=step)


def reduce_propagated(intensities: ArrayLike, sigmas: ArrayLike, params: ArrayLike,
                      cov: ArrayLike, design: Callable[[NDArray[np.float64]],
                                                       NDArray[np.float64]],
                      *, step: float = 1e-6) -> MuellerEstimate:
    """:func:`~analysis.polarimetry.drr.reduce` with the instrument matrix ``design(params)``
    of calibrated parameters, and their covariance ``cov`` propagated to first order:
    ``cov_M = cov_noise + J cov Jᵀ``, ``J = ∂vec(M)/∂params`` by central differences of
    step ``step`` (JCGM 100:2008, GUM, eq. 13). :func:`reduce_calibrated` is this for a
    DRR; a PEM calibration (:mod:`analysis.polarimetry.pem_calibration`) uses it too."""
    p0 = np.asarray(params, dtype=float)
    c = np.asarray(cov, dtype=float)
    base = reduce(intensities, sigmas, design(p0))
    jac = np.empty((16, p0.size))
    for i in range(p0.size):
        shifted = []
        for sign in (1.0, -1.0):
            p = p0.copy()
            p[i] += sign * step
            shifted.append(reduce(intensities, sigmas, design(p)).m.ravel())
        jac[:, i] = (shifted[0] - shifted[1]) / (2.0 * step)
    total = base.cov + jac @ c @ jac.T
    return estimate(base.m, 0.5 * (total + total.T), chi2=base.chi2, dof=base.dof)
