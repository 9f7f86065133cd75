"""Each geometry's K readings → its Mueller-matrix BRDF with covariance, decomposition and
realizability.

Instrument matrix (:func:`analysis.polarimetry.drr.instrument_matrix`, Goldstein 1992):
from the retarders' read-back axes and, uncalibrated, the optical train's nominal
retardances (at the group's wavelength) and polariser axes; calibrated, from
:meth:`analysis.polarimetry.calibration.DrrCalibration.instrument_matrix` and the
calibration's covariance added to the matrix's (:func:`reduce_calibrated`). A PEM run's
rows (:func:`analysis.polarimetry.pem.pem_design`) take the same polarisers' extinction;
calibrated, the PEM calibration's train
(:meth:`analysis.polarimetry.pem_calibration.PemCalibration.reduce`, ADR 0113).

Units. W is for a unit unpolarised source, so the reduced matrix is in watts per unit
source. The Mueller-matrix BRDF (1/sr) divides it by the unit-source intensity S, the
receiver's solid angle Ω and cos θr (the point-receiver BRDF of Nicodemus et al. 1977,
eq. 5, for each element):

    F = M / (S · Ω · cos θr),   Ω = π a² / (4 d²)   (aperture a at distance d)

S is the air scan's scale with a calibration, divided by the fraction
``1 − exp(−2a²/(4w²))`` of a Gaussian beam of 1/e² radius w (the profile's) that the
aperture a took in straight through; without a calibration it is 2·P for a DRR (the
profile's source power P, taken as polarised along the generator's fixed polariser: a
unit unpolarised source passes ½) and P × the photodiode's V/W for a PEM run (its
generator polariser turns, so the source is unpolarised: :func:`_pem_scale`). The
normalised matrix m_ij/m00 does not depend on S, Ω or cos θr. A group
taken straight through (the detector arm in the beam: a reference sample, θr ≥ 90°) is
divided by S alone: its matrix is the sample's transmittance matrix (unitless).

Decomposition (Lu & Chipman 1996, :func:`analysis.polarimetry.decomposition.decompose`)
and realizability (Cloude's coherency matrix, :func:`analysis.polarimetry.realizability`)
are reported per geometry; a matrix that fails the test is flagged, never projected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.brdf.reduction.detector import solid_angle_sr
from analysis.polarimetry.calibration import DrrCalibration, reduce_calibrated
from analysis.polarimetry.decomposition import PolarDecomposition, decompose
from analysis.polarimetry.drr import (
    MuellerEstimate,
    condition_number,
    estimate,
    instrument_matrix,
    reduce,
)
from analysis.polarimetry.pem import pem_design
from analysis.polarimetry.pem_calibration import PemCalibration
from analysis.polarimetry.realizability import Realizability, realizability
from analysis.polarimetry.validation import PolarimetryInputError
from instrument.pipelines.polarimetry.calibration import PolarimeterCalibration
from instrument.pipelines.polarimetry.readings import PolarimetricRun, StepGroup

__all__ = ["MuellerPoint", "Scale", "reduce_group", "source_scale"]


@dataclass(frozen=True)
class Scale:
    """The factor S·Ω between watts per unit source and the BRDF's 1/sr (without cos θr)."""

    source_w: float
    solid_angle_sr: float
    source: str
    #: What a straight-through reading of a unit source gives (the air scan's own scale,
    #: the aperture's part of the beam included): divides a transmitted group.
    direct_w: float = math.nan

    def through(self) -> float:
        return self.direct_w if math.isfinite(self.direct_w) else self.source_w


@dataclass(frozen=True)
class MuellerPoint:
    """One geometry's results. ``raw`` is in W per unit source; ``brdf`` in 1/sr."""

    group: StepGroup
    raw: MuellerEstimate
    brdf: MuellerEstimate
    condition: float
    decomposition: PolarDecomposition | None
    decomposition_note: str
    realizability: Realizability


