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
  for speed; how each pixel is drawn: ``_TemporalNoise``);
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
#: The unlit pixels (dark current alone) draw their Poisson counts by splitting (see
#: ``_split_counts``) up to this mean: beyond it the split's ∝-electrons cost
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

    def emva_saturation_capacity_e(self, binning: int = 1) -> float:
        """The saturation capacity μ_e.sat this sensor shows to an EMVA 1288 evaluation
        (R4.0 §6: the mean signal, in e⁻, where the temporal variance is largest): ground
        truth for camera characterization, below the full well because the PRNU spreads
        the pixels' approach to it.

        A pixel of mean m(1 + prnu·z) has Gaussian shot noise clipped at the well W
        (``_TemporalNoise``); the clipped normal's mean and variance are closed forms
        (with a = (W − μ)/s: E = μΦ(a) − sφ(a) + W(1 − Φ(a)),
        E² = (μ² + s²)Φ(a) − s(μ + W)φ(a) + W²(1 − Φ(a))), averaged over z by a
        64-point Gauss–Hermite rule; the maximum over m is found on a grid refined
        three times (relative resolution 1e-7).
        """
        from scipy.special import ndtr

        p = self.params
        well = p.full_well_e * binning * binning
        z, w = np.polynomial.hermite_e.hermegauss(64)
        w = w / w.sum()

        def moments(m: NDArray) -> tuple[NDArray, NDArray]:
            mu = m[:, None] * (1.0 + p.prnu * z[None, :])
            s = np.sqrt(np.maximum(mu, 1e-12))
            a = (well - mu) / s
            cdf, pdf = ndtr(a), np.exp(-0.5 * a * a) / np.sqrt(2.0 * np.pi)
            e1 = mu * cdf - s * pdf + well * (1.0 - cdf)
            e2 = (mu * mu + s * s) * cdf - s * (mu + well) * pdf + well * well * (1.0 - cdf)
            mean = e1 @ w
            return mean, (e2 - e1 * e1) @ w

        lo, hi = 0.8 * well, 1.2 * well
        for _ in range(4):
            grid = np.linspace(lo, hi, 401)
            k = int(np.argmax(moments(grid)[1]))
            step = grid[1] - grid[0]
            lo, hi = grid[max(k - 1, 0)] - step, grid[min(k + 1, 400)] + step
        m = np.array([0.5 * (lo + hi)])
        return float(moments(m)[0][0])

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
        b = int(binning)
        rate = np.asarray(photon_rate, dtype=np.float32)
        shape = (rate.shape[0] // b, rate.shape[1] // b)
        x, y, w, _ = roi
        well = p.full_well_e * b * b
        k = np.float32(p.system_gain(gain_db, bits))
        black = np.float32(p.black_level(bits))
        dn = np.empty(shape, dtype=np.uint8 if bits <= 8 else np.uint16)
        blocks = _row_blocks(shape)
        # every row block draws from its own stream of the frame's seed: the blocks are
        # fixed by the frame's shape, so a frame is the same whatever the threads
        streams = np.random.SeedSequence([self.seed, int(frame_index), 0xF4A3E]).spawn(
            len(blocks) + 1)
        # The unlit pixels (photon rate 0: dark current alone, most of a frame) share the
        # mean λ₀; up to _SPLIT_BELOW_E their Poisson counts come from one split total
        # (_split_counts), drawn before the blocks.
        lam0 = p.dark_current_e_per_s * exposure_us * 1e-6 * b * b
        counts = (_split_counts(lam0, shape, np.random.default_rng(streams[0]))
                  if lam0 <= _SPLIT_BELOW_E else None)
        noise = _TemporalNoise(p.read_noise_e, well, lam0, counts)

        def block(rows: slice, stream: np.random.SeedSequence) -> None:
            sub = rate[rows.start * b:rows.stop * b]
            rng = np.random.default_rng(stream)
            # a block without light has every pixel at λ₀ (a pixel has light or not:
            # rates are ≥ 0, so a binned sum is 0 only where all its pixels are)
            if counts is not None and not sub.any():
                e = noise.unlit(rows, rng)
            else:
                lam = self.mean_electrons(sub, exposure_us, binning=b,
                                          roi=(x, y + rows.start * b, w, sub.shape[0]))
                np.maximum(lam, 0.0, out=lam)
                unlit = self._bin(sub, b) == 0.0 if counts is not None else False
                e = noise.electrons(lam, unlit, rows, rng)
            e += self._bin(self.dsnu_map_e[y + rows.start * b:y + rows.stop * b,
                                           x:x + w], b)
            e *= k
            e += black
            np.rint(e, out=e)
            np.clip(e, 0, 2**bits - 1, out=e)
            dn[rows] = e

        workers.in_blocks([(block, rows, stream)
                           for rows, stream in zip(blocks, streams[1:], strict=True)])
        return dn


def _row_blocks(shape: tuple[int, ...]) -> list[slice]:
    """Rows of a frame in blocks of about 4 × :data:`workers.BLOCK_PIXELS` pixels (float32
    arrays of 256 KiB: a block's temporaries stay in a core's cache)."""
    step = max(1, 4 * workers.BLOCK_PIXELS // max(shape[1], 1))
    return [slice(r, min(r + step, shape[0])) for r in range(0, shape[0], step)]


def _split_counts(lam0: float, shape: tuple[int, int], rng: np.random.Generator
                  ) -> NDArray[np.intp]:
    """Independent Poisson(λ₀) counts on every pixel of ``shape``, drawn as a Poisson(N λ₀)
    number T of electrons dropped uniformly on the N pixels: splitting a Poisson count
    leaves independent Poisson counts (e^(−Nλ₀)(Nλ₀)^T/T! · T!/∏n_i! · N^(−T) =
    ∏ e^(−λ₀) λ₀^(n_i)/n_i!), at a cost ∝ N λ₀ rather than N."""
    n = shape[0] * shape[1]
    drops = rng.integers(0, n, size=int(rng.poisson(lam0 * n)))
    return np.bincount(drops, minlength=n).reshape(shape)


class _TemporalNoise:
    """A frame's electrons, block by block: shot noise on the mean, clipped at the full
    well, plus the read noise σ_d (module docstring), each pixel drawn in a form that is
    exact for it and cheap. One standard normal z per pixel carries the noise:

    * mean ≥ 50 e⁻ (shot noise Gaussian, module docstring): the shot and the read noise
      are independent Gaussians, so their sum is one, ``lam + √(lam + σ_d²) z`` — the
      distribution of drawing them apart; within 8 σ of the full well, where the clip
      acts between the two, they are drawn apart (a second draw for these pixels only);
    * mean < 50 e⁻: exact Poisson electrons plus ``σ_d z``. The unlit pixels (mean λ₀,
      dark current alone) take their counts from :func:`_split_counts` where it was
      drawn (λ₀ ≤ :data:`_SPLIT_BELOW_E`); the other pixels draw their own.
    """

    def __init__(self, read_noise_e: float, well_e: float, lam0: float,
                 counts: NDArray[np.intp] | None) -> None:
        self.sigma = np.float32(read_noise_e)
        self.well = well_e
        self.low = np.float32(_POISSON_EXACT_BELOW_E)
        self.high = np.float32(well_e - 8.0 * np.sqrt(well_e))
        self.lam0 = lam0
        self.counts = counts

    def unlit(self, rows: slice, rng: np.random.Generator) -> NDArray[np.float32]:
        """Electrons of the block ``rows`` where no pixel has light (the common block):
        the split counts plus the read noise."""
        e = self.counts[rows].astype(np.float32)
        z = rng.standard_normal(e.shape, dtype=np.float32)
        z *= self.sigma
        e += z
        return e

    def electrons(self, lam: NDArray[np.float32], unlit: NDArray[np.bool_] | bool,
                  rows: slice, rng: np.random.Generator) -> NDArray[np.float32]:
        """Electrons of the block ``rows`` with means ``lam``; ``unlit`` marks the pixels
        at λ₀ (used where the split counts exist)."""
        sigma = self.sigma
        z = rng.standard_normal(lam.shape, dtype=np.float32)
        counts = self.counts[rows] if self.counts is not None else None
        e = lam + sigma * sigma
        np.sqrt(e, out=e)
        e *= z
        e += lam
        rest = lam < self.low
        if counts is not None and np.any(unlit):
            mask = np.broadcast_to(unlit, lam.shape)
            split = counts.astype(np.float32)
            split += sigma * z
            np.copyto(e, split, where=mask)
            rest &= ~mask
        flat_e, flat_lam, flat_z = e.reshape(-1), lam.reshape(-1), z.reshape(-1)
        idx = np.flatnonzero(rest)
        if idx.size:
            flat_e[idx] = (rng.poisson(flat_lam[idx].astype(np.float64)).astype(np.float32)
                           + sigma * flat_z[idx])
        near = np.flatnonzero(lam > self.high)
        near = near[flat_lam[near] >= self.low]
        if near.size:
            ln = flat_lam[near]
            shot = np.clip(ln + np.sqrt(ln) * flat_z[near], 0.0, self.well)
            flat_e[near] = shot + sigma * rng.standard_normal(ln.shape, dtype=np.float32)
        return e
