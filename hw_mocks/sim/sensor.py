"""A linear image sensor following the EMVA 1288 camera model.

EMVA 1288 (Release 3.1, §2.1–2.3; Release 4.0 Linear, §2) models a pixel as

    photons μ_p --η--> electrons μ_e (+ dark electrons μ_d) --K--> digital value y

    μ_y = μ_y.dark + K (η μ_p + μ_d),     σ²_y = K² σ²_d + σ²_q + K (μ_y − μ_y.dark).

This module implements it pixel by pixel, with what the standard characterises around it:

* η: quantum efficiency; photo-response non-uniformity (PRNU) as a fixed per-pixel
  factor ``1 + prnu · z`` (z standard normal, fixed for the sensor's seed), R3.1 §4;
* dark current ``dark_current_e_per_s`` (electrons ∝ exposure time, R3.1 §3);
* shot noise: electrons are Poisson distributed (a Gaussian with the same mean and
  variance for means ≥ 50 e⁻, where the two agree to far better than any test resolves,
  for speed; how each pixel is drawn: ``_temporal_electrons``);
* full-well saturation: at most ``full_well_e`` electrons per (binned) pixel;
* temporal dark (read) noise σ_d (e⁻, Gaussian) and a dark-signal non-uniformity
  (DSNU) offset map (e⁻, fixed);
* system gain K = K₀ · 10^(gain_dB/20) · 2^(bits − native_bits) DN/e⁻ and a black level
  of ``black_level_dn`` at the native bit depth (scaled the same way), so that the read
  noise is never clipped at 0 (R3.1 §6.5 asks for an offset);
* an ADC of ``bits`` bits: y = clip(round(K e + black), 0, 2^bits − 1), which adds the
  quantisation noise σ²_q = 1/12 DN².

Binning (b × b) sums the electrons of b² pixels before the read-out (charge binning, as on a
CCD; the binned pixel's full well is b² times larger and its read noise is that of one
read).

Deterministic: the fixed pattern comes from ``seed`` and each frame's temporal noise from
``(seed, frame_index)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from hw_mocks.sim import workers

__all__ = ["Sensor", "SensorParams"]

_POISSON_EXACT_BELOW_E = 50.0
#: The pixels at a frame's least mean draw their Poisson counts by splitting (see
#: ``_temporal_electrons``) up to this mean: beyond it the split's ∝-electrons cost
#: exceeds numpy's per-pixel draw (measured, BENCHMARKS.md "main job").
_SPLIT_BELOW_E = 1.0


@dataclass(frozen=True)
class SensorParams:
    """EMVA 1288 parameters of the simulated sensor (defaults resemble a 2/3" CMOS).

    Attributes
    ----------
    width, height : int
        Sensor size in pixels.
    pixel_pitch_um : float
    quantum_efficiency : float
        η (e⁻/photon) at the source wavelength.
    system_gain_dn_per_e : float
        K₀ at 0 dB and the native bit depth.
    native_bits : int
        Bit depth at which K₀ and ``black_level_dn`` are stated.
    read_noise_e : float
        Temporal dark noise σ_d (e⁻).
    dark_current_e_per_s : float
    full_well_e : float
    black_level_dn : float
        Offset at the native bit depth.
    dsnu_e : float
        Standard deviation of the fixed dark offset (e⁻).
    prnu : float
        Relative standard deviation of the fixed response factor.
    """

    width: int = 1024
    height: int = 1024
    pixel_pitch_um: float = 5.5
    quantum_efficiency: float = 0.6
    system_gain_dn_per_e: float = 0.2
    native_bits: int = 12
    read_noise_e: float = 2.5
    dark_current_e_per_s: float = 20.0
    full_well_e: float = 18000.0
    black_level_dn: float = 40.0
    dsnu_e: float = 1.5
    prnu: float = 0.01

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"sensor size must be >= 1 x 1 px, got {self.width} x {self.height}")
        positive = {"pixel_pitch_um": self.pixel_pitch_um,
                    "system_gain_dn_per_e": self.system_gain_dn_per_e,
                    "full_well_e": self.full_well_e}
        for key, value in positive.items():
            if not value > 0:
                raise ValueError(f"sensor {key} must be > 0, got {value}")
        if not 0.0 < self.quantum_efficiency <= 1.0:
            raise ValueError(f"quantum_efficiency must lie in (0, 1], got "
                             f"{self.quantum_efficiency}")
        non_negative = {"read_noise_e": self.read_noise_e,
                        "dark_current_e_per_s": self.dark_current_e_per_s,
                        "black_level_dn": self.black_level_dn, "dsnu_e": self.dsnu_e,
                        "prnu": self.prnu}
        for key, value in non_negative.items():
            if not value >= 0:
                raise ValueError(f"sensor {key} must be >= 0, got {value}")
        if self.native_bits not in (8, 10, 12, 16):
            raise ValueError(f"native_bits must be 8, 10, 12 or 16, got {self.native_bits}")

    def system_gain(self, gain_db: float, bits: int) -> float:
        """K in DN/e⁻ at a gain (dB) and output bit depth."""
        return self.system_gain_dn_per_e * 10.0 ** (gain_db / 20.0) * 2.0 ** (
            bits - self.native_bits
        )

    def black_level(self, bits: int) -> float:
        return self.black_level_dn * 2.0 ** (bits - self.native_bits)


@dataclass
class Sensor:
    """A sensor with its fixed pattern (from ``seed``).

    Parameters
    ----------
    params : SensorParams
    seed : int
    """

    params: SensorParams = field(default_factory=SensorParams)
    seed: int = 0

    def __post_init__(self) -> None:
        p = self.params
        rng = np.random.default_rng([self.seed, 0x5EED])
        shape = (p.height, p.width)
        self.prnu_map = (1.0 + p.prnu * rng.standard_normal(shape)).astype(np.float32)
        self.dsnu_map_e = (p.dsnu_e * rng.standard_normal(shape)).astype(np.float32)

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _bin(a: NDArray, b: int) -> NDArray:
        if b == 1:
            return a
        h, w = a.shape[0] // b, a.shape[1] // b
        return a[: h * b, : w * b].reshape(h, b, w, b).sum(axis=(1, 3))

    def _slices(self, roi: tuple[int, int, int, int]) -> tuple[slice, slice]:
        x, y, w, h = roi
        return slice(y, y + h), slice(x, x + w)

    def mean_electrons(
        self, photon_rate: NDArray, exposure_us: float, *,
        roi: tuple[int, int, int, int], binning: int = 1,
    ) -> NDArray[np.float32]:
        """Expected electrons per (binned) pixel before clipping.

        ``photon_rate`` (photons/s per unbinned pixel) has the ROI's unbinned shape.
        """
        p = self.params
        t = exposure_us * 1e-6
        sy, sx = self._slices(roi)
        e = (np.asarray(photon_rate, dtype=np.float32) * np.float32(p.quantum_efficiency * t)
             * self.prnu_map[sy, sx] + np.float32(p.dark_current_e_per_s * t))
        return self._bin(e, binning)

    def saturation_dn(self, *, gain_db: float, bits: int, binning: int = 1) -> float:
        """Raw level at or above which a pixel must be treated as saturated: the ADC
        maximum, or the full-well level minus 4 σ of read noise and DSNU (pixels sitting at
        full well read as high as this), whichever is lower."""
        p = self.params
        k = p.system_gain(gain_db, bits)
        spread = 4.0 * float(np.hypot(p.read_noise_e, p.dsnu_e))
        well = p.full_well_e * binning * binning
        return float(min(2**bits - 1, np.floor(p.black_level(bits) + k * (well - spread))))

    def expected_dn(
        self, photon_rate: NDArray, exposure_us: float, *, gain_db: float, bits: int,
        roi: tuple[int, int, int, int], binning: int = 1,
    ) -> NDArray[np.float64]:
        """Noise-free mean DN (before quantisation and clipping at the ADC): the ground
        truth the analysis should recover (includes PRNU, DSNU and the black level)."""
        p = self.params
        e = self.mean_electrons(photon_rate, exposure_us, roi=roi, binning=binning)
        e = np.minimum(e.astype(np.float64), p.full_well_e * binning * binning)
        sy, sx = self._slices(roi)
        dsnu = self._bin(self.dsnu_map_e[sy, sx].astype(np.float64), binning)
        k = p.system_gain(gain_db, bits)
        return k * (e + dsnu) + p.black_level(bits)

    # ------------------------------------------------------------------ exposure
    def expose(
        self, photon_rate: NDArray, exposure_us: float, *, gain_db: float, bits: int,
        roi: tuple[int, int, int, int], binning: int = 1, frame_index: int = 0,
    ) -> NDArray:
        """One noisy frame in DN, dtype uint8 (bits ≤ 8) or uint16.

        Parameters
        ----------
        photon_rate : ndarray, shape (roi height, roi width)
            Photons per second reaching each unbinned pixel.
        exposure_us : float
        gain_db : float
        bits : int
            ADC bit depth of the output format.
        roi : (x, y, width, height)
            In unbinned sensor pixels; selects the fixed pattern.
        binning : int
        frame_index : int
            Selects the temporal noise realisation (with the sensor's seed).
        """
        p = self.params
        rng = np.random.default_rng([self.seed, int(frame_index), 0xF4A3E])
        lam = self.mean_electrons(photon_rate, exposure_us, roi=roi, binning=binning)
        lam = np.maximum(lam, 0.0, dtype=np.float32)
        well = p.full_well_e * binning * binning
        sy, sx = self._slices(roi)
        electrons = _temporal_electrons(lam, p.read_noise_e, well, rng)
        dsnu = self._bin(self.dsnu_map_e[sy, sx], binning)
        k = np.float32(p.system_gain(gain_db, bits))
        black = np.float32(p.black_level(bits))
        dn = np.empty(lam.shape, dtype=np.uint8 if bits <= 8 else np.uint16)

        def digitise(rows: slice) -> None:
            e = electrons[rows]
            e += dsnu[rows]
            e *= k
            e += black
            np.rint(e, out=e)
            np.clip(e, 0, 2**bits - 1, out=e)
            dn[rows] = e

        workers.in_blocks([(digitise, rows) for rows in _row_blocks(lam.shape)])
        return dn


def _row_blocks(shape: tuple[int, ...]) -> list[slice]:
    """Rows of a frame in blocks of about 4 × :data:`workers.BLOCK_PIXELS` pixels (float32
    arrays of 256 KiB: a block's temporaries stay in a core's cache)."""
    step = max(1, 4 * workers.BLOCK_PIXELS // max(shape[1], 1))
    return [slice(r, min(r + step, shape[0])) for r in range(0, shape[0], step)]


def _temporal_electrons(lam: NDArray[np.float32], read_noise_e: float, well_e: float,
                        rng: np.random.Generator) -> NDArray[np.float32]:
    """One frame's electrons: shot noise on the mean ``lam``, clipped at the full well
    ``well_e``, plus the read noise σ_d (module docstring), each pixel drawn in a form
    that is exact for it and cheap. One standard normal z per pixel carries the noise:

    * mean ≥ 50 e⁻ (shot noise Gaussian, module docstring): the shot and the read noise
      are independent Gaussians, so their sum is one, ``lam + √(lam + σ_d²) z`` — the
      distribution of drawing them apart; within 8 σ of the full well, where the clip
      acts between the two, they are drawn apart (a second draw for these pixels only);
    * mean < 50 e⁻: exact Poisson electrons plus ``σ_d z``. The pixels at the frame's
      least mean (the unlit ones: dark current alone, most of a frame) share one mean
      λ₀; for λ₀ ≤ :data:`_SPLIT_BELOW_E` their counts are drawn as a Poisson(N λ₀)
      number T of electrons dropped uniformly on all N pixels, which leaves independent
      Poisson(λ₀) counts n_i (splitting of a Poisson count: e^(−Nλ₀)(Nλ₀)^T/T! ·
      T!/∏n_i! · N^(−T) = ∏ e^(−λ₀) λ₀^(n_i)/n_i!), at a cost ∝ N λ₀ rather than N;
      the other pixels draw their own counts.
    """
    z = rng.standard_normal(lam.shape, dtype=np.float32)
    sigma = np.float32(read_noise_e)
    least = lam.min()
    counts = None
    if least <= _SPLIT_BELOW_E:
        # Poisson(least) on every pixel from a Poisson(N·least) number of electrons
        # dropped uniformly, kept where the mean is the least
        n = lam.size
        drops = rng.integers(0, n, size=int(rng.poisson(float(least) * n)))
        counts = np.bincount(drops, minlength=n).reshape(lam.shape)
    out = np.empty_like(lam)
    low, high = np.float32(_POISSON_EXACT_BELOW_E), np.float32(well_e - 8.0 * np.sqrt(well_e))
    width = lam.shape[1]

    def block(rows: slice) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Every pixel of ``rows`` as a Gaussian one, the least-mean ones from the split;
        the flat indices of the others below 50 e⁻ and of those near the well."""
        lb, zb = lam[rows], z[rows]
        ob = np.sqrt(lb + sigma * sigma)
        ob *= zb
        ob += lb
        rest = lb < low
        if counts is not None:
            at_least = lb == least
            split = counts[rows].astype(np.float32)
            split += sigma * zb
            np.copyto(ob, split, where=at_least)
            rest &= ~at_least
        out[rows] = ob
        offset = rows.start * width
        return np.flatnonzero(rest) + offset, np.flatnonzero(lb > high) + offset

    found = workers.in_blocks([(block, rows) for rows in _row_blocks(lam.shape)])
    # drawn in row-major order, as boolean indexing of the whole frame would
    rest = np.concatenate([f[0] for f in found])
    flat_out, flat_lam, flat_z = out.reshape(-1), lam.reshape(-1), z.reshape(-1)
    if rest.size:
        flat_out[rest] = (rng.poisson(flat_lam[rest].astype(np.float64)).astype(np.float32)
                          + sigma * flat_z[rest])
    near_well = np.concatenate([f[1] for f in found])
    near_well = near_well[flat_lam[near_well] >= low]
    if near_well.size:
        ln = flat_lam[near_well]
        shot = np.clip(ln + np.sqrt(ln) * flat_z[near_well], 0.0, well_e)
        flat_out[near_well] = shot + sigma * rng.standard_normal(ln.shape, dtype=np.float32)
    return out