def source_scale(prun: PolarimetricRun, cal: PolarimeterCalibration | None) -> Scale:
    """S and Ω of the module docstring, and where S came from (a PEM run's S in volts
    through the photodiode's responsivity and transimpedance).

    Raises
    ------
    ValueError
        No receiver geometry (detector distance and aperture) in the profile, or no
        source power and no calibration.
    """
    prof = prun.run.profile()
    geo = prof.get("geometry", {})
    try:
        distance = float(geo["detector_distance_mm"])
        aperture = float(geo["detector_aperture_mm"])
    except KeyError as err:
        raise ValueError(f"the run's bench profile names no [geometry] {err.args[0]}: the "
                         "Mueller-matrix BRDF needs the receiver's solid angle") from None
    omega, _ = solid_angle_sr(aperture, distance)
    if cal is not None and cal.mode == "drr":
        w = prof.get("simulation", {}).get("source", {}).get("beam_radius_mm",
                                                             geo.get("beam_radius_mm"))
        if w is None:
            return Scale(cal.source_scale_w, omega,
                         "the calibration's air scan (the whole beam taken as inside the "
                         "meter's aperture)")
        # the air scan read the part of the Gaussian beam inside the aperture
        inside = 1.0 - math.exp(-2.0 * (aperture / 2.0) ** 2 / float(w) ** 2)
        return Scale(cal.source_scale_w / inside, omega,
                     f"the calibration's air scan over the {inside:.1%} of the beam "
                     f"(1/e² radius {float(w):g} mm) inside the meter's aperture",
                     direct_w=cal.source_scale_w)
    # a PEM calibration's air scan is taken through an attenuator (the photodiode's DC
    # range), so its scale is not the sample runs' source: they keep the profile's (ADR 0113)
    power = prof.get("simulation", {}).get("source", {}).get("power_w")
    if power is None:
        raise ValueError("the source power is unknown (no calibration and no simulated "
                         "source power): run scatterlab calibrate polarimeter")
    if prun.polarimetry.get("mode") == "pem":
        return _pem_scale(prof, float(power), omega)
    return Scale(2.0 * float(power), omega,
                 "2 × the profile's source power (taken as polarised along the generator)")


def _pem_scale(prof: dict[str, object], power_w: float, omega: float) -> Scale:
    """A PEM run reads volts: the unit-source scale is the source power P times the
    photodiode's volts per watt, its responsivity × transimpedance (``[photodiode]``).

    Why P and not the DRR's 2P. The rows (:func:`analysis.polarimetry.pem.pem_design`)
    are for a unit *unpolarised* source: after the generator polariser it is
    ``½(1, cos 2p, sin 2p, 0)``, and the Jacobi–Anger factors (DC ``g₀ + J₀(A) g_c``, 1f
    ``√2 J₁(A) g_s``, 2f ``√2 J₂(A) g_c``: the lock-in's RMS of the peak amplitudes
    ``2J₁``, ``2J₂``) are the emulator's and the rows' alike, so the reduced matrix is in
    volts per unit unpolarised source. A source of power P and degree of linear
    polarisation d along the polariser's axis passes ``P(1 + d)/2`` where a unit
    unpolarised one passes ½: S = P(1 + d). The DRR's generator polariser is fixed and its
    laser polarised along it (d ≈ 1: S ≈ 2P); a PEM generator turns its polariser between
    0° and 45°, which only an unpolarised source (d = 0) sees equally at both settings
    (the rows take a unit unpolarised source at every setting): S = P. The DRR's 2P here
    made every PEM m00 half the truth (ADR 0106, amendment of 2026-11-27).

    Raises
    ------
    ValueError
        No ``[photodiode]`` responsivity and transimpedance.
    """
    pd = prof.get("photodiode")
    pd = pd if isinstance(pd, dict) else {}
    resp, gain = pd.get("responsivity_a_per_w"), pd.get("transimpedance_v_per_a")
    if not isinstance(resp, int | float) or not isinstance(gain, int | float):
        raise ValueError("a PEM run reads the photodiode in volts: the Mueller-matrix BRDF "
                         "needs [photodiode] responsivity_a_per_w (one value) and "
                         "transimpedance_v_per_a in the bench profile")
    volts = float(resp) * float(gain)
    return Scale(power_w * volts, omega,
                 f"the profile's source power (unpolarised: a PEM generator turns its "
                 f"polariser) × the photodiode's {volts:.4g} V/W (responsivity × "
                 "transimpedance)")


