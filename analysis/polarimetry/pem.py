"""PEM polarimetry: the fixed settings that determine all 16 elements, and the reduction
of a run's DC, 1f and 2f readings, geometry by geometry.

A PEM generator (a polariser, then a photoelastic modulator with retardation
``δ(t) = A sin ωt``) sends, per setting, three channels (DC, 1f, 2f;
:func:`analysis.polarimetry.drr.pem_instrument_rows`) that span at most three Stokes
directions: ``g₀ + J₀(A) g_c``, ``g_s`` and ``g_c`` (the modulated Stokes vector is
affine in cos δ and sin δ). A full Mueller matrix needs the rows ``a_n ⊗ g`` to span all
of R⁴ ⊗ R⁴, so

* **the generator needs two settings.** With the modulator fixed at 45° (a PEM head is not
  turned between readings) and its polariser at 0°, the channels span I, Q and V; the
  polariser at 45° adds U (the modulator then leaves the light unmodulated, its 1f and 2f
  rows are zero and its DC row is ``(1, 0, 1, 0)``);
* **the analyser needs four settings** whose first rows ``a_n`` span R⁴ (a retarder and
  a polariser: a linear polariser alone never senses V). With generator channel spaces
  G₁ (dim 3) and G₂ (dim 3, G₁ ∩ G₂ = span(I, V)), analysers A₁ with the first and A₂ with
  the second setting give dim = 3·dim A₁ + 3·dim A₂ − 2·dim(A₁ ∩ A₂) ≤ 12 + dim A₂, so 16
  needs dim A₁ = dim A₂ = 4: the minimal set is the 2 × 4 cross product, 8 settings, 24
  rows.

The default analyser angles (a quarter-wave retarder at ±37.5° and ±75° before a
polariser at 0°) minimise the stacked matrix's condition number over a 7.5° grid at
``A = 2.405`` rad (J₀(A) = 0): κ = 9.2 (BENCHMARKS.md, "PEM polarimeter settings").

Rows are ordered setting-major: generator setting, then analyser setting, then the
channels DC, 1f, 2f; the lock-in convention (signed RMS in-phase outputs) is
:func:`~analysis.polarimetry.drr.pem_instrument_rows`'s.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.polarimetry.drr import (
    MuellerEstimate,
    analyser_row,
    condition_number,
    pem_instrument_rows,
    reduce,
)
from analysis.polarimetry.validation import PolarimetryInputError, check_array

__all__ = [
    "DEFAULT_ANALYSER_RETARDER_DEG",
    "DEFAULT_GENERATOR_POLARISER_DEG",
    "PemSetting",
    "pem_condition_number",
    "pem_design",
    "pem_settings",
    "reduce_pem",
]

#: The source polariser's two settings (the modulator fixed at 45°).
DEFAULT_GENERATOR_POLARISER_DEG: tuple[float, float] = (0.0, 45.0)
#: The analyser retarder's four settings (a quarter-wave plate before a polariser at 0°).
DEFAULT_ANALYSER_RETARDER_DEG: tuple[float, ...] = (-75.0, -37.5, 37.5, 75.0)

#: Channels per setting: DC, 1f, 2f.
CHANNELS = 3


@dataclass(frozen=True)
class PemSetting:
    """One fixed setting of a PEM polarimeter: the source polariser (the modulator at
    ``pem_axis_deg``) and the analyser's retarder and polariser, angles in degrees."""

    polariser_deg: float
    analyser_retarder_deg: float
    pem_axis_deg: float = 45.0
    analyser_polariser_deg: float = 0.0


def pem_settings(generator_polariser_deg: Sequence[float] = DEFAULT_GENERATOR_POLARISER_DEG,
                 analyser_retarder_deg: Sequence[float] = DEFAULT_ANALYSER_RETARDER_DEG, *,
                 pem_axis_deg: float = 45.0,
                 analyser_polariser_deg: float = 0.0) -> tuple[PemSetting, ...]:
    """The cross product of generator and analyser settings, generator-major (module
    docstring: two by four is the minimal full set)."""
    return tuple(PemSetting(float(p), float(r), float(pem_axis_deg),
                            float(analyser_polariser_deg))
                 for p in generator_polariser_deg for r in analyser_retarder_deg)


