"""The goniometer scene: a flat sample with a ground-truth BRDF under a collimated beam.

Physics (Nicodemus et al. 1977; ASTM E2387; Li & Torrance 2003). The sample is a disk of radius
``sample_radius_mm`` in the plane through the lab origin with normal n (the pose of
:mod:`hw_mocks.sim.world`). A collimated Gaussian beam of power P and 1/e² radius w travels
along −ω_s through the origin, with intensity I(r⊥) = 2P/(πw²) exp(−2 r⊥²/w²) across it. A
point x of the sample plane receives the irradiance

    E(x) = I(r⊥(x)) · cos θi,       r⊥² = |x|² − (x·ω_s)²,

so the illuminated footprint is stretched by 1/cos θi along the plane of incidence and its
total power is P (under-filled sample). The radiance leaving x towards an observer at o is

    L(x → o) = f(θi, φi; θr(x), φr(x)) · E(x),      ω_r(x) = (o − x)/|o − x|,

with the angles of ω_s and ω_r(x) in the sample frame (conventions of
:mod:`analysis.brdf.geometry`). Every ray and every point of an aperture gets its own
direction: geometry is continuous, never an analysis grid. A camera looking at the sample
sees the footprint foreshortened by cos θr through its own projection.

Optional terms:

* ``target``: ``"sample"`` (the BRDF under test), ``"reference"`` (a reference standard,
  by default an ideal Lambertian of reflectance 0.99 — real PTFE deviates at large angles,
  EMRP xDReflect), or ``"none"`` (no sample: the beam passes through, which gives the
  instrument signature and the direct-beam power measurement).
* Instrument signature (stray light from the source optics, air scatter): a veiling
  radiance ``L_sig = f_sig(ψ) · E_peak`` added to every ray, with the BRDF-equivalent
  ``f_sig(ψ) = signature_sr / (1 + (ψ/ψ₀)²)`` (1/sr) of the angle ψ between the observer's
  direction from the sample and the forward beam, and E_peak = 2P/(πw²). On a point detector
  it contributes ``f_sig(ψ) · P · Ω``, the definition of a BRDF-equivalent signal.
* Ambient light: a uniform radiance added to every ray, source on or off (room light in
  the white-furnace approximation); removed by dark frames.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hw_mocks.sim.brdf_kernels import fixed_incidence
from hw_mocks.sim.state import WorldState

__all__ = ["BrdfFunction", "GoniometerScene", "aperture_rule", "brdf_from_model",
           "lambertian_brdf"]

#: The beam is cut where its intensity falls below 1e-16 of the peak (r⊥ > 4.3 w): no
#: sensor resolves it (a 10 s exposure of the peak's tail there collects < 1e-6 photons),
#: and it keeps the BRDF evaluation to the lit footprint.
BEAM_CUTOFF_W2 = 0.5 * math.log(1e16)


def aperture_rule(m: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nodes (K, 2) on the unit disk and weights (K,) summing to 1 (fractions of its area)
    for the mean of a smooth function over a disk; ``m`` as ``aperture_samples``.

    A product rule in polar coordinates (Stroud 1971, *Approximate Calculation of Multiple
    Integrals*, §2.7, S2: the disk): n = ⌈m/3⌉ Gauss–Legendre nodes in s = r² on [0, 1]
    (dA = π ds dφ/2 makes the radial weight constant in s) times 4n equally spaced angles
    (the trapezoidal rule, exact for trigonometric polynomials of degree < 4n). The
    monomial x^a y^b averages to zero over φ unless a and b are even, and then is
    s^((a+b)/2) times a constant (a, b even; odd degrees average to zero on every ring),
    so the rule is exact for polynomials of total degree ≤ 4n − 1: 11 at n = 3.

    Why not a square grid clipped to the disk (the rule before): its cells at the rim
    are either in or out, so its second moment misses the disk's by O(1/m²·⁵) and the
    mean of a curved integrand is biased by a few 10⁻⁶ (Lambert, 9 × 9) to 3·10⁻⁵ (a
    GGX α = 0.2 peak at 5 mm, 300 mm): as large as an SR830's relative noise over four
    snapshots, so the emulator's error showed in the lock-in's pulls.
    """
    rings = max(1, math.ceil(m / 3))
    x, w = np.polynomial.legendre.leggauss(rings)
    s, ws = 0.5 * (x + 1.0), 0.5 * w  # nodes and weights on [0, 1], Σ ws = 1
    k = 4 * rings
    # the rings' angles are staggered by half a step so no two nodes line up radially
    phi = 2.0 * math.pi * (np.arange(k)[None, :] + 0.5 * (np.arange(rings)[:, None] % 2)) / k
    r = np.sqrt(s)[:, None]
    nodes = np.stack([(r * np.cos(phi)).ravel(), (r * np.sin(phi)).ravel()], axis=-1)
    weights = np.repeat(ws / k, k)
    return nodes, weights