def _nominal_matrix(prun: PolarimetricRun, g: StepGroup) -> np.ndarray:
    return instrument_matrix(
        g.psg_retarder_deg, g.psa_retarder_deg,
        psg_retardance=math.radians(prun.retardance_deg("psg", g.wavelength_nm)),
        psa_retardance=math.radians(prun.retardance_deg("psa", g.wavelength_nm)),
        psg_polariser_deg=g.psg_polariser_deg, psa_polariser_deg=g.psa_polariser_deg,
        psg_extinction=prun.extinction("psg"), psa_extinction=prun.extinction("psa"))


def reduce_group(prun: PolarimetricRun, g: StepGroup, cal: PolarimeterCalibration | None,
                 scale: Scale, *, alpha: float = 0.05) -> MuellerPoint:
    """Reduce one group (module docstring).

    Raises
    ------
    PolarimetryInputError
        Too few or degenerate steps for the 16 elements (fewer than 25 equal steps).
    """
    # the pipeline pairs a PEM run with a PEM calibration only (choose_calibration)
    fitted = None if cal is None else cal.drr
    if g.pem is not None and isinstance(fitted, PemCalibration):
        # the PEM calibration's train (ADR 0113), its covariance propagated
        w = fitted.design(g.pem.settings, g.pem.amplitude_rad)
        raw = fitted.reduce(g.pem.readings, g.pem.sigmas, g.pem.settings,
                            g.pem.amplitude_rad)
    elif g.pem is not None:
        # DC, 1f and 2f of every setting (analysis.polarimetry.pem), nominal analyser
        # retardance and the polarisers' datasheet extinction
        w = pem_design(g.pem.settings, amplitude_rad=g.pem.amplitude_rad,
                       analyser_retardance_rad=math.radians(
                           prun.retardance_deg("psa", g.wavelength_nm)),
                       psg_extinction=prun.extinction("psg"),
                       psa_extinction=prun.extinction("psa"))
        raw = reduce(g.pem.readings.ravel(), g.pem.sigmas.ravel(), w)
    elif isinstance(fitted, DrrCalibration):
        w = fitted.instrument_matrix(g.psg_retarder_deg, g.psa_retarder_deg)
        raw = reduce_calibrated(g.intensity, g.sigma, fitted, g.psg_retarder_deg,
                                g.psa_retarder_deg)
    else:
        w = _nominal_matrix(prun, g)
        raw = reduce(g.intensity, g.sigma, w)
    # straight through (the detector arm in the beam, θr ≥ 90°): a transmittance, unitless
    factor = (scale.through() if g.transmitted else
              scale.source_w * scale.solid_angle_sr * math.cos(math.radians(g.theta_r)))
    brdf = estimate(raw.m / factor, raw.cov / factor**2, chi2=raw.chi2, dof=raw.dof)
    decomposition, note = None, ""
    try:
        decomposition = decompose(brdf.m, brdf.cov)
    except PolarimetryInputError as err:
        note = str(err)
    test = realizability(brdf.m, brdf.cov, alpha=alpha, seed=int(g.rows[0]))
    return MuellerPoint(group=g, raw=raw, brdf=brdf, condition=condition_number(w),
                        decomposition=decomposition, decomposition_note=note,
                        realizability=test)


def dop(m: np.ndarray) -> dict[str, float]:
    """Degree of polarisation of the light leaving ``m`` for unpolarised, H, V, +45° and
    −45° incident light, and the depolarisation index (Gil & Bernabeu 1985, Opt. Acta 32,
    259, eq. 10: ``P_Δ = √(Σ m_ij² − m00²) / (√3 m00)``)."""
    inputs = {"unpolarised": (1.0, 0.0, 0.0, 0.0), "H": (1.0, 1.0, 0.0, 0.0),
              "V": (1.0, -1.0, 0.0, 0.0), "+45°": (1.0, 0.0, 1.0, 0.0),
              "−45°": (1.0, 0.0, -1.0, 0.0)}
    out = {}
    for name, s in inputs.items():
        o = m @ np.asarray(s)
        out[name] = float(np.linalg.norm(o[1:]) / o[0]) if o[0] > 0 else math.nan
    m00 = float(m[0, 0])
    out["depolarisation index"] = (
        float(math.sqrt(max(float(np.sum(m**2)) - m00**2, 0.0)) / (math.sqrt(3.0) * m00))
        if m00 > 0 else math.nan)
    return out
