"""BRDF reduction: detector signals → BRDF values with an uncertainty budget.

Pure functions on arrays (no I/O). The chain, per measured point:

1. **Camera frames → collected power.** Light brackets and their dark frames are merged with
   :func:`analysis.hdr.merge_hdr` (dark subtracted per bracket, inverse-variance weighting
   with the EMVA 1288 noise model), divided by the flat field (:mod:`analysis.radiometry`)
   and summed over the region of interest. The summed signal rate S (DN/µs) of a camera
   whose pupil collects the light scattered by the whole footprint is the collected power
   ``P_s = S · 10⁶ · hν / (K η)`` (W): summing the camera equation
   ``Φ_pixel = L A_ap (p/f)² cos⁴α`` over the image of the footprint gives the power through
   the entrance pupil. The camera is then a detector whose aperture is its pupil.
2. **Absolute method** (Nicodemus et al. 1977, NBS Monograph 160, eq. for f_r = dL_r/dE_i;
   ASTM E2387 practice, hardware.md §5d; physics.md §1): for an under-filled sample
   ``f = P_s / (P_i · Ω · cos θr · G)``, with P_i the incident power (power meter in the
   direct beam), Ω the receiver solid angle (a meter aperture: the cone 2π(1 − cos a),
   tan a = (D/2)/R; a camera: A_pupil/R², the étendue of its calibration,
   :func:`camera_solid_angle_sr`) and G the **receiver factor** (:func:`receiver_factor`):
   what a constant BRDF would give through the real geometry — the beam's 1/cos θi
   footprint seen from the receiver (1/r² and obliquities across it) and the aperture's
   projected solid angle. A value is then the normalised average of f over what the
   receiver integrated, exact for a Lambertian sample; near a specular peak that average
   differs from f at the nominal angles (−7·10⁻⁴ on the sim bench's GGX α = 0.2 peak), which
   instrument-aware fitting accounts for (:func:`receiver_model`; issue 5 §3).
3. **Relative method** (hardware.md §5d; Li & Torrance 2003): a reference standard measured at
   the same geometry, ``f = (S / S_ref) · f_ref(θi, θr)``, with f_ref from the standard's
   *measured* BRDF table (:class:`ReferenceStandard`), not ρ/π — real diffusers deviate by up
   to 20 % at large angles. Source drift between the two runs is removed with monitor
   readings when given.
4. **Instrument signature** (hardware.md §5e): the BRDF-equivalent signal with no sample,
   reduced the same way, is subtracted point by point (:func:`subtract_signature`).

Output convention (flag ``cosine_corrected``): ``False`` gives the BRDF f (1/sr) of
Nicodemus; ``True`` gives Stover's *cosine-corrected BRDF* f·cos θr = P_s/(P_i Ω) (1/sr),
the quantity scatterometers often report (ASTM E1392/E2387 "CC-BRDF"). hardware.md §5d
calls the f form "cosine-corrected" because cos θr is divided out; the flag names the
result, not the operation.

Uncertainty budget (hardware.md §5f), kept in separate columns of :class:`BRDFPoints`:

* ``u_stat``: signal noise — shot, read and dark noise of the light and dark frames
  (camera), or the reading noise of a power meter; independent between points.
* ``u_angle``: positioning — |∂f/∂θi| σθi ⊕ |∂f/∂θr| σθr with the local slope of the
  measured BRDF (:func:`angular_uncertainty`); independent between points.
* ``u_ref``: the reference table's uncertainty (relative method).
* ``cov_corr``: errors shared between points with a known covariance — the camera's pixel
  response (PRNU, or a flat field's own noise) weighted by where each point's footprint
  is imaged (:func:`pixel_response_covariance`); propagated into fitted parameters by
  :func:`with_correlated_uncertainty`, not fitted as noise.
* ``u_scale_rel``: a *relative* uncertainty common to every point of the run — incident
  power, solid angle, camera responsivity Kη (absolute method) or the standard's
  calibration scale (relative method). Being fully correlated it must not be fed to a fit as
  per-point noise: :func:`with_scale_uncertainty` adds it to the fitted parameters instead.

Angles are in radians with the conventions of :mod:`analysis.brdf.geometry` (polar angles
from the normal, ωi towards the source, ωr towards the detector, specular at φr = φi + π).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from analysis.brdf.fit import FitResult
from analysis.brdf.geometry import Geometry, geometry_from_vectors, make_geometry
from analysis.brdf.model import BRDFModel
from analysis.hdr import merge_hdr
from analysis.radiometry import PLANCK_J_S, SPEED_OF_LIGHT_M_S, FlatField

__all__ = [
    "BRDFPoints",
    "CameraSignal",
    "DetectorNoise",
    "ReceiverGeometry",
    "ReciprocityCheck",
    "ReferenceStandard",
    "absolute_brdf",
    "angular_uncertainty",
    "camera_power_w",
    "camera_signal",
    "camera_solid_angle_sr",
    "pixel_response_covariance",
    "receiver_factor",
    "receiver_model",
    "receiver_nodes",
    "reciprocity_check",
    "relative_brdf",
    "scale_sensitivity",
    "solid_angle_sr",
    "subtract_signature",
    "with_correlated_uncertainty",
    "with_scale_uncertainty",
]


# ------------------------------------------------------------------------------ camera
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
    """

    rate_dn_per_us: float
    variance: float
    n_pixels: int
    saturated_pixels: int
    n_brackets: int
    profile: NDArray[np.float64] | None = None
    profile_block: int = 0
    profile_sq_sum: float = 0.0

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
    return CameraSignal(
        rate_dn_per_us=float(rate[sel].sum()),
        variance=float(var[sel].sum()),
        n_pixels=int(sel.sum()),
        saturated_pixels=int((merged.saturated & sel).sum()),
        n_brackets=int(stack.shape[0]),
        profile=profile,
        profile_block=int(profile_block),
        profile_sq_sum=sq_sum,
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


# ------------------------------------------------------------------------------ receiver
#: Radon's 7-point rule on the unit disk, exact for polynomials of degree ≤ 5 (Stroud 1971,
#: *Approximate Calculation of Multiple Integrals*, S2:5-1): the centre with weight 1/4 and
#: six points at radius √(2/3) with weight 1/8 (weights sum to 1: a mean over the disk).
_DISK_R = np.concatenate([[0.0], np.full(6, np.sqrt(2.0 / 3.0))])
_DISK_CHI = np.concatenate([[0.0], np.arange(6) * np.pi / 3.0])
_DISK_W = np.concatenate([[0.25], np.full(6, 0.125)])


@dataclass(frozen=True)
class ReceiverGeometry:
    """What one receiver reading integrates: a beam footprint seen through an aperture.

    A collimated Gaussian beam (1/e² radius w) lights a flat, under-filled sample; its
    irradiance on the sample plane is E(x) = 2Pᵢ cos θi /(πw²) · exp(−2(u² cos²θi + v²)/w²)
    (u along the plane of incidence, v across: the 1/cos θi footprint). A receiver whose
    aperture (diameter D) is centred at distance R from the sample centre along ωr and faces
    it collects P = ∫_spot ∫_aperture f(ωi, ω) E cos θ cos α / r² dA_ap dA, with ω, r the
    direction and distance from a spot point to an aperture point, θ its polar angle and α
    its angle to the aperture normal (hardware.md §5e: the angular resolution is set by the
    aperture and the spot size seen from the receiver).

    Attributes
    ----------
    beam_radius_mm : float
        1/e² intensity radius w of the beam (mm).
    distance_mm : float
        R, sample centre to the aperture (camera pupil) centre (mm).
    aperture_diameter_mm : float
        D of the receiver aperture or camera entrance pupil (mm).
    solid_angle_sr : float
        The Ω the reduction divides by (:func:`solid_angle_sr` or
        :func:`camera_solid_angle_sr`).
    sample_aperture : bool
        True: the aperture is integrated (a power-meter aperture, a real lens pupil), with
        a degree-5 disk rule. False: radiance is taken along the ray through the aperture
        centre with étendue A cos α / r² (a pinhole camera model — the simulated camera,
        which traces chief rays).
    n_spot : int
        Gauss–Hermite nodes per footprint axis.
    """

    beam_radius_mm: float
    distance_mm: float
    aperture_diameter_mm: float
    solid_angle_sr: float
    sample_aperture: bool = True
    n_spot: int = 8

    def __post_init__(self) -> None:
        if not (self.beam_radius_mm > 0 and self.distance_mm > 0):
            raise ValueError("beam radius and distance must be > 0")
        if not (self.aperture_diameter_mm > 0 and self.solid_angle_sr > 0):
            raise ValueError("aperture diameter and solid angle must be > 0")
        if self.n_spot < 1:
            raise ValueError("n_spot must be >= 1")


def receiver_nodes(geometry: Geometry, receiver: ReceiverGeometry
                   ) -> tuple[Geometry, NDArray[np.float64]]:
    """Quadrature of a reading (:class:`ReceiverGeometry`) for every point of ``geometry``.

    The footprint is integrated by Gauss–Hermite in the beam's own coordinates (the
    Gaussian is its weight), the aperture by Radon's 7-point disk rule (or its centre).

    Returns
    -------
    nodes : Geometry, shape (M, N)
        Incident direction ωi (the beam is collimated) and the direction from each spot
        node to each aperture node; N = ``geometry`` flattened.
    weights : ndarray, shape (M, N)
        W with P / (Pᵢ Ω cos θr) = Σ_m W f(node m): E dA/Pᵢ · cos θ cos α A/r² / (Ω cos θr).
    """
    wi = np.stack([geometry.xi, geometry.yi, geometry.mu_i], axis=-1).reshape(-1, 3)
    wr = np.stack([geometry.xr, geometry.yr, geometry.mu_r], axis=-1).reshape(-1, 3)
    wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
    wr = wr / np.linalg.norm(wr, axis=-1, keepdims=True)
    n = wi.shape[0]
    # footprint axes: u along the beam's projection on the sample, v across it
    proj = np.hypot(wi[:, 0], wi[:, 1])
    safe = proj > 1e-12
    eu = np.zeros((n, 3))
    eu[:, 0] = np.where(safe, wi[:, 0] / np.where(safe, proj, 1.0), 1.0)
    eu[:, 1] = np.where(safe, wi[:, 1] / np.where(safe, proj, 1.0), 0.0)
    ev = np.stack([-eu[:, 1], eu[:, 0], np.zeros(n)], axis=-1)
    x, w = np.polynomial.hermite.hermgauss(receiver.n_spot)
    s, t = (a.reshape(-1) for a in np.meshgrid(x, x, indexing="ij"))
    w_spot = np.outer(w, w).reshape(-1) / np.pi  # ∫ exp(−s²−t²)/π = 1
    half = receiver.beam_radius_mm / np.sqrt(2.0)
    u = s[:, None] * half / wi[None, :, 2]  # (Ms, N): exp(−2u²cos²θi/w²) = exp(−s²)
    v = np.broadcast_to(t[:, None] * half, u.shape)
    spot = u[..., None] * eu[None] + v[..., None] * ev[None]  # (Ms, N, 3), mm
    # aperture nodes on the plane ⟂ ωr through R ωr
    helper = np.where((np.abs(wr[:, 1]) < 0.9)[:, None], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    e1 = np.cross(wr, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(wr, e1)
    rho = 0.5 * receiver.aperture_diameter_mm
    area = np.pi * rho**2
    if receiver.sample_aperture:
        rk, ck, wk = _DISK_R * rho, _DISK_CHI, _DISK_W
    else:
        rk, ck, wk = np.zeros(1), np.zeros(1), np.ones(1)
    ap = (receiver.distance_mm * wr[None]
          + (rk * np.cos(ck))[:, None, None] * e1[None]
          + (rk * np.sin(ck))[:, None, None] * e2[None])  # (Ma, N, 3)
    d = ap[:, None] - spot[None]  # (Ma, Ms, N, 3): spot → aperture
    r2 = np.einsum("...k,...k->...", d, d)
    omega = d / np.sqrt(r2)[..., None]
    cos_t = np.clip(omega[..., 2], 0.0, None)
    cos_a = np.clip(np.einsum("...k,...k->...", omega, wr[None, None]), 0.0, None)
    weights = (wk[:, None, None] * w_spot[None, :, None] * area * cos_t * cos_a / r2
               / (receiver.solid_angle_sr * wr[None, None, :, 2]))
    m = weights.shape[0] * weights.shape[1]
    nodes = geometry_from_vectors(np.broadcast_to(wi, omega.shape).reshape(m, n, 3),
                                  omega.reshape(m, n, 3))
    return nodes, weights.reshape(m, n)


def receiver_factor(
    theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike, phi_r: ArrayLike,
    *, receiver: ReceiverGeometry,
) -> NDArray[np.float64]:
    """G = Σ W: the reading of a constant BRDF f = 1 in units of Pᵢ Ω cos θr, shape (n,).

    For a point receiver and a point spot G = 1; the finite footprint (1/r² and the
    obliquities across it), the aperture's projected solid angle (π sin²a against Ω) and
    the pinhole étendue make it differ by a few 10⁻⁴ on the sim bench, up to ~10⁻³ at
    grazing views. Dividing a reduced value by G turns it into a normalised average of f
    over what was integrated (:func:`receiver_model`).
    """
    g = make_geometry(*_angles(theta_i, phi_i, theta_r, phi_r))
    _, w = receiver_nodes(g, receiver)
    return w.sum(axis=0)


def receiver_model(model: BRDFModel, receiver: ReceiverGeometry) -> BRDFModel:
    """``model`` as the receiver sees it: f_meas = Σ W f(node) / Σ W (:func:`receiver_nodes`).

    Instrument-aware fitting (issue 5 §3): near a specular peak the reading is the average
    of f over the directions from the footprint to the aperture, not f at the nominal
    angles. The normalisation matches values reduced with :func:`receiver_factor` divided
    out. Same name, parameters and bounds as ``model``; the Jacobian is the same average of
    the model's Jacobian (analytic where the model's is).
    """
    key = ("receiver", receiver)

    def prepared(g: Geometry) -> tuple[Geometry, NDArray[np.float64]]:
        if key not in g.cache:
            nodes, w = receiver_nodes(g, receiver)
            g.cache[key] = (nodes, w / w.sum(axis=0))
        return g.cache[key]

    def value(p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
        nodes, w = prepared(g)
        return np.sum(model.value_fn(p, nodes) * w, axis=0).reshape(g.shape)

    jac = None
    if model.jac_fn is not None:
        mjac = model.jac_fn

        def jac(p: NDArray[np.float64], g: Geometry) -> NDArray[np.float64]:
            nodes, w = prepared(g)
            out = np.sum(mjac(p, nodes) * w[..., None], axis=0)
            return out.reshape((*g.shape, p.size))

    # a plain BRDFModel under the same name (a composite's parts would stay unaveraged)
    return BRDFModel(
        name=model.name, params=model.params, value_fn=value, jac_fn=jac,
        energy_bounded=model.energy_bounded, reciprocal=False, unit=model.unit,
        validity=model.validity, reference=model.reference,
        description=f"{model.description} Averaged over the beam footprint seen through a "
        f"{receiver.aperture_diameter_mm:g} mm receiver at {receiver.distance_mm:g} mm.")


# ------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class BRDFPoints:
    """Reduced BRDF values with their uncertainty budget; every array has shape (n,).

    Attributes
    ----------
    theta_i, phi_i, theta_r, phi_r : ndarray
        Radians (conventions of :mod:`analysis.brdf.geometry`).
    brdf : ndarray
        f (1/sr), or f·cos θr when ``cosine_corrected``.
    u_stat, u_angle, u_ref : ndarray
        Independent standard uncertainties (same unit as ``brdf``); see the module docstring.
    u_scale_rel : float
        Relative standard uncertainty common to all points (correlated).
    cosine_corrected : bool
    method : str
        "absolute" or "relative" (with "-signature" appended after a subtraction).
    receiver : ReceiverGeometry or None
        What each reading integrated (beam footprint × receiver aperture); the values are
        then the normalised average of f over it (:func:`receiver_model`), which an
        instrument-aware fit compares them with. ``None``: treated as point samples.
    cov_corr : ndarray, shape (n, n), or None
        Covariance (unit of ``brdf`` squared) of errors shared between points, e.g. the
        camera's pixel response (:func:`pixel_response_covariance`). Like the common scale
        it is not fitted as noise: :func:`with_correlated_uncertainty` propagates it.
    """

    theta_i: NDArray[np.float64]
    phi_i: NDArray[np.float64]
    theta_r: NDArray[np.float64]
    phi_r: NDArray[np.float64]
    brdf: NDArray[np.float64]
    u_stat: NDArray[np.float64]
    u_angle: NDArray[np.float64]
    u_ref: NDArray[np.float64]
    u_scale_rel: float
    cosine_corrected: bool
    method: str
    receiver: ReceiverGeometry | None = None
    cov_corr: NDArray[np.float64] | None = None

    @property
    def n(self) -> int:
        return int(self.brdf.size)

    @property
    def u_point(self) -> NDArray[np.float64]:
        """Independent part: √(u_stat² + u_angle² + u_ref²) — the σ to fit with."""
        return np.sqrt(self.u_stat**2 + self.u_angle**2 + self.u_ref**2)

    @property
    def u_total(self) -> NDArray[np.float64]:
        """Combined standard uncertainty of each value, common and correlated parts
        included."""
        corr = np.diag(self.cov_corr) if self.cov_corr is not None else 0.0
        return np.sqrt(self.u_point**2 + (self.brdf * self.u_scale_rel) ** 2 + corr)

    def plain_brdf(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(f, u_point) as the BRDF f whatever ``cosine_corrected`` is."""
        if not self.cosine_corrected:
            return self.brdf, self.u_point
        c = np.maximum(np.cos(self.theta_r), 1e-12)
        return self.brdf / c, self.u_point / c

    def plain_cov_corr(self) -> NDArray[np.float64] | None:
        """:attr:`cov_corr` for the BRDF f whatever ``cosine_corrected`` is."""
        if self.cov_corr is None or not self.cosine_corrected:
            return self.cov_corr
        c = np.maximum(np.cos(self.theta_r), 1e-12)
        return self.cov_corr / np.outer(c, c)

    def take(self, index: ArrayLike) -> BRDFPoints:
        """The subset ``index`` (boolean mask or integer indices)."""
        idx = np.asarray(index)
        return replace(
            self, theta_i=self.theta_i[idx], phi_i=self.phi_i[idx],
            theta_r=self.theta_r[idx], phi_r=self.phi_r[idx], brdf=self.brdf[idx],
            u_stat=self.u_stat[idx], u_angle=self.u_angle[idx], u_ref=self.u_ref[idx],
            cov_corr=(None if self.cov_corr is None
                      else self.cov_corr[np.ix_(*(np.arange(self.n)[idx],) * 2)]),
        )


def _angles(*arrays: ArrayLike) -> list[NDArray[np.float64]]:
    out = np.broadcast_arrays(*(np.asarray(a, dtype=float).reshape(-1) for a in arrays))
    return [np.array(a, dtype=float) for a in out]


def absolute_brdf(
    power_w: ArrayLike,
    u_power_w: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    incident_power_w: float,
    u_incident_power_w: float = 0.0,
    solid_angle: float,
    u_solid_angle: float = 0.0,
    u_responsivity_rel: float = 0.0,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    cosine_corrected: bool = False,
    receiver: ReceiverGeometry | None = None,
    cov_power_rel: ArrayLike | None = None,
) -> BRDFPoints:
    """BRDF by the absolute method, f = P_s / (P_i Ω cos θr G) (module docstring, step 2).

    Parameters
    ----------
    power_w, u_power_w : array_like, shape (n,)
        Collected scattered power P_s (W) and its independent standard uncertainty.
    theta_i, phi_i, theta_r, phi_r : array_like, shape (n,)
        Radians.
    incident_power_w, u_incident_power_w : float
        P_i on the sample (W) and its standard uncertainty.
    solid_angle, u_solid_angle : float
        Receiver solid angle Ω (sr), e.g. from :func:`solid_angle_sr`.
    u_responsivity_rel : float
        Relative uncertainty of the detector's responsivity that does not cancel against
        P_i (e.g. the camera's Kη when P_i comes from a power meter).
    sigma_theta_i, sigma_theta_r : float
        Angular standard uncertainties (radians), propagated through the local slope.
    cosine_corrected : bool
        Return f·cos θr instead of f (module docstring).
    receiver : ReceiverGeometry, optional
        What each reading integrated. Given, the receiver factor G
        (:func:`receiver_factor`) is divided out, so that a value is the normalised
        average of f over the footprint and aperture (exact for a Lambertian sample), and
        the geometry is kept on the result for instrument-aware fitting. Without it G = 1:
        a point spot and a point receiver (biased by a few 10⁻⁴ on the sim bench).
    cov_power_rel : array_like, shape (n, n), optional
        Relative covariance of the collected powers shared between points (the camera's
        pixel response, :func:`pixel_response_covariance`); kept as ``cov_corr``.

    Returns
    -------
    BRDFPoints
        ``u_scale_rel`` = √((u_Pi/Pi)² + (u_Ω/Ω)² + u_resp²).
    """
    p = np.asarray(power_w, dtype=float).reshape(-1)
    up = np.broadcast_to(np.asarray(u_power_w, dtype=float), p.shape)
    ti, pi_, tr, pr = _angles(theta_i, phi_i, theta_r, phi_r)
    if ti.shape != p.shape:
        raise ValueError(f"angles have shape {ti.shape} but power has {p.shape}")
    if not (incident_power_w > 0 and solid_angle > 0):
        raise ValueError("incident power and solid angle must be > 0")
    cos_r = np.maximum(np.cos(tr), 1e-12)
    denom = incident_power_w * solid_angle * (1.0 if cosine_corrected else cos_r)
    if receiver is not None:
        denom = denom * receiver_factor(ti, pi_, tr, pr, receiver=receiver)
    f = p / denom
    u_stat = np.abs(up / denom)
    scale = float(np.sqrt((u_incident_power_w / incident_power_w) ** 2
                          + (u_solid_angle / solid_angle) ** 2 + u_responsivity_rel**2))
    u_ang = angular_uncertainty(f, ti, tr, sigma_theta_i=sigma_theta_i,
                                sigma_theta_r=sigma_theta_r, phi_i=pi_, phi_r=pr)
    cov = None
    if cov_power_rel is not None:
        c_rel = np.asarray(cov_power_rel, dtype=float)
        if c_rel.shape != (f.size, f.size):
            raise ValueError(f"cov_power_rel must have shape ({f.size}, {f.size})")
        cov = c_rel * np.outer(f, f)
    return BRDFPoints(ti, pi_, tr, pr, f, u_stat, u_ang, np.zeros_like(f), scale,
                      bool(cosine_corrected), "absolute", receiver, cov)


@dataclass(frozen=True)
class ReferenceStandard:
    """The measured BRDF table of a reference standard (calibration certificate).

    Attributes
    ----------
    name : str
    theta_i_deg : ndarray, shape (m,)
        Increasing incidence angles of the table (degrees).
    theta_r_deg : ndarray, shape (q,)
        Increasing *signed* in-plane viewing angles (degrees; > 0 on the specular side,
        < 0 on the source side, as in plan files).
    brdf : ndarray, shape (m, q)
        f_ref (1/sr).
    u_rel : ndarray, shape (m, q)
        Relative standard uncertainty of each entry (independent part).
    u_scale_rel : float
        Relative uncertainty of the certificate's overall scale (e.g. of the DHR it was
        scaled to), common to all entries.
    """

    name: str
    theta_i_deg: NDArray[np.float64]
    theta_r_deg: NDArray[np.float64]
    brdf: NDArray[np.float64]
    u_rel: NDArray[np.float64]
    u_scale_rel: float = 0.0

    def __post_init__(self) -> None:
        ti = np.asarray(self.theta_i_deg, dtype=float)
        tr = np.asarray(self.theta_r_deg, dtype=float)
        f = np.asarray(self.brdf, dtype=float)
        u = np.broadcast_to(np.asarray(self.u_rel, dtype=float), f.shape)
        if f.shape != (ti.size, tr.size):
            raise ValueError(f"brdf must have shape ({ti.size}, {tr.size}), got {f.shape}")
        if np.any(np.diff(ti) <= 0) or np.any(np.diff(tr) <= 0):
            raise ValueError("table angles must be strictly increasing")
        if np.any(f <= 0) or np.any(u < 0):
            raise ValueError("table values must be > 0 and uncertainties >= 0")
        for name, v in (("theta_i_deg", ti), ("theta_r_deg", tr), ("brdf", f),
                        ("u_rel", np.array(u))):
            object.__setattr__(self, name, v)

    @classmethod
    def uniform(
        cls, name: str, reflectance: float, *, u_rel: float = 0.0, u_scale_rel: float = 0.0,
        theta_i_deg: ArrayLike = (0.0, 89.0), theta_r_deg: ArrayLike = (-89.0, 89.0),
    ) -> ReferenceStandard:
        """A table with the same value ρ/π everywhere — an *ideal* diffuser's certificate.

        Only for ideal simulated standards: a real diffuser's table comes from its
        certificate (hardware.md §5d).
        """
        ti = np.asarray(theta_i_deg, dtype=float)
        tr = np.asarray(theta_r_deg, dtype=float)
        f = np.full((ti.size, tr.size), reflectance / np.pi)
        return cls(name, ti, tr, f, np.full(f.shape, u_rel), u_scale_rel)

    def evaluate(self, theta_i: ArrayLike, phi_i: ArrayLike, theta_r: ArrayLike,
                 phi_r: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(f_ref, u_ref) at in-plane angles in radians, bilinear in (θi, signed θr).

        The signed viewing angle is +θr when the detector is on the far side of the normal
        from the source (|φr − φi| ≈ π), −θr otherwise. Outside the table: ValueError.
        """
        ti, pi_, tr, pr = _angles(theta_i, phi_i, theta_r, phi_r)
        dphi = np.abs(np.angle(np.exp(1j * (pr - pi_))))
        signed = np.where(dphi > np.pi / 2, tr, -tr)
        x, y = np.degrees(ti), np.degrees(signed)
        tol = 1e-6
        if (np.any(x < self.theta_i_deg[0] - tol) or np.any(x > self.theta_i_deg[-1] + tol)
                or np.any(y < self.theta_r_deg[0] - tol)
                or np.any(y > self.theta_r_deg[-1] + tol)):
            raise ValueError(f"angles outside the table of reference {self.name!r}")
        f = _bilinear(self.theta_i_deg, self.theta_r_deg, self.brdf, x, y)
        u = _bilinear(self.theta_i_deg, self.theta_r_deg, self.brdf * self.u_rel, x, y)
        return f, u


def _bilinear(gx: NDArray, gy: NDArray, table: NDArray, x: NDArray, y: NDArray) -> NDArray:
    """Bilinear interpolation on a rectilinear grid (size-1 axes are constant)."""

    def locate(g: NDArray, v: NDArray) -> tuple[NDArray, NDArray]:
        if g.size == 1:
            return np.zeros(v.shape, dtype=int), np.zeros(v.shape)
        j = np.clip(np.searchsorted(g, v, side="right") - 1, 0, g.size - 2)
        w = np.clip((v - g[j]) / (g[j + 1] - g[j]), 0.0, 1.0)
        return j, w

    jx, wx = locate(gx, x)
    jy, wy = locate(gy, y)
    jx1 = np.minimum(jx + 1, gx.size - 1)
    jy1 = np.minimum(jy + 1, gy.size - 1)
    return ((1 - wx) * (1 - wy) * table[jx, jy] + wx * (1 - wy) * table[jx1, jy]
            + (1 - wx) * wy * table[jx, jy1] + wx * wy * table[jx1, jy1])


def relative_brdf(
    signal: ArrayLike,
    u_signal: ArrayLike,
    ref_signal: ArrayLike,
    u_ref_signal: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    reference: ReferenceStandard,
    monitor: ArrayLike | None = None,
    ref_monitor: ArrayLike | None = None,
    u_monitor_rel: float = 0.0,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    cosine_corrected: bool = False,
) -> BRDFPoints:
    """BRDF by the relative method, f = (S/S_ref)·(M_ref/M)·f_ref(θi, θr) (module docstring).

    Parameters
    ----------
    signal, u_signal : array_like, shape (n,)
        Sample signal (any unit proportional to collected power) and its σ.
    ref_signal, u_ref_signal : array_like, shape (n,)
        Reference-standard signal at the same geometry, same unit.
    theta_i, phi_i, theta_r, phi_r : array_like, shape (n,)
        Radians; the table is looked up here.
    reference : ReferenceStandard
    monitor, ref_monitor : array_like, optional
        Source monitor readings during the sample and reference measurements (drift).
    u_monitor_rel : float
        Relative uncertainty of one monitor ratio (common to all points).

    Returns
    -------
    BRDFPoints
        ``u_stat`` from both signals, ``u_ref`` from the table, ``u_scale_rel`` from the
        certificate scale and the monitor.
    """
    s = np.asarray(signal, dtype=float).reshape(-1)
    us = np.broadcast_to(np.asarray(u_signal, dtype=float), s.shape)
    r = np.broadcast_to(np.asarray(ref_signal, dtype=float), s.shape)
    ur = np.broadcast_to(np.asarray(u_ref_signal, dtype=float), s.shape)
    ti, pi_, tr, pr = _angles(theta_i, phi_i, theta_r, phi_r)
    if ti.shape != s.shape:
        raise ValueError(f"angles have shape {ti.shape} but signal has {s.shape}")
    if np.any(r <= 0):
        raise ValueError("reference signals must be > 0")
    drift = np.ones_like(s)
    if monitor is not None or ref_monitor is not None:
        if monitor is None or ref_monitor is None:
            raise ValueError("give both monitor and ref_monitor, or neither")
        drift = (np.broadcast_to(np.asarray(ref_monitor, float), s.shape)
                 / np.broadcast_to(np.asarray(monitor, float), s.shape))
    f_ref, u_fref = reference.evaluate(ti, pi_, tr, pr)
    ratio = s / r * drift
    # the table is f; cosine-corrected output multiplies both sides by cos θr
    c = np.cos(tr) if cosine_corrected else np.ones_like(tr)
    f = ratio * f_ref * c
    # independent: both signals' noise (first order), and the table entry
    u_stat = np.abs(f) * np.sqrt((us / np.where(s != 0, s, np.inf)) ** 2 + (ur / r) ** 2)
    u_stat = np.where(s != 0, u_stat, np.abs(us / r * drift * f_ref * c))
    u_tab = np.abs(ratio * u_fref * c)
    scale = float(np.hypot(reference.u_scale_rel, u_monitor_rel))
    u_ang = angular_uncertainty(f, ti, tr, sigma_theta_i=sigma_theta_i,
                                sigma_theta_r=sigma_theta_r, phi_i=pi_, phi_r=pr)
    return BRDFPoints(ti, pi_, tr, pr, f, u_stat, u_ang, u_tab, scale,
                      bool(cosine_corrected), "relative")


def subtract_signature(
    points: BRDFPoints, signature: ArrayLike, u_signature: ArrayLike
) -> BRDFPoints:
    """Remove the instrument signature (hardware.md §5e), point by point.

    ``signature`` is the BRDF-equivalent signal measured with no sample (or a beam dump) at
    the same detector positions and reduced the same way (same method, same
    ``cosine_corrected``), shape (n,). Its uncertainty adds to ``u_stat`` in quadrature.
    """
    sig = np.broadcast_to(np.asarray(signature, dtype=float), points.brdf.shape)
    us = np.broadcast_to(np.asarray(u_signature, dtype=float), points.brdf.shape)
    method = points.method if points.method.endswith("-signature") else (
        points.method + "-signature")
    return replace(points, brdf=points.brdf - sig, u_stat=np.hypot(points.u_stat, us),
                   method=method)


# ------------------------------------------------------------------------------ angles
def _cluster(x: NDArray, tol: float) -> NDArray[np.int64]:
    """Integer labels grouping values whose sorted neighbours lie within ``tol`` (one label
    per set angle despite read-back jitter)."""
    order = np.argsort(x, kind="stable")
    lab = np.concatenate([[0], np.cumsum(np.diff(x[order]) > tol)])
    out = np.empty(x.size, dtype=np.int64)
    out[order] = lab
    return out


def _combine(*labels: NDArray) -> NDArray[np.int64]:
    """One label per distinct tuple of labels."""
    _, inv = np.unique(np.stack(labels, axis=1), axis=0, return_inverse=True)
    return inv.reshape(-1).astype(np.int64)


def angular_uncertainty(
    brdf: ArrayLike,
    theta_i: ArrayLike,
    theta_r: ArrayLike,
    *,
    sigma_theta_i: float = 0.0,
    sigma_theta_r: float = 0.0,
    phi_i: ArrayLike | None = None,
    phi_r: ArrayLike | None = None,
    tol_rad: float = 1e-3,
) -> NDArray[np.float64]:
    """|∂f/∂θr| σθr ⊕ |∂f/∂θi| σθi from the local slope of the measured values.

    Slopes are second-order finite differences (:func:`numpy.gradient` on the non-uniform
    grid) along θr at fixed incidence and fixed relative azimuth φr − φi — in the plane of
    incidence along the signed θr, across the normal — and along θi at a fixed receiver
    direction; a group with a single point has slope 0. Angles closer than ``tol_rad``
    (default 10⁻³ rad ≈ 0.06°, above stage read-back jitter, below any scan step) count as
    the same set angle: their readings are averaged before differencing, never differenced
    over the jitter. Without ``phi_i``/``phi_r`` all points are taken as in-plane on one
    side. The slope of noisy data overestimates the true slope slightly, which errs on the
    safe side (hardware.md §5f: angular errors matter through steep BRDF slopes).

    Returns
    -------
    ndarray, shape (n,)
    """
    f = np.asarray(brdf, dtype=float).reshape(-1)
    ti = np.asarray(theta_i, dtype=float).reshape(-1)
    tr = np.asarray(theta_r, dtype=float).reshape(-1)
    if sigma_theta_i == 0.0 and sigma_theta_r == 0.0:
        return np.zeros_like(f)
    if phi_i is not None and phi_r is not None:
        pi_, pr = _angles(phi_i, phi_r)
        dphi = np.broadcast_to(np.angle(np.exp(1j * (pr - pi_))), f.shape)
        # in the plane of incidence when the receiver is within tol of it
        plane = np.abs(np.sin(tr) * np.sin(dphi)) <= tol_rad
        signed = np.where(np.abs(dphi) > np.pi / 2, tr, -tr)
        azimuth = np.where(plane, -1, _cluster(dphi, tol_rad))
        coord_r = np.where(plane, signed, tr)
    else:
        azimuth = np.zeros(f.shape, dtype=np.int64)
        coord_r = tr

    def slopes(groups: NDArray, coord: NDArray) -> NDArray:
        out = np.zeros_like(f)
        for k in np.unique(groups):
            sel = np.flatnonzero(groups == k)
            if sel.size < 2:
                continue
            order = sel[np.argsort(coord[sel], kind="stable")]
            x = coord[order]
            inv = _cluster(x, tol_rad)  # repeats of one set angle
            if inv.max() < 1:
                continue
            cnt = np.bincount(inv)
            ym = np.bincount(inv, weights=f[order]) / cnt
            xm = np.bincount(inv, weights=x) / cnt
            out[order] = np.gradient(ym, xm, edge_order=1)[inv]
        return out

    ti_lab = _cluster(ti, tol_rad)
    d_r = (slopes(_combine(ti_lab, azimuth), coord_r) if sigma_theta_r
           else np.zeros_like(f))
    d_i = (slopes(_combine(_cluster(coord_r, tol_rad), azimuth), ti) if sigma_theta_i
           else np.zeros_like(f))
    return np.hypot(d_r * sigma_theta_r, d_i * sigma_theta_i)


# ------------------------------------------------------------------------------ checks
@dataclass(frozen=True)
class ReciprocityCheck:
    """Pairs of points measured both ways, (ωi, ωr) and (ωr, ωi).

    Attributes
    ----------
    pairs : ndarray of int, shape (m, 2)
    ratio : ndarray, shape (m,)
        f(a)/f(b).
    z : ndarray, shape (m,)
        (f(a) − f(b)) / √(u_a² + u_b²): Helmholtz reciprocity predicts |z| ≲ 2.
    """

    pairs: NDArray[np.int64]
    ratio: NDArray[np.float64]
    z: NDArray[np.float64]

    @property
    def n_pairs(self) -> int:
        return int(self.pairs.shape[0])

    @property
    def fraction_within_2sigma(self) -> float:
        return float(np.mean(np.abs(self.z) <= 2.0)) if self.z.size else float("nan")


def reciprocity_check(
    points: BRDFPoints, *, tol_rad: float = 1e-3, isotropic: bool = True
) -> ReciprocityCheck:
    """Find points whose source and detector directions are exchanged and compare them.

    Helmholtz reciprocity f(ωi→ωr) = f(ωr→ωi) (physics.md §1) holds for the BRDF f, so
    cosine-corrected values are converted first. With ``isotropic`` (f depends on φr − φi
    only, physics.md §1) a pair needs θi(a) = θr(b), θr(a) = θi(b) and equal cos(φr − φi);
    otherwise the direction vectors themselves must be exchanged. Angles match within
    ``tol_rad``.
    """
    f, u = points.plain_brdf()
    if isotropic:
        key_a = np.stack([points.theta_i, points.theta_r,
                          np.cos(points.phi_r - points.phi_i)], -1)
        key_b = np.stack([points.theta_r, points.theta_i,
                          np.cos(points.phi_r - points.phi_i)], -1)
    else:
        def vec(t: NDArray, p: NDArray) -> NDArray:
            return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)

        wi = vec(points.theta_i, points.phi_i)
        wr = vec(points.theta_r, points.phi_r)
        key_a = np.concatenate([wi, wr], -1)
        key_b = np.concatenate([wr, wi], -1)
    swapped = np.max(np.abs(key_a[:, None, :] - key_b[None, :, :]), axis=-1) < tol_rad
    same = np.max(np.abs(key_a[:, None, :] - key_a[None, :, :]), axis=-1) < tol_rad
    match = swapped & ~same  # a point on the diagonal θi = θr is its own reciprocal
    a, b = np.nonzero(np.triu(match, k=1))
    pairs = np.stack([a, b], axis=-1).astype(np.int64).reshape(-1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = f[a] / f[b]
        z = (f[a] - f[b]) / np.hypot(u[a], u[b])
    return ReciprocityCheck(pairs, ratio, z)


# ------------------------------------------------------------------------------ fitting
def scale_sensitivity(
    model: BRDFModel,
    params: ArrayLike,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
) -> NDArray[np.float64]:
    """∂p/∂s: how the weighted least-squares optimum moves when all data scale by (1 + s).

    Linearised at ``params``: δp = (JᵀWJ)⁺ JᵀW f, W = diag(1/σ²), J = ∂f/∂p (the
    Gauss–Newton step towards the rescaled data; Nocedal & Wright §10.3). For a model that is
    an amplitude times a shape (ρ/π, ks·D·V) it is exactly p_amp for the amplitudes and 0 for
    the shape parameters.

    Returns
    -------
    ndarray, shape (k,)
    """
    p = np.asarray(params, dtype=float)
    g = make_geometry(*_angles(theta_i, phi_i, theta_r, phi_r))
    jac = model.jacobian_geometry(p, g).reshape(-1, p.size)
    f = model.evaluate_geometry(p, g).reshape(-1)
    w = 1.0 / np.broadcast_to(np.asarray(sigma, dtype=float).reshape(-1), f.shape) ** 2
    a = jac.T @ (jac * w[:, None])
    return np.linalg.pinv(a, rcond=1e-12) @ (jac.T @ (w * f))


def with_scale_uncertainty(
    fit: FitResult,
    model: BRDFModel,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
    scale_rel: float,
) -> FitResult:
    """The fit with the run's common scale uncertainty added to its covariance.

    C' = C + u_s² δp δpᵀ with δp from :func:`scale_sensitivity` (GUM, JCGM 100:2008 §5.2:
    a fully correlated input contributes the outer product of its sensitivities). Standard
    errors and correlations are recomputed; everything else is unchanged.
    """
    if scale_rel == 0.0:
        return fit
    dp = scale_sensitivity(model, fit.params, theta_i, phi_i, theta_r, phi_r, sigma=sigma)
    cov = fit.covariance + scale_rel**2 * np.outer(dp, dp)
    with np.errstate(invalid="ignore"):
        se = np.sqrt(np.diag(cov))
        corr = cov / np.outer(se, se)
    return replace(fit, covariance=cov, stderr=se, correlation=corr)


def with_correlated_uncertainty(
    fit: FitResult,
    model: BRDFModel,
    theta_i: ArrayLike,
    phi_i: ArrayLike,
    theta_r: ArrayLike,
    phi_r: ArrayLike,
    *,
    sigma: ArrayLike,
    cov: ArrayLike,
) -> FitResult:
    """The fit with errors correlated between points (covariance ``cov``, shape (n, n))
    added to its parameter covariance.

    The weighted least-squares optimum responds linearly to a data error δy:
    δp = S δy, S = (JᵀWJ)⁺ JᵀW, W = diag(1/σ²) (the Gauss–Newton step, Nocedal & Wright
    §10.3), so C' = C + S cov Sᵀ (GUM, JCGM 100:2008 §5.2, correlated inputs). The common
    scale of :func:`with_scale_uncertainty` is the special case cov = u_s² f fᵀ.
    """
    c = np.asarray(cov, dtype=float)
    if not np.any(c):
        return fit
    p = np.asarray(fit.params, dtype=float)
    g = make_geometry(*_angles(theta_i, phi_i, theta_r, phi_r))
    jac = model.jacobian_geometry(p, g).reshape(-1, p.size)
    if c.shape != (jac.shape[0], jac.shape[0]):
        raise ValueError(f"cov must have shape ({jac.shape[0]}, {jac.shape[0]})")
    w = 1.0 / np.broadcast_to(np.asarray(sigma, dtype=float).reshape(-1), (jac.shape[0],)) ** 2
    sens = np.linalg.pinv(jac.T @ (jac * w[:, None]), rcond=1e-12) @ (jac.T * w[None, :])
    cov_p = fit.covariance + sens @ c @ sens.T
    with np.errstate(invalid="ignore"):
        se = np.sqrt(np.diag(cov_p))
        corr = cov_p / np.outer(se, se)
    return replace(fit, covariance=cov_p, stderr=se, correlation=corr)
