"""Laser speckle on the simulated camera's sensor.

Light from a laser scattered by a rough sample interferes: each point of the sample
re-radiates with a phase set by the local height, and a lens images the sum of those
wavelets with a point-spread function set by its pupil. The result is *fully developed
speckle* (Goodman, *Speckle Phenomena in Optics*, 2007, ch. 3: the intensity at a point is
exponentially distributed, contrast C = σ_I/⟨I⟩ = 1; ch. 4: integrated over a detector
much larger than a grain, the contrast falls as 1/√M with M the number of grains in it;
ch. 5: in an imaging system the grain size on the sensor is ≈ λ·F#, F# the working
f-number z_i/D of the lens; the simulated camera, whose pixels subtend p/f, uses f/D:
:meth:`hw_mocks.sim.camera.SimulatedCamera.speckle_optics`).

How it is generated here (cheaply, and physically):

1. The incoherent rendering of the sample's light (photons/s per pixel, the veil of
   ambient and stray light removed: those are incoherent) gives the mean intensity of the
   image. Its square root, spread over a sub-pixel grid fine enough for the intensity's
   band (spacing ≤ λ·F#/2), is the field's amplitude.
2. A random phase, uniform on [0, 2π) and independent from cell to cell, stands for the
   rough surface (a surface rougher than λ: Goodman 2007, §3.1's random-phasor sum).
3. The field is band-limited by the pupil: its Fourier transform is cut to the disk of
   radius 1/(2 λ F#) (the coherent transfer function of a diffraction-limited lens,
   Goodman, *Introduction to Fourier Optics*, 3rd ed., eq. 6-20), transformed back, and
   its squared modulus divided by the fraction of the band passed (so that, by Parseval,
   the expected total equals the incoherent total exactly).
4. Summed over each pixel's sub-cells: a pixel larger than a grain averages several and
   shows a lower contrast.

The phase screen belongs to the sample: it is drawn from a seed made of the camera's seed
and the bench geometry, so a static sample shows the same pattern frame after frame (the
speckle is frozen, not noise), and a new geometry a new, independent pattern.

A sample spun about its normal by Δφ decorrelates its pattern. The far field at the
detector samples the surface's phase-screen spectrum at the in-plane scattering vector
q_t = k (ω_i,t + ω_r,t) (the tangential parts of the unit vectors towards source and
detector); rotating the screen by Δφ moves that sample by |q_t|·Δφ, and the spectrum is
correlated over 2π/L (L the spot's size). The pattern is therefore taken as decorrelated
after ``Δφ_c = λ / (L · max(|ω_i,t + ω_r,t|, a))``, where the pupil's half-angle a keeps
the spread of directions the pupil itself collects (at the specular direction q_t = 0), and
L = 2w/√cos θi is the footprint's 1/e² diameter (the geometric mean of its two axes).
The model draws an independent pattern per decorrelation step of the spin angle (stated
in ADR 0098): an exposure sweeping the angle Φ averages N = Φ/Δφ_c independent patterns.
Up to :data:`EXACT_PATTERNS` of them are drawn and averaged; beyond, the average of K
drawn patterns has its deviation from the ensemble mean scaled by √(K/N), which keeps the
mean and the variance (and the grains' correlation) of the N-pattern average exactly and
approximates only its skewness.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["EXACT_PATTERNS", "SpeckleOptics", "decorrelation_angle_deg",
           "speckle_image", "speckle_seed"]

#: Independent patterns drawn for an exposure at most (module docstring).
EXACT_PATTERNS = 8
#: Pixels whose coherent rate is below this fraction of the brightest are left out of
#: the speckle grid (their light is < 10⁻⁷ of a grain's; the grid stays small).
SUPPORT_FRACTION = 1e-7
#: Pixels of margin around the lit box: the point-spread function's tails wrap around
#: the periodic transform by less than 10⁻³ of a grain's intensity this far out.
MARGIN_PX = 4


@dataclass(frozen=True)
class SpeckleOptics:
    """What sets the grain on the sensor: wavelength (nm), the lens's working f-number
    (image distance / entrance-pupil diameter) and the pixel pitch (µm)."""

    wavelength_nm: float
    working_f_number: float
    pixel_pitch_um: float

    def __post_init__(self) -> None:
        if not (self.wavelength_nm > 0 and self.working_f_number > 0
                and self.pixel_pitch_um > 0):
            raise ValueError("wavelength, working f-number and pixel pitch must be > 0")

    @property
    def grain_um(self) -> float:
        """The grain size λ·F# on the sensor (µm)."""
        return 1e-3 * self.wavelength_nm * self.working_f_number

    @property
    def subsamples(self) -> int:
        """Sub-cells per pixel side: spacing ≤ λ·F#/2, the intensity's Nyquist step."""
        return max(1, math.ceil(self.pixel_pitch_um / (0.5 * self.grain_um)))


def speckle_seed(seed: int, geometry: Sequence[float], step: int) -> list[int]:
    """The entropy of one pattern: the camera's seed, the geometry (positions to 10⁻⁶)
    and the decorrelation step of the spin angle."""
    words = [int(seed) % 2**63, 0x5BEC]
    words += [round(x * 1e6) % 2**63 for x in geometry]
    words.append(int(step) % 2**63)
    return words


