"""Camera radiometry: master dark, flat-field normalisation, frames → radiance.

Pure functions on arrays. The camera model is the linear model of EMVA 1288
(Release 3.1, §2.1 "Linear signal model"; Release 4.0 Linear, §2.1):

    μ_y = μ_y.dark + K · η · μ_p,          μ_p = A · E · t / (h ν)

with μ_y the mean digital value (DN), K the system gain (DN/e⁻), η the quantum
efficiency (e⁻/photon), μ_p the photons reaching the pixel (area A, irradiance E on the
sensor, exposure time t). Spatial non-uniformity is split as in EMVA 1288 R3.1 §4 into the
dark-signal non-uniformity (DSNU, removed by subtracting a master dark taken at the same
exposure, gain and temperature) and the photo-response non-uniformity (PRNU and
vignetting, removed by dividing by a normalised flat field).

A pinhole camera with an entrance pupil of area A_ap and focal length f maps scene
radiance L (W m⁻² sr⁻¹) to power on a pixel of pitch p as (the "camera equation", e.g.
Nicodemus 1977 / Stover 1990, and ASTM E2387)

    Φ_pixel = L · A_ap · (p / f)² · cos⁴ α

with α the field angle of the pixel. :func:`to_radiance` inverts this.

Conventions: frames are arrays of shape (H, W) in DN; stacks have shape (N, H, W);
exposures are in microseconds; results are float64. Inputs are never modified.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "CameraResponse",
    "FlatField",
    "apply_dark_flat",
    "flat_field",
    "master_dark",
    "pinhole_relative_illumination",
    "rate_to_radiance",
    "to_radiance",
]

PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_S = 299792458.0


def _stack(frames: ArrayLike, what: str) -> NDArray[np.float64]:
    arr = np.asarray(frames, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[np.newaxis]
    if arr.ndim != 3 or arr.shape[0] < 1:
        raise ValueError(f"{what} must have shape (N, H, W) or (H, W), got {arr.shape}")
    return arr


def master_dark(frames: ArrayLike, *, method: str = "median") -> NDArray[np.float64]:
    """Combine dark frames into a master dark.

    Parameters
    ----------
    frames : array_like, shape (N, H, W) or (H, W)
        Dark frames (light off) at the exposure, gain and temperature of the frames
        they will correct (dark current scales with exposure: EMVA 1288 R3.1 §3).
    method : {"median", "mean"}
        The median rejects outliers (cosmic rays, hot-pixel flicker); the mean has the
        lower noise, 1/N of a single frame's temporal variance (the median's is about
        π/(2N) for Gaussian noise).

    Returns
    -------
    ndarray, shape (H, W), float64
        The per-pixel dark level in DN (offset + DSNU + dark signal).
    """
    stack = _stack(frames, "dark frames")
    if method == "median":
        return np.median(stack, axis=0)
    if method == "mean":
        return stack.mean(axis=0)
    raise ValueError(f"method must be 'median' or 'mean', got {method!r}")


@dataclass(frozen=True)
class FlatField:
    """A normalised flat field.

    Attributes
    ----------
    response : ndarray, shape (H, W)
        Relative response, mean 1 over the valid pixels; 1 where not valid (so that a
        division by it never produces inf or NaN).
    valid : ndarray of bool, shape (H, W)
        Pixels whose flat signal was above ``min_fraction`` of the mean.
    mean_signal_dn : float
        Mean dark-subtracted flat signal (DN) over the valid pixels.
    """

    response: NDArray[np.float64]
    valid: NDArray[np.bool_]
    mean_signal_dn: float


def flat_field(
    frames: ArrayLike,
    dark: ArrayLike,
    *,
    min_fraction: float = 0.1,
) -> FlatField:
    """Normalised flat field ``(F − D) / mean(F − D)`` from frames of a uniform source.

    Parameters
    ----------
    frames : array_like, shape (N, H, W) or (H, W)
        Frames of a spatially uniform radiance (integrating sphere, diffuser), well
        below saturation. They are averaged first, which reduces their shot noise by N.
    dark : array_like, shape (H, W) or scalar
        Master dark at the flat frames' exposure and gain.
    min_fraction : float
        Pixels whose signal is below this fraction of the mean (vignetted corners, dead
        pixels) are marked invalid and get a response of 1.

    Returns
    -------
    FlatField

    Notes
    -----
    This is the PRNU correction of EMVA 1288 R3.1 §4. The residual
    non-uniformity after correction is the flat's own shot noise, so average enough
    frames that its variance, ``σ²_flat / N``, is well below that of the frames being
    corrected.
    """
    stack = _stack(frames, "flat frames")
    signal = stack.mean(axis=0) - np.asarray(dark, dtype=np.float64)
    if not 0.0 <= min_fraction < 1.0:
        raise ValueError("min_fraction must lie in [0, 1)")
    rough_mean = float(np.mean(signal))
    if not rough_mean > 0:
        raise ValueError("the dark-subtracted flat has no positive signal")
    valid = signal > min_fraction * rough_mean
    mean = float(signal[valid].mean())
    response = np.where(valid, signal / mean, 1.0)
    return FlatField(response=response, valid=valid, mean_signal_dn=mean)


def apply_dark_flat(
    frame: ArrayLike,
    *,
    dark: ArrayLike,
    flat: FlatField | ArrayLike | None = None,
) -> NDArray[np.float64]:
    """``(raw − dark) / flat``: a frame corrected for DSNU and PRNU, in DN.

    Parameters
    ----------
    frame : array_like, shape (H, W) or (N, H, W)
    dark : array_like, broadcastable to ``frame``
    flat : FlatField or array_like of shape (H, W), optional
        Normalised response; omitted means no flat correction.
    """
    out = np.asarray(frame, dtype=np.float64) - np.asarray(dark, dtype=np.float64)
    if flat is not None:
        response = flat.response if isinstance(flat, FlatField) else np.asarray(flat, float)
        out = out / response
    return out


def pinhole_relative_illumination(
    shape: tuple[int, int],
    *,
    focal_length_px: float,
    principal_point: tuple[float, float] | None = None,
) -> NDArray[np.float64]:
    """cos⁴ α for every pixel of a pinhole camera (natural vignetting).

    Parameters
    ----------
    shape : (H, W)
    focal_length_px : float
        Focal length in pixel pitches (f / p).
    principal_point : (cx, cy), optional
        In pixel coordinates (column, row) of pixel centres; default the image centre
        ``((W − 1)/2, (H − 1)/2)``.

    Returns
    -------
    ndarray, shape (H, W)
        cos⁴ α with tan² α = ((u − cx)² + (v − cy)²) / f_px².
    """
    h, w = shape
    cx, cy = principal_point if principal_point is not None else ((w - 1) / 2, (h - 1) / 2)
    u = (np.arange(w) - cx) / focal_length_px
    v = (np.arange(h) - cy) / focal_length_px
    tan2 = u[np.newaxis, :] ** 2 + v[:, np.newaxis] ** 2
    return 1.0 / (1.0 + tan2) ** 2


@dataclass(frozen=True)
class CameraResponse:
    """Absolute radiometric constants of a camera + lens at one wavelength.

    Attributes
    ----------
    system_gain_dn_per_e : float
        K in DN/e⁻ at the gain setting used (EMVA 1288 R3.1 §2.1).
    quantum_efficiency : float
        η in e⁻/photon at ``wavelength_nm``.
    wavelength_nm : float
    pixel_pitch_um : float
        Pitch of one (binned) pixel.
    focal_length_mm : float
    aperture_diameter_mm : float
        Entrance-pupil diameter D (f-number N = f/D).
    """

    system_gain_dn_per_e: float
    quantum_efficiency: float
    wavelength_nm: float
    pixel_pitch_um: float
    focal_length_mm: float
    aperture_diameter_mm: float

    @property
    def photon_energy_j(self) -> float:
        return PLANCK_J_S * SPEED_OF_LIGHT_M_S / (self.wavelength_nm * 1e-9)

    @property
    def etendue_m2_sr(self) -> float:
        """A_ap · (p/f)²: the étendue of one on-axis pixel through the pupil (m² sr)."""
        area = np.pi * (0.5 * self.aperture_diameter_mm * 1e-3) ** 2
        return float(area * (self.pixel_pitch_um * 1e-3 / self.focal_length_mm) ** 2)

    def radiance_per_dn_rate(self) -> float:
        """Radiance (W m⁻² sr⁻¹) of an on-axis pixel that accumulates 1 DN per second."""
        photons_per_s = 1.0 / (self.system_gain_dn_per_e * self.quantum_efficiency)
        return photons_per_s * self.photon_energy_j / self.etendue_m2_sr


def to_radiance(
    frame: ArrayLike,
    *,
    dark: ArrayLike,
    exposure_us: float,
    response: CameraResponse,
    flat: FlatField | ArrayLike | None = None,
    relative_illumination: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Scene radiance in W m⁻² sr⁻¹ from a raw frame.

    ``L = (y − dark) / flat / (t · K · η) · hν / (A_ap (p/f)² cos⁴α)`` — the linear
    model of EMVA 1288 (R3.1 §2.1) inverted through the camera equation in the module
    docstring.

    Parameters
    ----------
    frame : array_like, shape (H, W)
        Raw frame in DN (or an HDR merge already in DN at ``exposure_us``).
    dark : array_like, broadcastable
        Master dark at the same exposure and gain.
    exposure_us : float
    response : CameraResponse
    flat : FlatField or array_like, optional
        Normalised PRNU flat (should exclude the natural cos⁴ vignetting when
        ``relative_illumination`` is also given, or it is corrected twice).
    relative_illumination : array_like, shape (H, W), optional
        cos⁴ α (see :func:`pinhole_relative_illumination`); default 1 (on-axis).

    Returns
    -------
    ndarray, shape (H, W), float64
    """
    if not exposure_us > 0:
        raise ValueError("exposure_us must be > 0")
    rate = apply_dark_flat(frame, dark=dark, flat=flat) / exposure_us
    return rate_to_radiance(rate, response=response,
                            relative_illumination=relative_illumination)


def rate_to_radiance(
    rate_dn_per_us: ArrayLike,
    *,
    response: CameraResponse,
    flat: FlatField | ArrayLike | None = None,
    relative_illumination: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Radiance (W m⁻² sr⁻¹) from a dark-subtracted signal rate in DN/µs, such as
    :attr:`analysis.hdr.HdrResult.rate` (at relative gain 1, whose K is
    ``response.system_gain_dn_per_e``).

    Parameters
    ----------
    rate_dn_per_us : array_like, shape (H, W)
    response : CameraResponse
    flat, relative_illumination : optional
        As in :func:`to_radiance`.
    """
    rate = np.asarray(rate_dn_per_us, dtype=np.float64) * 1e6  # DN/s
    if flat is not None:
        rate = rate / (flat.response if isinstance(flat, FlatField) else np.asarray(flat, float))
    radiance = rate * response.radiance_per_dn_rate()
    if relative_illumination is not None:
        radiance = radiance / np.asarray(relative_illumination, dtype=np.float64)
    return radiance