def pem_design(settings: Sequence[PemSetting], *, amplitude_rad: float,
               analyser_retardance_rad: float = math.pi / 2, psg_extinction: float = 0.0,
               psa_extinction: float = 0.0) -> NDArray[np.float64]:
    """The stacked instrument matrix, shape (3·S, 16): rows 3s, 3s+1, 3s+2 are setting
    s's DC, 1f and 2f channels (:func:`~analysis.polarimetry.drr.pem_instrument_rows`).

    ``psg_extinction``, ``psa_extinction``: the source and analyser polarisers' power
    extinction ratios ε, partial polarisers as in the DRR's W
    (:func:`~analysis.polarimetry.drr.instrument_matrix`; 0 is ideal and gives the ideal
    rows bit for bit). The generator's is the effective one for the source's own
    polarisation (:func:`~analysis.polarimetry.drr.generator_extinction`)."""
    if not settings:
        raise PolarimetryInputError("settings", "needs at least one setting")
    rows = [pem_instrument_rows(
        analyser_row(s.analyser_retarder_deg, analyser_retardance_rad,
                     s.analyser_polariser_deg, psa_extinction)[None, :],
        amplitude_rad=amplitude_rad, pem_axis_deg=s.pem_axis_deg,
        polariser_deg=s.polariser_deg, polariser_extinction=psg_extinction)
        for s in settings]
    return np.vstack(rows)


def pem_condition_number(settings: Sequence[PemSetting], *, amplitude_rad: float,
                         analyser_retardance_rad: float = math.pi / 2,
                         psg_extinction: float = 0.0, psa_extinction: float = 0.0) -> float:
    """κ of :func:`pem_design` (∞ when the settings miss some elements)."""
    w = pem_design(settings, amplitude_rad=amplitude_rad,
                   analyser_retardance_rad=analyser_retardance_rad,
                   psg_extinction=psg_extinction, psa_extinction=psa_extinction)
    return condition_number(w)


def reduce_pem(geometry: Sequence[Hashable], setting: ArrayLike, readings: ArrayLike,
               sigmas: ArrayLike, w: ArrayLike) -> dict[Hashable, MuellerEstimate]:
    """The Mueller matrix of every geometry of a PEM run.

    Parameters
    ----------
    geometry : sequence of length P
        A hashable label per reading point (e.g. ``(θi, θr, φr, wavelength)``); points
        with the same label are reduced together.
    setting : array_like of int, shape (P,)
        Each point's index into the settings that made ``w`` (0 … S−1).
    readings, sigmas : array_like of shape (P, 3)
        Each point's DC, 1f and 2f readings (the lock-in's signed RMS in-phase outputs
        and the mean, in the same units) and their standard deviations (> 0).
    w : array_like of shape (3·S, 16)
        :func:`pem_design` for the settings the run used, at its amplitude.

    Returns
    -------
    dict
        Geometry label → :class:`~analysis.polarimetry.drr.MuellerEstimate`, in the order
        the labels first appear.

    Raises
    ------
    PolarimetryInputError
        Mis-shaped or non-finite input, a setting index outside ``w``, or a geometry whose
        settings do not determine all 16 elements (the error names the geometry).
    """
    mat = check_array("w", w, ndim=2)
    if mat.shape[1] != 16 or mat.shape[0] % CHANNELS:
        raise PolarimetryInputError("w", f"must have shape (3·S, 16), got {mat.shape}")
    n_settings = mat.shape[0] // CHANNELS
    labels = list(geometry)
    p = len(labels)
    idx = check_array("setting", setting, shape=(p,))
    if np.any(idx != np.round(idx)) or np.any(idx < 0) or np.any(idx >= n_settings):
        raise PolarimetryInputError(
            "setting", f"must be integers in 0..{n_settings - 1} (the rows of w)")
    y = check_array("readings", readings, shape=(p, CHANNELS))
    s = check_array("sigmas", sigmas, shape=(p, CHANNELS))
    out: dict[Hashable, MuellerEstimate] = {}
    for label in dict.fromkeys(labels):
        points = [k for k, g in enumerate(labels) if g == label]
        rows = np.vstack([mat[CHANNELS * int(idx[k]):CHANNELS * (int(idx[k]) + 1)]
                          for k in points])
        try:
            out[label] = reduce(y[points].ravel(), s[points].ravel(), rows)
        except PolarimetryInputError as err:
            raise PolarimetryInputError(
                "setting", f"geometry {label!r}: {err}") from err
    return out
