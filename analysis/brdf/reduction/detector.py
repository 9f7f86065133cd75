"""Detector signals and noise: camera frames → collected power, and the receiver solid angle.

The camera is a detector whose aperture is its entrance pupil: the summed, dark-subtracted
signal rate of the footprint's image gives the collected power (EMVA 1288 constants K, η).
Power-meter and camera solid angles follow the reduction's convention (package docstring
of :mod:`analysis.brdf.reduction`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.hdr import merge_hdr
from analysis.radiometry import PLANCK_J_S, SPEED_OF_LIGHT_M_S, FlatField


@dataclass(frozen=True)
class DetectorNoise:
    """EMVA 1288 noise constants of a camera at the gain and bit depth used.

    Attributes
    ----------
    system_gain_dn_per_e : float
        K (DN/e⁻).
    read_noise_e : float
        Temporal dark noise σ_d (e⁻) of one frame.
    saturation_dn : float
        Raw level at or above which a pixel is saturated.
    dark_current_e_per_s : float
        Mean dark current μ_d/t (e⁻/s); its shot noise adds to the read noise.
    """

    system_gain_dn_per_e: float
    read_noise_e: float
    saturation_dn: float
    dark_current_e_per_s: float = 0.0

    def __post_init__(self) -> None:
        if not (self.system_gain_dn_per_e > 0 and self.saturation_dn > 0):
            raise ValueError("system gain and saturation level must be > 0")
        if self.read_noise_e < 0 or self.dark_current_e_per_s < 0:
            raise ValueError("read noise and dark current must be >= 0")

    def difference_noise_dn(
        self, exposure_us: float, *, n_averaged: int = 1, n_dark_averaged: int = 1
    ) -> float:
        """σ (DN) of the signal-independent noise of a (light − dark) difference.

        Each of the two frames (means of ``n`` exposures) carries read noise σ_d², the shot
        noise of the dark current μ_d and the quantisation noise 1/12 DN² (EMVA 1288 R3.1
        §2.3): σ² = Σ_frames [K²(σ_d² + μ_d) + 1/12] / n.
        """
        k = self.system_gain_dn_per_e
        mu_d = self.dark_current_e_per_s * exposure_us * 1e-6
        per_frame = k * k * (self.read_noise_e**2 + mu_d) + 1.0 / 12.0
        return float(np.sqrt(per_frame / n_averaged + per_frame / n_dark_averaged))


@dataclass(frozen=True)
class CameraSignal:
    """Summed, dark-subtracted, flat-corrected signal rate of one point.

    Attributes
    ----------
    rate_dn_per_us : float
        Σ over the region of interest of the HDR-merged rate (DN/µs).
    variance : float
        Its variance from the noise model ((DN/µs)²): shot noise of the signal and the
        signal-independent noise of every pixel summed.
    n_pixels : int
        Pixels summed.
    saturated_pixels : int
        Pixels saturated in every bracket (their rate is a lower bound).
    n_brackets : int
    profile : ndarray, shape (H // b, W // b), or None
        The signal image (negative rates set to 0) summed over b × b blocks, b =
        ``profile_block``: which pixels carried the signal, for the covariance of the
        pixel-response error between points (:func:`pixel_response_covariance`).
    profile_block : int
    profile_sq_sum : float
        Σ s_i² over the pixels (exact, not from blocks), with the profile.
    clipped_pixels : int
        Pixels of the region at or above the saturation level in the *shortest* bracket:
        their true rate is unknown (above what the merge reports), so the summed rate is
        only a lower bound — a point to leave out of fits, or to re-measure with less
        light.
    """

    rate_dn_per_us: float
    variance: float
    n_pixels: int
    saturated_pixels: int
    n_brackets: int
    profile: NDArray[np.float64] | None = None
    profile_block: int = 0
    profile_sq_sum: float = 0.0
    clipped_pixels: int = 0

    @property
    def sigma(self) -> float:
        return float(np.sqrt(self.variance))


def camera_signal(
    frames: ArrayLike,
    exposures_us: ArrayLike,
    darks: ArrayLike,
    *,
    noise: DetectorNoise,
    n_averaged: int = 1,
    n_dark_averaged: int | None = None,
    flat: FlatField | ArrayLike | None = None,
    mask: ArrayLike | None = None,
    profile_block: int = 0,
) -> CameraSignal:
    """Merge one point's brackets and sum the signal rate over the region of interest.

    Parameters
    ----------
    frames : array_like, shape (N, H, W)
        Light frames in DN, one per exposure bracket (each the mean of ``n_averaged``
        exposures).
    exposures_us : array_like, shape (N,)
    darks : array_like, shape (N, H, W) or (H, W)
        Dark frame for each bracket, at the same exposure (or one master dark).
    noise : DetectorNoise
    n_averaged, n_dark_averaged : int
        Exposures averaged into each light / dark frame (dark default: same).
    flat : FlatField or array_like (H, W), optional
        Normalised PRNU response; the rate and its σ are divided by it.
    profile_block : int
        Keep the signal image summed over blocks of this size (0: not kept).
    mask : array_like of bool (H, W), optional
        Region of interest (default the whole frame). Choose it from the geometry, not from
        the data, or the sum is biased by the selection.

    Returns
    -------
    CameraSignal

    Notes
    -----
    Summing every pixel of the region (no thresholding) keeps the estimate unbiased; the
    background pixels only add their read noise, which the variance includes. The HDR merge
    is Debevec & Malik (1997) eq. 6 with the known linear response and Robertson et al.
    (2003) inverse-variance weights (:func:`analysis.hdr.merge_hdr`).
    """
    stack = np.asarray(frames)
    if stack.ndim == 2:
        stack = stack[np.newaxis]
    t = np.atleast_1d(np.asarray(exposures_us, dtype=float))
    if stack.ndim != 3 or t.shape != (stack.shape[0],):
        raise ValueError("frames must be (N, H, W) with one exposure per frame")
    if n_averaged < 1:
        raise ValueError("n_averaged must be >= 1")
    nd = n_averaged if n_dark_averaged is None else int(n_dark_averaged)
    read = np.array([noise.difference_noise_dn(float(e), n_averaged=n_averaged,
                                               n_dark_averaged=nd) for e in t])
    merged = merge_hdr(
        stack, t, darks=darks, saturation_dn=noise.saturation_dn,
        weighting="inverse_variance",
        # an average of n frames has 1/n of the shot-noise variance: K/n in the model
        system_gain_dn_per_e=noise.system_gain_dn_per_e / n_averaged,
        read_noise_dn=read,
    )
    rate = merged.rate
    var = merged.variance if merged.variance is not None else np.zeros_like(rate)
    if flat is not None:
        resp = flat.response if isinstance(flat, FlatField) else np.asarray(flat, float)
        rate = rate / resp
        var = var / resp**2
    sel = np.ones(rate.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if sel.shape != rate.shape:
        raise ValueError(f"mask shape {sel.shape} differs from the frames {rate.shape}")
    profile, sq_sum = None, 0.0
    if profile_block > 0:
        b = int(profile_block)
        img = np.where(sel, np.maximum(rate, 0.0), 0.0)
        h, w = (img.shape[0] // b) * b, (img.shape[1] // b) * b
        profile = img[:h, :w].reshape(h // b, b, w // b, b).sum(axis=(1, 3))
        sq_sum = float(np.sum(img * img))
    shortest = int(np.argmin(t))
    clipped = int(np.count_nonzero((stack[shortest] >= noise.saturation_dn) & sel))
    return CameraSignal(
        rate_dn_per_us=float(rate[sel].sum()),
        variance=float(var[sel].sum()),
        n_pixels=int(sel.sum()),
        saturated_pixels=int((merged.saturated & sel).sum()),
        n_brackets=int(stack.shape[0]),
        profile=profile,
        profile_block=int(profile_block),
        profile_sq_sum=sq_sum,
        clipped_pixels=clipped,
    )


def camera_power_w(
    rate_dn_per_us: ArrayLike,
    *,
    system_gain_dn_per_e: float,
    quantum_efficiency: float,
    wavelength_nm: float,
) -> NDArray[np.float64]:
    """Optical power (W) that produced a summed signal rate: S·10⁶/(Kη) photons/s × hν.

    EMVA 1288 R3.1 §2.1 (μ_y − μ_y.dark = K η μ_p) inverted; shape of ``rate_dn_per_us``.
    Apply the same factor to a standard deviation.
    """
    photon_j = PLANCK_J_S * SPEED_OF_LIGHT_M_S / (wavelength_nm * 1e-9)
    k_eta = system_gain_dn_per_e * quantum_efficiency
    if not k_eta > 0:
        raise ValueError("system gain and quantum efficiency must be > 0")
    return np.asarray(rate_dn_per_us, dtype=float) * 1e6 / k_eta * photon_j


def pixel_response_covariance(
    profiles: ArrayLike, *, u_response_rel: float, block: int = 1,
    sq_sums: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Relative covariance between points of a summed camera signal from the pixel response.

    Each pixel's response is off by an independent error of relative σ u (EMVA 1288 R3.1
    §4 PRNU without a flat-field correction; the flat's own noise with one). A summed
    signal S_j = Σ_i s_ji (1 + ε_i) then carries the relative error Σ_i s_ji ε_i / S_j, and
    two points that image the footprint onto the same pixels share it:

        C_jk = u² Σ_i s_ji s_ki / (S_j S_k).

    With block sums B (b × b pixels) of a smooth image, Σ_i s_ji s_ki ≈ Σ_B B_j B_k / b²;
    an image narrow on the block scale makes that too small (Cauchy–Schwarz), so with the
    exact Σ_i s_ji² (``sq_sums``) the diagonal is exact and the blocks only give the
    correlations.
    On the sim bench (1 % PRNU, ~10⁴ pixels under the spot) C_jj^½ is ~0.3–1·10⁻⁴ and the
    points are strongly correlated (the spot is imaged onto the same pixels): averaged
    over points it does not go down like an independent noise, so it is carried as a
    correlated input (:func:`with_correlated_uncertainty`).

    Parameters
    ----------
    profiles : array_like, shape (n, h, w)
        Per-point signal images (non-negative), e.g. :attr:`CameraSignal.profile`.
    u_response_rel : float
        u, relative standard uncertainty of one pixel's response.
    block : int
        b, the block size the profiles were summed over.
    sq_sums : array_like, shape (n,), optional
        Exact Σ_i s_ji² per point (:attr:`CameraSignal.profile_sq_sum`).

    Returns
    -------
    ndarray, shape (n, n)
    """
    prof = np.asarray(profiles, dtype=float)
    if prof.ndim != 3:
        raise ValueError("profiles must have shape (n, h, w)")
    flat = prof.reshape(prof.shape[0], -1)
    total = flat.sum(axis=1)
    if np.any(total <= 0):
        raise ValueError("every profile needs a positive signal")
    gram = flat @ flat.T / float(block) ** 2
    if sq_sums is not None:
        exact = np.asarray(sq_sums, dtype=float).reshape(-1)
        if exact.shape != total.shape:
            raise ValueError("sq_sums needs one value per profile")
        d = np.sqrt(np.diag(gram))
        gram = gram / np.outer(d, d) * np.sqrt(np.outer(exact, exact))
    return u_response_rel**2 * gram / np.outer(total, total)


def solid_angle_sr(
    aperture_diameter_mm: float,
    distance_mm: float,
    *,
    u_diameter_mm: float = 0.0,
    u_distance_mm: float = 0.0,
) -> tuple[float, float]:
    """Receiver solid angle Ω = 2π(1 − cos a), tan a = (D/2)/R, and its standard uncertainty.

    The uncertainty is first-order propagation of u(D) and u(R) through the exact form (for
    a small aperture u(Ω)/Ω → √((2u_D/D)² + (2u_R/R)²), the A/R² rule).
    """
    d, r = float(aperture_diameter_mm), float(distance_mm)
    if not (d > 0 and r > 0):
        raise ValueError("aperture diameter and distance must be > 0")
    a = np.arctan2(d / 2.0, r)
    omega = 2.0 * np.pi * (1.0 - np.cos(a))
    # dΩ/da = 2π sin a; da/dD = (r/2)/(r² + D²/4); da/dR = −(D/2)/(r² + D²/4)
    den = r * r + d * d / 4.0
    da_dd, da_dr = (r / 2.0) / den, -(d / 2.0) / den
    dom = 2.0 * np.pi * np.sin(a)
    u = dom * np.hypot(da_dd * u_diameter_mm, da_dr * u_distance_mm)
    return float(omega), float(u)


def camera_solid_angle_sr(
    pupil_diameter_mm: float,
    distance_mm: float,
    *,
    u_diameter_mm: float = 0.0,
    u_distance_mm: float = 0.0,
) -> tuple[float, float]:
    """Receiver solid angle of a camera used by the absolute method: Ω = A_pupil / R².

    A camera's radiometric calibration is the camera equation Φ = L A (p/f)² cos⁴α per
    pixel (EMVA 1288 with the optics of :class:`analysis.radiometry.CameraResponse`): its
    étendue is defined by the pupil *area* A. Summing it over the image of the footprint
    gives Σ Φ = (A/R²) ∫ L cos α cos θ (R/r)² dA, so A/R² — not the cone solid angle
    2π(1 − cos a) of :func:`solid_angle_sr`, which is 3a²/4 ≈ 3·10⁻⁴ smaller for a 12.5 mm
    pupil at 300 mm — is the solid angle that matches the calibration. What remains
    (footprint, obliquity, 1/r²) is the receiver factor of :func:`receiver_factor`.
    """
    d, r = float(pupil_diameter_mm), float(distance_mm)
    if not (d > 0 and r > 0):
        raise ValueError("pupil diameter and distance must be > 0")
    omega = np.pi * (d / 2.0) ** 2 / r**2
    u = omega * float(np.hypot(2.0 * u_diameter_mm / d, 2.0 * u_distance_mm / r))
    return float(omega), u