def decorrelation_angle_deg(wavelength_nm: float, beam_radius_mm: float, cos_i: float,
                            tangential_sum: float, pupil_half_angle: float) -> float:
    """Δφ_c (degrees) of a rotation about the sample normal (module docstring).

    ``tangential_sum`` is |ω_i,t + ω_r,t|; ``pupil_half_angle`` a (radians)."""
    spot_mm = 2.0 * beam_radius_mm / math.sqrt(max(cos_i, 1e-3))
    spread = max(tangential_sum, pupil_half_angle)
    return math.degrees(wavelength_nm * 1e-6 / (spot_mm * spread))


def _band(shape: tuple[int, int], spacing_um: float, optics: SpeckleOptics
          ) -> NDArray[np.bool_]:
    """The pupil's coherent pass band on the FFT grid: |f| ≤ 1/(2 λ F#)."""
    from scipy import fft as sfft  # where used: see speckle_image

    cutoff = 1.0 / (2.0 * optics.grain_um)
    fy = sfft.fftfreq(shape[0], d=spacing_um)
    fx = sfft.fftfreq(shape[1], d=spacing_um)
    return (fy[:, None] ** 2 + fx[None, :] ** 2) <= cutoff * cutoff


def speckle_image(coherent: NDArray[np.floating], optics: SpeckleOptics,
                  seeds: Sequence[Sequence[int]], *, patterns: float | None = None
                  ) -> NDArray[np.float64]:
    """The speckled image of ``coherent`` (photons/s per pixel, the mean image).

    Parameters
    ----------
    coherent
        The incoherent rendering of the coherently lit part, shape (H, W), ≥ 0.
    optics
        Wavelength, working f-number and pixel pitch.
    seeds
        One seed (:func:`speckle_seed`) per pattern drawn; their patterns are averaged.
    patterns
        N, the independent patterns the exposure integrates (default ``len(seeds)``);
        N > len(seeds) scales the average's deviation from the mean by √(len(seeds)/N).

    Returns
    -------
    ndarray, shape (H, W)
        Photons/s per pixel; its expected total is the total of ``coherent``.
    """
    rate = np.asarray(coherent, dtype=np.float64)
    if rate.ndim != 2:
        raise ValueError("coherent must be a 2-D image")
    if not seeds:
        raise ValueError("at least one pattern seed is needed")
    n_drawn = len(seeds)
    n_eff = float(n_drawn if patterns is None else patterns)
    if n_eff < 1.0:
        raise ValueError(f"patterns must be >= 1, got {n_eff:g}")
    out = rate.copy()
    peak = float(rate.max(initial=0.0))
    if peak <= 0.0:
        return out
    rows, cols = np.nonzero(rate > SUPPORT_FRACTION * peak)
    r0 = max(int(rows.min()) - MARGIN_PX, 0)
    r1 = min(int(rows.max()) + MARGIN_PX + 1, rate.shape[0])
    c0 = max(int(cols.min()) - MARGIN_PX, 0)
    c1 = min(int(cols.max()) + MARGIN_PX + 1, rate.shape[1])
    box = rate[r0:r1, c0:c1]
    # scipy.fft is imported here, not at the top: every emulated bench (each server
    # start, each test process) imports this module, and scipy.fft with the part of
    # scipy.special it loads costs about 0.5-1 s of CPU that a bench without a laser's
    # speckle never needs
    from scipy import fft as sfft

    s = optics.subsamples
    h, w = box.shape
    shape = (sfft.next_fast_len(h * s), sfft.next_fast_len(w * s))
    amplitude = np.zeros(shape)
    amplitude[:h * s, :w * s] = np.sqrt(np.repeat(np.repeat(box / (s * s), s, 0), s, 1))
    band = _band(shape, optics.pixel_pitch_um / s, optics)
    passed = float(np.count_nonzero(band)) / band.size
    total = np.zeros(shape)
    for words in seeds:
        rng = np.random.default_rng(list(words))
        field = amplitude * np.exp(2j * math.pi * rng.random(shape))
        spectrum = sfft.fft2(field, workers=1)
        spectrum[~band] = 0.0
        image = sfft.ifft2(spectrum, workers=1)
        total += image.real ** 2 + image.imag ** 2
    total /= n_drawn * passed
    if n_eff > n_drawn:
        # the ensemble mean: the incoherent image blurred by |h|², h the coherent PSF
        psf = sfft.ifft2(band.astype(np.complex128), workers=1)
        kernel = (psf.real ** 2 + psf.imag ** 2) / passed
        mean = sfft.ifft2(sfft.fft2(amplitude ** 2) * sfft.fft2(kernel)).real
        total = mean + (total - mean) * math.sqrt(n_drawn / n_eff)
    binned = total[:h * s, :w * s].reshape(h, s, w, s).sum(axis=(1, 3))
    # the light that the band spread into the padding belongs to the box's edge pixels
    # (< 10⁻³ of it); it is dropped, as a sensor's dead border would
    out[r0:r1, c0:c1] = binned
    return out