def _dot3(v: NDArray[np.float64], a: NDArray[np.float64]) -> NDArray[np.float64]:
    """v · a over the last axis of ``v`` (shape (..., 3)) with a fixed 3-vector ``a``."""
    return v[..., 0] * a[0] + v[..., 1] * a[1] + v[..., 2] * a[2]

#: f(θi, φi, θr, φr) in 1/sr; angles in radians, broadcasting arrays. A function may also
#: carry ``from_vectors(ω_i, ω_r)`` (unit vectors in the sample frame) or
#: ``from_components(ω_i, x_r, y_r, z_r)`` (ω_r by its components), which the renderer
#: prefers, and ``fixed_incidence`` (None or ω_i ↦ a function of ω_r's components in any
#: frame turned about the normal: an isotropic BRDF for one incidence), preferred to both.
BrdfFunction = Callable[[Any, Any, Any, Any], NDArray[np.float64]]


def brdf_from_model(name: str, params: Sequence[float] | Mapping[str, float] | None = None
                    ) -> BrdfFunction:
    """A ground-truth BRDF from the :mod:`analysis.brdf` registry.

    Parameters
    ----------
    name
        A registry name, e.g. ``"lambert"`` or ``"lambert+ggx"`` (Lambertian + Cook–Torrance
        with the GGX distribution and Smith masking).
    params
        Parameter vector in the model's order, or a mapping by parameter name (missing
        names take the model's start values); default the start values.
    """
    from analysis.brdf import get_model
    from analysis.brdf.geometry import MU_FLOOR, Geometry, geometry_from_vectors

    model = get_model(name)
    if params is None:
        vector = model.start
    elif isinstance(params, Mapping):
        unknown = set(params) - set(model.param_names)
        if unknown:
            raise ValueError(f"{name} has no parameters {sorted(unknown)}; "
                             f"it has {model.param_names}")
        vector = np.array([float(params.get(k, s))
                           for k, s in zip(model.param_names, model.start, strict=True)])
    else:
        vector = np.asarray(params, dtype=float)
        if vector.size != model.n_params:
            raise ValueError(f"{name} takes {model.n_params} parameters {model.param_names}")

    def brdf(theta_i, phi_i, theta_r, phi_r):
        return model.evaluate(vector, theta_i, phi_i, theta_r, phi_r)

    def from_vectors(omega_i, omega_r):
        # the same values from unit vectors in the sample frame (no angles in between:
        # the renderer has vectors, and arccos/sin/cos per ray cost more than the model)
        return model.evaluate_geometry(vector, geometry_from_vectors(omega_i, omega_r))

    def from_components(omega_i, rx, ry, rz):
        # from_vectors with ω_r given as its sample-frame components (unit already): the
        # renderer has them as separate arrays, and stacking, normalising and splitting
        # them again cost as much as the model
        wi = np.asarray(omega_i, dtype=float)
        wi = wi / np.linalg.norm(wi)
        shape = np.shape(rz)
        # ω_i is one direction: broadcast views of it, not arrays filled with it
        return model.evaluate_geometry(vector, Geometry(
            xi=np.broadcast_to(wi[0], shape), yi=np.broadcast_to(wi[1], shape),
            mu_i=np.broadcast_to(max(float(wi[2]), MU_FLOOR), shape),
            xr=rx, yr=ry, mu_r=np.maximum(rz, MU_FLOOR)))

    # attributes the scene reads, set on the function object
    brdf.from_vectors = from_vectors  # type: ignore[attr-defined]
    brdf.from_components = from_components  # type: ignore[attr-defined]
    # ω_i ↦ f(ω_r components) fused for one incidence, exact (hw_mocks.sim.brdf_kernels);
    # None where the model has a part without a kernel
    brdf.fixed_incidence = fixed_incidence(model, vector)  # type: ignore[attr-defined]
    brdf.model_name = name  # type: ignore[attr-defined]
    brdf.params = tuple(float(v) for v in vector)  # type: ignore[attr-defined]
    return brdf


