"""Speckle in a BRDF reading: the relative error a laser's speckle leaves in each value.

A rough sample under spatially coherent light scatters fully developed speckle (contrast
C = 1 at a point; Goodman, *Speckle Phenomena in Optics*, 2007, ch. 3). A receiver that
integrates it over its aperture A sums M ≈ 1 + A/A_c independent grains, A_c the
correlation area of the speckle at distance z from a spot of intensity I,

    A_c = λ² z² ∫I² / (∫I)²

(Goodman 2007, ch. 4, integrated speckle and the correlation area of free-space speckle),
and its reading fluctuates by 1/√M relative. With A/z² = Ω the receiver's solid angle and
the spot a collimated Gaussian beam of 1/e² radius w on the sample, its footprint
stretched by 1/cos θi and seen foreshortened by cos θr, ∫I²/(∫I)² = cos θi/(π w² cos θr),
so

    M = 1 + π w² cos θr Ω / (λ² cos θi)

(the étendue of the footprint into the receiver in units of λ²). A camera summing the
image of the footprint is such a receiver with its entrance pupil as aperture (the summed
image is the power through the pupil, :mod:`analysis.brdf.reduction`).

With a static sample the pattern is frozen: it does not average over frames, so it is an
error of the geometry, not noise of the readings. Each geometry of a scan sees another,
independent pattern (the pupils of two scan points a few degrees apart sample
non-overlapping parts of the far field, whose grains are λ/(2w) ≈ 10⁻⁴ rad wide), so the
errors are independent between points and enter each value's σ:
σ_rel = C/√M. Spinning the sample about its normal averages N independent patterns
within an exposure: C = 1/√N.

How many (:func:`spin_patterns`): the receiver samples the surface's phase-screen spectrum
at the in-plane scattering vector q_t = k (ω_i,t + ω_r,t) (tangential parts of the unit
vectors towards source and receiver), spread by the receiver's half-angle a = √(Ω/π);
the spectrum is correlated over 2π/L, L = 2w/√cos θi the footprint's 1/e² diameter
(geometric mean of its axes), and a rotation by Δφ moves the sample by |q_t| Δφ, so
patterns decorrelate every Δφ_c = λ / (L · max(|ω_i,t + ω_r,t|, a)) and an exposure of
t at the spin rate ω averages N = max(1, ω t / Δφ_c). Frames taken at other spin angles
(HDR brackets, repeats) see other patterns; a merge weighing them by exposure averages
N = ω Σt / Δφ_c (the caller passes Σt). The simulated bench draws its
patterns by the same model (``hw_mocks.sim.speckle``, ADR 0098).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["speckle_cells", "speckle_rel", "spin_patterns"]


def speckle_cells(theta_i: ArrayLike, theta_r: ArrayLike, *, wavelength_nm: float,
                  beam_radius_mm: float, solid_angle_sr: float) -> NDArray[np.float64]:
    """M, the independent speckle grains a receiver of solid angle Ω integrates
    (module docstring); angles in radians."""
    if not (wavelength_nm > 0 and beam_radius_mm > 0 and solid_angle_sr > 0):
        raise ValueError("wavelength, beam radius and solid angle must be > 0")
    cos_i = np.maximum(np.cos(np.asarray(theta_i, dtype=float)), 1e-6)
    cos_r = np.maximum(np.cos(np.asarray(theta_r, dtype=float)), 0.0)
    lam_mm = wavelength_nm * 1e-6
    return 1.0 + np.pi * beam_radius_mm**2 * cos_r * solid_angle_sr / (lam_mm**2 * cos_i)


def speckle_rel(theta_i: ArrayLike, theta_r: ArrayLike, *, wavelength_nm: float,
                beam_radius_mm: float, solid_angle_sr: float,
                patterns: ArrayLike = 1.0) -> NDArray[np.float64]:
    """σ_rel = 1/√(N M): the relative standard error speckle leaves in a reading that
    integrates M grains (:func:`speckle_cells`) and N independent patterns (1: a static
    sample)."""
    n = np.asarray(patterns, dtype=float)
    if np.any(n < 1.0):
        raise ValueError("patterns must be >= 1")
    m = speckle_cells(theta_i, theta_r, wavelength_nm=wavelength_nm,
                      beam_radius_mm=beam_radius_mm, solid_angle_sr=solid_angle_sr)
    return np.asarray(1.0 / np.sqrt(n * m), dtype=np.float64)


def spin_patterns(theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike, phi_r: ArrayLike,
                  *, spin_deg_s: float, exposure_s: ArrayLike, wavelength_nm: float,
                  beam_radius_mm: float, solid_angle_sr: float) -> NDArray[np.float64]:
    """N ≥ 1, the independent speckle patterns an exposure of ``exposure_s`` averages while
    the sample spins at ``spin_deg_s`` about its normal (module docstring); radians."""
    if spin_deg_s < 0 or not (wavelength_nm > 0 and beam_radius_mm > 0
                              and solid_angle_sr > 0):
        raise ValueError("spin rate must be >= 0; wavelength, beam radius and solid angle "
                         "> 0")
    ti, pi_ = np.asarray(theta_i, dtype=float), np.asarray(phi_i, dtype=float)
    tr, pr = np.asarray(theta_r, dtype=float), np.asarray(phi_r, dtype=float)
    qx = np.sin(ti) * np.cos(pi_) + np.sin(tr) * np.cos(pr)
    qy = np.sin(ti) * np.sin(pi_) + np.sin(tr) * np.sin(pr)
    spread = np.maximum(np.hypot(qx, qy), np.sqrt(solid_angle_sr / np.pi))
    spot_mm = 2.0 * beam_radius_mm / np.sqrt(np.maximum(np.cos(ti), 1e-3))
    step_rad = wavelength_nm * 1e-6 / (spot_mm * spread)
    swept_rad = np.radians(spin_deg_s) * np.asarray(exposure_s, dtype=float)
    return np.asarray(np.maximum(1.0, swept_rad / step_rad), dtype=np.float64)