def lambertian_brdf(reflectance: float) -> BrdfFunction:
    """f = ρ/π: the ideal diffuse reference standard."""
    if not 0.0 <= reflectance <= 1.0:
        raise ValueError("reflectance must lie in [0, 1]")
    value = reflectance / math.pi

    def brdf(theta_i, phi_i, theta_r, phi_r):
        return np.full(np.broadcast(theta_i, phi_i, theta_r, phi_r).shape, value)

    def from_vectors(omega_i, omega_r):
        return np.full(np.shape(omega_r)[:-1], value)

    def from_components(omega_i, rx, ry, rz):
        return np.full(np.shape(rz), value)

    def fixed_incidence(omega_i):
        return lambda rx, ry, rz: np.full(np.shape(rz), value)

    # attributes the scene reads, set on the function object
    brdf.from_vectors = from_vectors  # type: ignore[attr-defined]
    brdf.from_components = from_components  # type: ignore[attr-defined]
    brdf.fixed_incidence = fixed_incidence  # type: ignore[attr-defined]
    return brdf


@dataclass(frozen=True)
class GoniometerScene:
    """A flat sample (or reference, or nothing) under a collimated beam.

    Attributes
    ----------
    brdf : BrdfFunction or SpectralSample
        Ground truth of the sample, f(θi, φi, θr, φr) in 1/sr; an object with
        ``at_light(wavelength_nm, bandwidth_nm)`` (a
        :class:`~hw_mocks.sim.spectral_sample.SpectralSample`) gives the BRDF under the
        light that reaches the sample (camera, power meter and photodiode alike).
    sample_radius_mm : float
    target : {"sample", "reference", "none"}
    reference_brdf : BrdfFunction
        The reference standard's BRDF (default ideal Lambertian, ρ = 0.99).
    signature_sr : float
        Peak BRDF-equivalent instrument signature (1/sr); 0 disables it.
    signature_width_deg : float
        ψ₀ of the signature's Lorentzian fall-off.
    ambient_radiance : float
        Ambient radiance in W m⁻² sr⁻¹.
    spot_samples : int
        Grid points per side over the footprint for aperture integrals.
    aperture_samples : int
        Resolution of the quadrature over a detector aperture, as the points per side of
        the square grid it replaces: the scattered light is integrated with the polar
        Gauss rule of :func:`aperture_rule` (⌈m/3⌉ rings, 36 nodes at the default 9,
        where the clipped 9 × 9 grid had 69); the direct beam keeps an m × m grid.
    """

    brdf: BrdfFunction = field(default_factory=lambda: lambertian_brdf(0.5))
    sample_radius_mm: float = 12.5
    target: str = "sample"
    reference_brdf: BrdfFunction = field(default_factory=lambda: lambertian_brdf(0.99))
    signature_sr: float = 0.0
    signature_width_deg: float = 2.0
    ambient_radiance: float = 0.0
    spot_samples: int = 48
    aperture_samples: int = 9
    #: Fraction of the direct beam's power the detector reads (a polarisation analyser
    #: after a transmissive reference sample, :mod:`hw_mocks.sim.polarimetric_scene`);
    #: not a configuration key.
    direct_transmission: float = 1.0

    def __post_init__(self) -> None:
        if self.target not in ("sample", "reference", "none"):
            raise ValueError(f"target must be sample, reference or none, got {self.target!r}")
        if not self.sample_radius_mm > 0:
            raise ValueError("sample_radius_mm must be > 0")
        if self.signature_sr < 0 or self.ambient_radiance < 0:
            raise ValueError("signature_sr and ambient_radiance must be >= 0")

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> GoniometerScene:
        """From a plain dict: ``brdf`` (registry name, default "lambert"), ``params``
        (list or table), ``reference_reflectance``, and the dataclass fields by name.

        ``brdf = "spectral"`` with a ``spectral`` table makes the sample's BRDF depend on
        the light's wavelength (:meth:`hw_mocks.sim.spectral_sample.SpectralSample.
        from_config` lists its keys); a ``spectral`` table alone implies it.
        """
        cfg = dict(config)
        spectral = cfg.pop("spectral", None)
        name = cfg.pop("brdf", "spectral" if spectral is not None else "lambert")
        params = cfg.pop("params", None)
        if (name == "spectral") != (spectral is not None):
            raise ValueError('[simulation.scene] brdf = "spectral" goes with a '
                             "[simulation.scene.spectral] table (and that table with it)")
        if spectral is not None and params is not None:
            raise ValueError("[simulation.scene] a spectral sample takes its parameters from "
                             "[simulation.scene.spectral], not params")
        if params is None and name == "lambert":
            params = [0.5]
        reference = float(cfg.pop("reference_reflectance", 0.99))
        allowed = {"sample_radius_mm", "target", "signature_sr", "signature_width_deg",
                   "ambient_radiance", "spot_samples", "aperture_samples"}
        unknown = set(cfg) - allowed
        if unknown:
            raise ValueError(f"unknown scene keys {sorted(unknown)}")
        if spectral is not None:
            from hw_mocks.sim.spectral_sample import SpectralSample

            sample: Any = SpectralSample.from_config(spectral)
        else:
            sample = brdf_from_model(name, params)
        return cls(brdf=sample, reference_brdf=lambertian_brdf(reference), **cfg)

    @property
    def depth_extent_mm(self) -> float:
        """How far (mm) lit scene points can lie from the sample centre: a camera focused
        there sees them defocused by at most this depth (the sample's radius)."""
        return self.sample_radius_mm

    def lit_outlines(self, state: WorldState) -> tuple[NDArray[np.float64], ...] | None:
        """Where the scene sends more than its uniform veil (ambient + signature): lab
        point sets (K, 3), mm, each of whose convex hulls holds every lit point; None when
        nothing is lit (every ray sees the veil alone).

        The lit points are those of the sample disk inside the beam's cut-off
        (:data:`BEAM_CUTOFF_W2`), an ellipse of semi-axes √C·w/cos θi and √C·w in the
        beam-aligned sample coordinates of :meth:`radiance`. Both curves are given as
        circumscribed polygons (vertices at 1/cos(π/K) of the radius, an affine image of
        a polygon around the unit circle), so each hull contains its curve. A camera
        renders only the pixels whose rays can reach them."""
        pose = state.pose
        cos_i = float(pose.normal @ pose.source_dir)
        if (self._active_brdf(state) is None or cos_i <= 0.0
                or state.source.peak_intensity_w_m2() == 0.0):
            return None
        k = 64
        phi = 2.0 * math.pi * np.arange(k) / k
        c, s = np.cos(phi) / math.cos(math.pi / k), np.sin(phi) / math.cos(math.pi / k)
        s_loc = pose.to_sample(pose.source_dir)
        proj = math.hypot(s_loc[0], s_loc[1])
        eu = (s_loc[0] / proj, s_loc[1] / proj) if proj > 1e-12 else (1.0, 0.0)
        half = math.sqrt(BEAM_CUTOFF_W2) * state.source.beam_radius_mm
        up, vp = c * (half / cos_i), s * half
        ellipse = (up * eu[0] - vp * eu[1], up * eu[1] + vp * eu[0])
        disk = (c * self.sample_radius_mm, s * self.sample_radius_mm)
        x_s, y_s = pose.sample_axes[0], pose.sample_axes[1]
        return tuple(xy[0][:, None] * x_s + xy[1][:, None] * y_s for xy in (ellipse, disk))

    # helpers ------------------------------------------------------------------
    def _active_brdf(self, state: WorldState) -> BrdfFunction | None:
        if self.target == "sample":
            at_light = getattr(self.brdf, "at_light", None)
            if at_light is not None:
                # a spectral sample: its BRDF under the light that reaches it now
                # (centre and width of the band through the filter)
                return at_light(state.source.wavelength_nm, state.source.bandwidth_nm)
            return self.brdf
        if self.target == "reference":
            return self.reference_brdf
        return None

    def _signature(self, observer_dir: NDArray[np.float64], state: WorldState) -> float:
        """BRDF-equivalent signature f_sig(ψ) (1/sr) for an observer direction."""
        if self.signature_sr == 0.0 or not state.source.on:
            return 0.0
        forward = -state.pose.source_dir
        cos_psi = float(np.clip(np.dot(observer_dir, forward), -1.0, 1.0))
        psi = math.degrees(math.acos(cos_psi))
        return self.signature_sr / (1.0 + (psi / self.signature_width_deg) ** 2)

    def veil_radiance(self, origin_mm: NDArray[np.float64], state: WorldState) -> float:
        """The uniform veil (W m⁻² sr⁻¹) an observer at ``origin_mm`` sees along every ray:
        ambient light and the instrument signature. Both are incoherent (room light, and
        stray light from many paths), so a laser speckles only what the sample scatters
        (:mod:`hw_mocks.sim.speckle`)."""
        o = np.asarray(origin_mm, dtype=float)
        dist = math.sqrt(float(o @ o))  # (np.linalg.norm costs more than the rest here)
        observer_dir = o / dist if dist > 0 else state.pose.detector_dir
        peak = state.source.peak_intensity_w_m2()
        return self.ambient_radiance + self._signature(observer_dir, state) * peak

    @staticmethod
    def _beam_intensity(points: NDArray[np.float64], state: WorldState) -> NDArray[np.float64]:
        """Beam intensity (W/m², perpendicular to the beam) at lab points (mm), shape (...)."""
        peak = state.source.peak_intensity_w_m2()
        if peak == 0.0:
            return np.zeros(points.shape[:-1])
        along = points @ state.pose.source_dir
        r2 = np.maximum(np.einsum("...k,...k->...", points, points) - along * along, 0.0)
        w2 = state.source.beam_radius_mm ** 2
        return np.where(r2 <= BEAM_CUTOFF_W2 * w2, peak * np.exp(-2.0 * r2 / w2), 0.0)

    # Scene protocol ------------------------------------------------------------
    def radiance(
        self, origin_mm: NDArray[np.float64], directions: NDArray[np.float64],
        state: WorldState,
    ) -> NDArray[np.float64]:
        """Radiance (W m⁻² sr⁻¹) seen from ``origin_mm`` along unit ``directions``
        (shape (..., 3), pointing away from the observer), shape (...)."""
        d = np.asarray(directions, dtype=float)
        return self.radiance_projected(origin_mm, lambda a: _dot3(d, a), d.shape[:-1],
                                       state)

    def radiance_projected(
        self, origin_mm: NDArray[np.float64],
        project: Callable[[NDArray[np.float64]], NDArray[np.float64]],
        shape: tuple[int, ...], state: WorldState,
    ) -> NDArray[np.float64]:
        """:meth:`radiance` along rays given by their projections: ``project(a)`` is
        d · a, shape ``shape``, for a lab vector a (a camera has its rays' components on
        its own axes, and projects them without building the (..., 3) directions)."""
        pose = state.pose
        o = np.asarray(origin_mm, dtype=float)
        n = pose.normal
        peak = state.source.peak_intensity_w_m2()
        veil = self.veil_radiance(o, state)
        brdf = self._active_brdf(state)
        cos_i = float(n @ pose.source_dir)
        height = float(o @ n)
        if brdf is None or cos_i <= 0.0 or peak == 0.0 or height <= 0.0:
            # nothing lit, or we look at the back of the sample
            return np.full(shape, veil, dtype=float)
        x_s, y_s = pose.sample_axes[0], pose.sample_axes[1]
        # The beam-aligned sample axes (e_u along the beam's projection on the sample,
        # e_v across it): on the plane, r⊥² = u'² cos²θi + v'² in these coordinates.
        s_loc = pose.to_sample(pose.source_dir)
        proj = math.hypot(s_loc[0], s_loc[1])
        eu = (s_loc[0] / proj, s_loc[1] / proj) if proj > 1e-12 else (1.0, 0.0)
        e_u = eu[0] * x_s + eu[1] * y_s
        e_v = eu[0] * y_s - eu[1] * x_s
        w2 = state.source.beam_radius_mm ** 2
        # Towards the observer, −d, on the normal and the beam-aligned axes (the ray meets
        # the plane at x = o − t·(−d), t = height / (−d)·n, in front of the observer where
        # (−d)·n > 0), by the rays' projections: a (..., 3) @ (3,) product is several times
        # slower in numpy for large ray bundles.
        lz, lu, lv = project(-n), project(-e_u), project(-e_v)
        # (rays along the plane or away from it give ±inf or NaN here, and are not lit)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t = np.divide(height, lz)
            up = t * lu
            np.subtract(float(o @ e_u), up, out=up)
            vp = t * lv
            np.subtract(float(o @ e_v), vp, out=vp)
            up *= up
            vp *= vp
            r_perp2 = up * (cos_i * cos_i)
            r_perp2 += vp
            up += vp
            lit = up <= self.sample_radius_mm**2
            lit &= lz > 0.0
            lit &= r_perp2 <= BEAM_CUTOFF_W2 * w2
        n_lit = int(np.count_nonzero(lit))
        if n_lit == 0:
            return np.full(shape, veil, dtype=float)
        every = n_lit == lit.size  # the common case of a pupil's rays onto the footprint
        if not every:
            r_perp2, lz, lu, lv = r_perp2[lit], lz[lit], lu[lit], lv[lit]
        irradiance = np.multiply(r_perp2, -2.0 / w2, out=r_perp2)
        np.exp(irradiance, out=irradiance)
        values = self._brdf_values(brdf, pose, (e_u, e_v, n), lu, lv, lz)
        values *= irradiance
        values *= peak * cos_i
        if every:
            if veil != 0.0:
                values += veil
            return values
        out = np.full(shape, veil, dtype=float)
        out[lit] += values
        return out

    @staticmethod
    def _brdf_values(brdf: BrdfFunction, pose, frame: tuple[NDArray, NDArray, NDArray],
                     lu: NDArray, lv: NDArray, lz: NDArray) -> NDArray[np.float64]:
        """f(ω_i, ω_r) for ω_r given by its components (lu, lv, lz) on the beam-aligned
        sample axes ``frame`` = (e_u, e_v, n); a new array."""
        fixed = getattr(brdf, "fixed_incidence", None)
        if fixed is not None:  # isotropic: the beam-aligned frame will do
            s = pose.source_dir
            return fixed(np.array([s @ frame[0], s @ frame[1], s @ frame[2]]))(lu, lv, lz)
        # the sample frame's x and y from the beam-aligned components
        x_s, y_s = pose.sample_axes[0], pose.sample_axes[1]
        cu, su = float(frame[0] @ x_s), float(frame[0] @ y_s)
        lx = cu * lu - su * lv
        ly = su * lu + cu * lv
        s_loc = pose.to_sample(pose.source_dir)
        from_components = getattr(brdf, "from_components", None)
        from_vectors = getattr(brdf, "from_vectors", None)
        if from_components is not None:
            return np.array(from_components(s_loc, lx, ly, lz), dtype=float)
        if from_vectors is not None:
            return np.array(from_vectors(s_loc, np.stack([lx, ly, lz], axis=-1)),
                            dtype=float)
        ti, pi = pose.local_angles(pose.source_dir)
        tr = np.arccos(np.clip(lz, -1.0, 1.0))
        pr = np.arctan2(ly, lx)
        return np.array(brdf(float(ti), float(pi), tr, pr), dtype=float)

    def power_on_aperture(
        self, center_mm: NDArray[np.float64], facing: NDArray[np.float64],
        diameter_mm: float, state: WorldState,
    ) -> float:
        """Power (W) on a disk aperture: scattered light integrated over the footprint and
        the aperture (a grid and a Gauss rule), the direct beam where nothing blocks it,
        ambient light over the hemisphere, and the instrument signature."""
        pose = state.pose
        c = np.asarray(center_mm, dtype=float)
        f = np.asarray(facing, dtype=float)
        f = f / np.linalg.norm(f)
        radius = 0.5 * diameter_mm
        aperture_area_m2 = math.pi * (radius * 1e-3) ** 2
        # Aperture axes e1, e2 on the plane ⟂ f; the scattered light's nodes come from
        # aperture_rule, the direct beam's from a square grid clipped to the disk (the
        # beam's edge and the sample's shadow are not smooth, which a Gauss rule needs).
        e1 = np.cross(f, [0.0, 1.0, 0.0])
        if np.linalg.norm(e1) < 1e-9:
            e1 = np.cross(f, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(f, e1)

        def disk_points(m: int) -> NDArray[np.float64]:
            g = ((np.arange(m) + 0.5) / m * 2.0 - 1.0) * radius
            gu, gv = np.meshgrid(g, g, indexing="ij")
            inside = gu**2 + gv**2 <= radius**2
            return c + gu[inside][:, None] * e1 + gv[inside][:, None] * e2

        unit_nodes, a_weights = aperture_rule(self.aperture_samples)
        a_pts = (c + radius * unit_nodes[:, :1] * e1 + radius * unit_nodes[:, 1:] * e2)

        power = 0.0
        # Ambient radiance over the hemisphere in front of the head: π L A.
        power += math.pi * self.ambient_radiance * aperture_area_m2
        if not state.source.on:
            return power
        p_in = state.source.power_w
        dist = float(np.linalg.norm(c))
        observer_dir = c / dist if dist > 0 else pose.detector_dir
        omega = aperture_area_m2 / (dist * 1e-3) ** 2 if dist > 0 else 0.0
        power += self._signature(observer_dir, state) * p_in * omega

        n = pose.normal
        cos_i = float(n @ pose.source_dir)
        brdf = self._active_brdf(state)
        # Direct beam: aperture points whose ray back towards the source misses the sample.
        if float(f @ pose.source_dir) > 0.0:
            # The beam is narrow: sample the aperture finely enough to resolve it (w/8).
            m = min(max(self.aperture_samples,
                        math.ceil(8.0 * diameter_mm / state.source.beam_radius_mm)), 256)
            b_pts = disk_points(m)
            db = aperture_area_m2 / b_pts.shape[0]
            blocked = np.zeros(b_pts.shape[0], dtype=bool)
            if brdf is not None:
                sn = float(pose.source_dir @ n)
                if abs(sn) > 1e-12:
                    t = -(b_pts @ n) / sn
                    hit = b_pts + t[:, None] * pose.source_dir
                    loc = pose.to_sample(hit)
                    blocked = (t > 0) & (loc[:, 0] ** 2 + loc[:, 1] ** 2
                                         <= self.sample_radius_mm**2)
            downstream = b_pts @ pose.source_dir < 0.0
            beam = self._beam_intensity(b_pts, state) * float(f @ pose.source_dir)
            direct = float(np.sum(np.where(~blocked & downstream, beam, 0.0)) * db)
            power += direct if self.direct_transmission == 1.0 \
                else direct * self.direct_transmission
        if brdf is None or cos_i <= 0.0 or float(c @ n) <= 0.0:
            return power
        # Scattered light: footprint grid in sample coordinates aligned with the beam.
        s_loc = pose.to_sample(pose.source_dir)
        proj = np.hypot(s_loc[0], s_loc[1])
        eu = np.array([s_loc[0], s_loc[1]]) / proj if proj > 1e-12 else np.array([1.0, 0.0])
        ev = np.array([-eu[1], eu[0]])
        w = state.source.beam_radius_mm
        half_u = min(3.2 * w / max(cos_i, 1e-3), self.sample_radius_mm)
        half_v = min(3.2 * w, self.sample_radius_mm)
        k = self.spot_samples
        gu = ((np.arange(k) + 0.5) / k * 2.0 - 1.0) * half_u
        gv = ((np.arange(k) + 0.5) / k * 2.0 - 1.0) * half_v
        uu, vv = np.meshgrid(gu, gv, indexing="ij")
        xs = uu * eu[0] + vv * ev[0]
        ys = uu * eu[1] + vv * ev[1]
        on_sample = xs**2 + ys**2 <= self.sample_radius_mm**2
        axes = pose.sample_axes
        spot = xs[on_sample][:, None] * axes[0] + ys[on_sample][:, None] * axes[1]
        da_spot = (2 * half_u / k) * (2 * half_v / k) * 1e-6
        irradiance = self._beam_intensity(spot, state) * cos_i
        keep = irradiance > 1e-12 * irradiance.max()
        spot, irradiance = spot[keep], irradiance[keep]
        vec = a_pts[None, :, :] - spot[:, None, :]  # spot → aperture, mm
        r2 = np.einsum("ijk,ijk->ij", vec, vec)
        r = np.sqrt(r2)
        unit = vec / r[..., None]
        cos_r = unit @ n
        cos_a = -(unit @ f)
        fixed = getattr(brdf, "fixed_incidence", None)
        if fixed is not None:  # the same values from the vectors (no angles in between)
            loc = pose.to_sample(unit)
            values = fixed(pose.to_sample(pose.source_dir))(
                loc[..., 0], loc[..., 1], loc[..., 2])
        else:
            tr, pr = pose.local_angles(unit)
            ti, pi = pose.local_angles(pose.source_dir)
            values = np.asarray(brdf(float(ti), float(pi), tr, pr), dtype=float)
        integrand = (values * irradiance[:, None] * np.clip(cos_r, 0.0, None)
                     * np.clip(cos_a, 0.0, None) / (r2 * 1e-6))
        power += float((integrand @ a_weights).sum() * da_spot * aperture_area_m2)
        return power
