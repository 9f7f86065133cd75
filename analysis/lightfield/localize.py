"""Localisation of hidden objects from a reconstructed light field (Sasaki 2020, ch. 3).

Input is the reconstructed incident light field at the wall, ``L(c, θ)`` (z = 0; objects at
z < 0).  A trial point (y, z) collects the rays ``L(y − z tan θ, θ)`` (a shear, S1).

* Conventional refocusing: ``I(y, z) = (1/(B − A)) Σ_j L(y − z tan θ_j, θ_j) Δθ`` over the
  solvable angle domain [A, B] (rays that miss the wall count as 0).
* Radiance-preserving (RP) refocusing: the same sum divided by the angular measure of the
  rays through (y, z) that lie inside the solvable domain *and* hit the measured wall, so a
  point source's peak equals its radiance wherever it sits.
* Matched filter (derivation ours, tested in tests/analysis/lightfield): a point source
  at (y, z) is reconstructed as ``L_m(c, θ) = K(θ − θ*(c))/cos θ`` (:func:`point_response`,
  K the filtered delta of the filter factors φ_p).  The data are the rays inside the
  solvable domain [A, B]; the inner product of their ``g = L cos θ`` with the model is,
  row by row, ``H(c, θ*(c))`` with ``H(c, ·) = Σ_{θ ∈ [A, B]} g(c, θ) K(θ − ·)`` (the
  masked row filtered by φ), and the model's squared norm ``k2(θ*) = Σ_{θ ∈ [A, B]}
  K(θ − θ*)²``.  Summing over the wall rows with ``dc = |z| dθ/cos² θ`` gives
  ``|z| Σ_j H(y − z tan θ_j, θ_j)/cos² θ_j Δθ`` over ``(|z| Σ_{j available}
  k2(θ_j)/cos² θ_j Δθ)^½``: the normalised matched filter, the maximum-likelihood
  statistic of one point source of unknown radiance in white noise.  Every trial point
  is scored on the same set of rays, so by Cauchy–Schwarz its column peaks at the true
  depth — also where the solvable domain, not the wall, limits the aperture.  (Without
  the mask and the kernel overlap — ``K`` taken as a projector, H ≈ g — it reduces to
  conventional refocusing weighted by ``|z|/cos θ``, what :func:`refocus` returns without
  ``filter_factors``; that form leans 0.2–0.3 δz away from the wall when the domain
  limits the aperture.)  The
  plain conventional stack peaks nearer the wall: its height scales as W/|z|.
* Depth filter on the mixed (p_y, z) plane: around each object the (matched-filter
  numerator) stack is windowed in y (which removes the interference of objects at similar
  z but different y), Fourier transformed along y, and the normalised z-profiles
  ``|Î_z(p_y)|/max_z`` of the spatial frequencies p_y that the reconstruction supports are
  multiplied; the product peaks at the object's depth and is narrower than any single
  profile.  For a point at depth z0 and small angles,
  ``Î_z(p_y) ∝ sinc(p_y W (1 − z/z0)) · K̂(p_y |z|)``: the aperture term peaks at z0, and
  the angular transfer function K̂ (flat up to the cut-off ``(P + ½)/(B − A)`` cycles/rad)
  is unbiased only where it is flat.  A frequency above ``(P + ½)/((B − A)|z0|) = 1/(2 δy)``
  has signal only at trial depths nearer the wall (where ``p_y |z|`` is below the cut-off),
  so its profile peaks there: a band reaching 1/δy pulled the product ≈ 0.3 δz (P = 18)
  to 0.6 δz (P = 5) towards the wall.  The band therefore ends at 1/(2 δy), and the window
  (half-width 3 δy) keeps the defocused spots of nearby trial depths whole.
* Theoretical resolution from the highest recovered angular order p̂_max: angular blur
  ``δθ = (b − a)/(2 p̂_max + 1)`` (first zero of the Dirichlet kernel of the truncated
  Fourier series), transverse ``δy = D δθ / cos² θ̄``, depth ``δz = D² δθ / W`` with D the
  distance from the wall and W the wall aperture seen inside the solvable domain
  (triangulation: two rays with slopes ±W/2D crossing at D).  Triangulation measures the
  inverse distance, ``δ(1/D) = δθ/W``, so the compatible depth interval is symmetric in 1/D
  and has no far end when ``δz ≥ D`` (:func:`depth_interval`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .field import LightField2D, LightField4D
from .propagate import project_4d, propagate_4d, sample_columns
from .ray_fit import JointFit as _JointFit
from .ray_fit import fit_points as _fit_points
from .ray_fit import ray_model as _ray_model
from .wall_samples import SamplePlan, ray_sums

__all__ = [
    "BLEND_WIDTH_RATIO",
    "QUALITY_FLAGS",
    "Detection",
    "FocalStack",
    "Resolution",
    "depth_interval",
    "depth_profile",
    "detect_objects",
    "effective_p_max",
    "point_response",
    "refocus",
    "refocus_4d",
    "theoretical_resolution",
]


@dataclass(frozen=True)
class FocalStack:
    """Refocused images over a (y, z) grid.

    Attributes
    ----------
    y_mm : (N_y,), z_mm : (N_z,) — the grid (z < 0 in front of the wall)
    conventional : (N_z, N_y) — mean radiance over the full solvable domain
    radiance_preserving : (N_z, N_y) — mean over the rays actually available (0 where none)
    measure_rad : (N_z, N_y) — angular measure of the available rays
    solvable_domain_rad : (A, B)
    matched_filter : (N_z, N_y) — the normalised matched-filter (point-source likelihood)
        statistic of :func:`refocus` (module doc), in radiance·mm^½; empty (0, 0) when the
        stack was assembled by hand
    """

    y_mm: NDArray[np.float64]
    z_mm: NDArray[np.float64]
    conventional: NDArray[np.float64]
    radiance_preserving: NDArray[np.float64]
    measure_rad: NDArray[np.float64]
    solvable_domain_rad: tuple[float, float]
    matched_filter: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))


def _filtered_masked(
    lf_wall: LightField2D, use: NDArray[np.bool_], phi: NDArray[Any]
) -> tuple[NDArray[Any], NDArray[Any]]:
    """Data and model norms of the exact matched filter (module doc).

    Returns ``H`` (R, N): each row's ``g = L cos θ`` restricted to the solvable domain and
    filtered by φ (``H(c, θ') = Σ_{θ ∈ [A, B]} g(c, θ) K(θ − θ')``), and ``k2`` (N,): the
    squared norm of a point's kernel over the same rays, ``Σ_{θ ∈ [A, B]} K(θ − θ')²``.
    """
    from .spectral import coefficients, synthesize

    th = lf_wall.theta_rad
    g = np.asarray(lf_wall.radiance, dtype=float) * np.cos(th)[None, :]
    h = synthesize(coefficients(np.where(use[None, :], g, 0.0), axis=-1) * phi,
                   axis=-1).real
    kernel = synthesize(coefficients(np.eye(th.size), axis=-1) * phi, axis=-1).real
    k2 = (kernel[use] ** 2).sum(axis=0)
    return h, k2


def _stacks(
    lf_wall: LightField2D, y: NDArray[Any], zs: NDArray[Any], a: float, b: float,
    phi: NDArray[Any] | None = None, *, dense: bool = False,
    geometry: tuple[NDArray[Any], NDArray[Any]] | None = None,
    plan: SamplePlan | None = None,
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]:
    """One pass over the sheared samples: conventional, RP, measure, MF numerator, MF norm.

    On an increasing y grid the sums run over the rays that meet the wall only
    (:mod:`.wall_samples`; equal to rounding); ``dense`` (or any other grid) samples every
    (y, ray) pair, as the reference.  ``geometry`` (the measure and the MF norm of an
    earlier call on the same grid, rays and filter: they do not depend on the field) saves
    their sums; it is returned as given.  ``plan`` (:func:`_sample_plan` of the same grid,
    rays and filter; with ``phi`` and ``geometry``) takes the samples' sums as sparse
    products (:class:`.wall_samples.SamplePlan`: the same sums, to rounding).

    Without ``phi`` the matched-filter numerator is the line-sample form
    ``|z| Σ_{j ∈ [A, B]} L(y − z tan θ_j, θ_j)/cos θ_j Δθ`` with the squared norm
    ``|z| Σ_{j available} Δθ/cos² θ_j``; with the filter factors ``phi`` (N,) it is the
    exact inner product over the fixed set of rays inside [A, B] (module doc).
    """
    th = lf_wall.theta_rad
    use = (th >= a) & (th <= b)
    n_use = int(np.count_nonzero(use))
    vals = np.asarray(lf_wall.radiance, dtype=float)[:, use]
    sec2 = 1.0 / np.cos(th) ** 2
    if phi is None:
        t = np.tan(th[use])
        mf_w = sec2[use]
        k2 = np.ones(n_use)
        cols = vals
    else:
        h, k2 = _filtered_masked(lf_wall, use, phi)
        # rays whose kernel barely overlaps [A, B] add nothing but cost
        keep = k2 >= 1e-3 * k2.max()
        k2 = k2[keep]
        t = np.concatenate([np.tan(th[use]), np.tan(th[keep])])
        mf_w = sec2[keep]
        cols = np.concatenate([vals, h[:, keep]], axis=1)
    dth = lf_wall.dtheta_rad
    full = max(n_use * dth, dth)
    lo, hi = lf_wall.y_mm[0], lf_wall.y_mm[-1]
    shape = (zs.size, y.size)
    conv, rp, meas, num, norm2 = (np.empty(shape) for _ in range(5))
    if plan is not None and phi is not None and geometry is not None:
        # a point-response model on the data's geometry: one sparse product per depth
        total, s_mf = plan.sums(vals, cols[:, n_use:] * mf_w[None, :])
        total = total * dth
        meas, norm2 = geometry
        conv = total / full
        rp = np.where(meas > 0, total / np.where(meas > 0, meas, 1.0), 0.0)
        num = np.abs(zs)[:, None] * s_mf * dth
        return conv, rp, meas, num, norm2
    if _on_runs(lf_wall, y, dense):
        # the same sums over the rays that meet the wall only (.wall_samples)
        n_c = cols.shape[1]
        first = (np.arange(n_c) < n_use).astype(float)
        if phi is None:
            mf_s, mf_h = np.cos(th[use]) * mf_w, k2 * mf_w
        else:
            mf_s = np.concatenate([np.zeros(n_use), mf_w])
            mf_h = np.concatenate([np.zeros(n_use), k2 * mf_w])
        u = np.vstack([first, mf_s])
        # the measure and the model norm depend on the grid and the rays alone
        v = np.vstack([first, mf_h]) if geometry is None else np.zeros((0, n_c))
        for i, z in enumerate(zs):
            (total, s_mf), hits = ray_sums(cols, lo, lf_wall.dy_mm, y, float(z), t, hi,
                                           u, v)
            total = total * dth
            if geometry is None:
                meas[i] = hits[0] * dth
                norm2[i] = abs(z) * hits[1] * dth
            else:
                meas[i], norm2[i] = geometry[0][i], geometry[1][i]
            m = meas[i]
            conv[i] = total / full
            rp[i] = np.where(m > 0, total / np.where(m > 0, m, 1.0), 0.0)
            num[i] = abs(z) * s_mf * dth
        return conv, rp, meas, num, norm2
    for i, z in enumerate(zs):
        q = y[:, None] - z * t[None, :]
        s = sample_columns(cols, lo, lf_wall.dy_mm, q, method="linear")
        ok = (q >= lo) & (q <= hi)
        total = s[:, :n_use].sum(axis=1) * dth
        m = ok[:, :n_use].sum(axis=1) * dth
        conv[i] = total / full
        rp[i] = np.where(m > 0, total / np.where(m > 0, m, 1.0), 0.0)
        meas[i] = m
        if phi is None:
            num[i] = abs(z) * ((s * np.cos(th[use])[None, :]) @ mf_w) * dth
            norm2[i] = abs(z) * (ok @ (k2 * mf_w)) * dth
        else:
            num[i] = abs(z) * (s[:, n_use:] @ mf_w) * dth
            norm2[i] = abs(z) * (ok[:, n_use:] @ (k2 * mf_w)) * dth
    return conv, rp, meas, num, norm2


#: Memory the models' sample plan (:class:`.wall_samples.SamplePlan`) may take; beyond it
#: the models are summed over the runs as the data are (the same answer, ≈ 5× the CPU).
#: The issue's case at n_theta 1024 on the default search takes 1.5 GB.
SAMPLE_PLAN_MAX_BYTES = 4 * 2**30


def _on_runs(lf_wall: LightField2D, y: NDArray[Any], dense: bool = False) -> bool:
    """Whether :func:`_stacks` sums over the rays' runs of trial points (an increasing
    grid, a wall of more than one row)."""
    return bool(not dense and y.size > 1 and np.all(np.diff(y) > 0)
                and lf_wall.y_mm.size > 1)


def _sample_plan(lf_wall: LightField2D, y: NDArray[Any], zs: NDArray[Any], a: float,
                 b: float, phi: NDArray[Any]) -> SamplePlan | None:
    """The samples of :func:`_stacks` with the filter ``phi`` as sparse matrices, for the
    fields on ``lf_wall``'s rows and angles (the columns of :func:`_stacks`: the rays in
    [A, B], then the filter's rays); None where :func:`_stacks` takes its reference path."""
    if not _on_runs(lf_wall, y):
        return None
    th = lf_wall.theta_rad
    use = (th >= a) & (th <= b)
    _, k2 = _filtered_masked(lf_wall, use, phi)
    keep = k2 >= 1e-3 * k2.max()
    t = np.concatenate([np.tan(th[use]), np.tan(th[keep])])
    return SamplePlan.build(lf_wall.y_mm.size, int(np.count_nonzero(use)), lf_wall.y_mm[0],
                            lf_wall.dy_mm, y, zs, t, lf_wall.y_mm[-1],
                            max_bytes=SAMPLE_PLAN_MAX_BYTES)


def _normalised(num: NDArray[Any], norm2: NDArray[Any]) -> NDArray[Any]:
    """Matched-filter numerator over the model norm (0 where no ray is available)."""
    return np.where(norm2 > 0, num / np.sqrt(np.where(norm2 > 0, norm2, 1.0)), 0.0)


def refocus(
    lf_wall: LightField2D,
    *,
    y_mm: ArrayLike,
    z_mm: ArrayLike,
    solvable_domain_rad: tuple[float, float] | None = None,
    filter_factors: ArrayLike | None = None,
) -> FocalStack:
    """Conventional, radiance-preserving and matched-filter refocusing of the wall's field.

    ``lf_wall`` is the reconstructed incident field at z = 0 (rows: wall points c);
    ``y_mm`` (N_y,), ``z_mm`` (N_z,) the trial grid; the solvable domain defaults to the
    field's whole angle domain.  With the reconstruction's ``filter_factors`` (N,) (fftfreq
    order) the matched filter is the exact inner product over the rays in the solvable
    domain; without, its projector form (module doc).
    """
    y = np.asarray(y_mm, dtype=float)
    zs = np.atleast_1d(np.asarray(z_mm, dtype=float))
    a, b = lf_wall.domain_rad if solvable_domain_rad is None else solvable_domain_rad
    phi = (None if filter_factors is None
           else np.atleast_2d(np.asarray(filter_factors, dtype=float)).mean(axis=0))
    conv, rp, meas, num, norm2 = _stacks(lf_wall, y, zs, a, b, phi)
    return FocalStack(y, zs, conv, rp, meas, (float(a), float(b)), _normalised(num, norm2))


def refocus_4d(
    lf: LightField4D, z_mm: float, *, method: str = "fourier"
) -> NDArray[np.float64]:
    """Conventional refocus of a 4-D field at depth z: shear by z, then the angular mean.

    Returns the image of shape (N_x, N_y) (radiance averaged over the angle domains).
    """
    # method: a str checked by propagate_4d itself (ValueError), not narrowed to its Literal
    moved = propagate_4d(lf, z_mm, method=method)  # type: ignore[arg-type]
    area = (lf.u_domain_rad[1] - lf.u_domain_rad[0]) * (lf.v_domain_rad[1] - lf.v_domain_rad[0])
    return project_4d(moved) / area


@dataclass(frozen=True)
class Resolution:
    """Theoretical resolution of a localisation (Sasaki 2020, ch. 3; derivation in
    the module docstring).

    Attributes
    ----------
    transverse_mm, depth_mm : blur widths (first zero of the angular Dirichlet kernel)
    angular_rad : δθ = (b − a)/(2 p̂_max + 1)
    p_max : float — the highest recovered angular order p̂_max
    distance_mm : D, object distance from the wall
    aperture_mm : W, the wall width used
    """

    transverse_mm: float
    depth_mm: float
    angular_rad: float
    p_max: float
    distance_mm: float
    aperture_mm: float


def effective_p_max(filter_factors: ArrayLike, orders: ArrayLike) -> float:
    """p̂_max of a filter: the highest |p| whose filter factor is at least ½ (half power).

    A truncation at P gives exactly P; for a smooth (Wiener, Tikhonov) filter this is its
    cut-off order.  ``filter_factors`` (K,) or (R, K) (averaged over points), ``orders``
    (K,) the Fourier orders (or mode levels) of the factors; −1 when nothing passes.
    """
    phi = np.atleast_2d(np.asarray(filter_factors, dtype=float)).mean(axis=0)
    p = np.abs(np.asarray(orders))
    passed = p[phi >= 0.5]
    return float(passed.max()) if passed.size else -1.0


def theoretical_resolution(
    p_max: float,
    *,
    domain_rad: tuple[float, float],
    distance_mm: float,
    aperture_mm: float,
    solvable_domain_rad: tuple[float, float] | None = None,
    mean_angle_rad: float = 0.0,
) -> Resolution:
    """δθ, δy and δz from p̂_max, the distance D, the wall aperture W (see module doc).

    W is capped at the wall width seen from D inside the solvable domain,
    ``D (tan B − tan A)``.
    """
    a, b = domain_rad
    dtheta = (b - a) / (2.0 * max(p_max, 0.0) + 1.0)
    d = abs(float(distance_mm))
    sa, sb = solvable_domain_rad or domain_rad
    w = min(float(aperture_mm), d * (np.tan(sb) - np.tan(sa)))
    dy = d * dtheta / np.cos(mean_angle_rad) ** 2
    dz = d * d * dtheta / max(w, 1e-12)
    return Resolution(float(dy), float(dz), float(dtheta), float(p_max), d, float(w))


def depth_profile(
    stack: FocalStack,
    y_center_mm: float,
    *,
    window_halfwidth_mm: float,
    max_frequency_per_mm: float,
    min_frequency_per_mm: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Depth filter on the (p_y, z) plane around one object (module doc).

    The conventional focal stack is multiplied by a Hann window of half-width
    ``window_halfwidth_mm`` centred on ``y_center_mm`` (this suppresses the other objects),
    Fourier transformed along y, and the normalised z-profiles of the spatial frequencies
    in ``(min, max]`` are multiplied.

    Returns
    -------
    profile : (N_z,) — the geometric mean of the normalised profiles (peak 1; its argmax is
        that of their product)
    frequencies_per_mm : the spatial frequencies used
    """
    y = stack.y_mm
    dy = float(y[1] - y[0])
    u = (y - y_center_mm) / window_halfwidth_mm
    win = np.where(np.abs(u) < 1, 0.5 * (1 + np.cos(np.pi * u)), 0.0)
    img = stack.conventional * win[None, :]
    n_pad = int(2 ** np.ceil(np.log2(4 * y.size)))
    spec = np.abs(np.fft.rfft(img, n=n_pad, axis=1))
    f = np.fft.rfftfreq(n_pad, d=dy)
    band = (f > min_frequency_per_mm) & (f <= max_frequency_per_mm)
    if not np.any(band):
        band = f == f[1]
    prof = spec[:, band]
    peak = prof.max(axis=0, keepdims=True)
    prof = prof / np.where(peak > 0, peak, 1.0)
    logp = np.log(np.clip(prof, 1e-300, None)).mean(axis=1)
    # float64 both: numpy's stubs widen rfftfreq's and the mean's dtypes
    return np.exp(logp), f[band]  # type: ignore[return-value]


def depth_interval(
    z_mm: float, resolution: Resolution, *, limit_mm: float = -np.inf
) -> tuple[float, float]:
    """The depths compatible with an estimate ``z_mm`` within one depth resolution.

    Triangulation measures the inverse distance 1/D (the difference of the ray angles
    across the aperture W is W/D), with the uncertainty ``δ(1/D) = δθ/W = δz/D²``
    (module doc); so the interval is symmetric in 1/D and asymmetric in z:
    ``1/D ∈ [1/D − δz/D², 1/D + δz/D²]``.  Its far end is unbounded when
    ``δz ≥ D`` (the parallax across the aperture is below one angular blur); it is then
    clipped to ``limit_mm`` (e.g. the far end of the searched range).

    Returns
    -------
    (far, near) : z bounds in mm, ``far ≤ z_mm ≤ near < 0``
    """
    d = max(abs(float(z_mm)), 1e-12)
    k = resolution.depth_mm / (d * d)
    near = 1.0 / (1.0 / d + k)
    far = 1.0 / (1.0 / d - k) if 1.0 / d > k else np.inf
    return float(max(-far, limit_mm)), float(-near)


#: Quality flags of a detection's depth (see :func:`detect_objects`).
QUALITY_FLAGS = ("resolved", "two_estimates_agree", "unresolved", "extended")


@dataclass(frozen=True)
class Detection:
    """Objects found in a reconstructed light field.

    Attributes
    ----------
    count : int
    positions_mm : (count, 2) — (y, z) of each object; z is the median of the three depth
        estimates (``depth_estimates_mm``); for a depth flagged "unresolved" it is only a
        best guess, read ``depth_interval_mm`` instead
    brightness_rp : (count,) — RP-refocused radiance at the object
    brightness_conventional : (count,) — conventional refocused value there
    resolutions : tuple of Resolution — the theoretical blur at each object
    stack : FocalStack — the focal stack used
    depth_profiles : (count, N_z) — the depth-filter profile of each object
    depth_interval_mm : (count, 2) — (far, near) z bounds: the depths within one depth
        resolution (:func:`depth_interval`), widened to hold all three estimates and the
        span where the fitted point response's matched-filter column stays above half
        its peak (≈ 2.4 δz/D² either side in inverse depth); where the searched region
        ends inside it, opened to the end of the searched z range (and flagged)
    quality : tuple of str — per object, one of :data:`QUALITY_FLAGS`:
        "resolved" (the depth filter, the matched filter and the RP peak agree pairwise
        within one inverse-depth resolution), "two_estimates_agree" (one of them does not),
        "unresolved" (no two agree, the interval runs out of the searched region, or the
        detection is a blend wider than one point's response), "extended" (several point
        components within :data:`EXTENDED_RANGE` resolution cells whose rays a uniform
        segment explains as well as two points do, :mod:`.extended`: one object larger
        than the blur, its size in ``extent_mm``)
    depth_estimates_mm : (count, 3) — z from the depth filter, the matched filter and the
        RP stack (the evidence behind the flag)
    depth_open : (count, 2) bool — the (far, near) end of the interval is open: the searched
        region ends inside it, the object may lie beyond (the stored bound is the search
        edge, not a measured one)
    significance : (count,) — amplitude over its standard deviation (σ; NaN without a
        noise model), objects in decreasing order of it
    false_alarm : (count,) — per-scan probability that noise alone gives a peak this
        significant anywhere in the searched region (the expected Euler characteristic of
        the excursion above σ, :mod:`.excursion`; ``resolution_cells × Q(σ)`` without a
        noise model)
    threshold_sigma : float — the significance an object needed (NaN without noise model)
    resolution_cells : float — the independent trials one scan amounts to: with a noise
        model the count whose Bonferroni tail equals the field's at the threshold
        (``false_alarm / Q(threshold_sigma)``), without one the searched area in
        resolution cells
    below_positions_mm : (M, 2), below_significance : (M,) — candidates examined that did
        not clear the threshold (or whose fitted brightness is not positive), strongest first
    notes : tuple of str — warnings about the whole detection
    extent_mm : (count, 2) — size across and in depth of an "extended" object: the width of
        a uniform object with the same weighted spread as its point components (√12 × their
        standard deviation; 0 for a point), each uncertain by the blur
    components_mm : tuple of (n_k, 2) — the (y, z) of the point components of each object
    extended_tests : tuple of (y₁, z₁, y₂, z₂, Δ, ln n_eff) — each pair of components tested
        for being one extended object (:func:`.extended.one_or_two`): its statistic Δ and
        the bound it is compared with (Δ ≤ bound: one extended object)
    across_interval_mm : (count, 2) — (low, high) y bounds the object's data allow at the
        detection's own confidence (:func:`.significance.likelihood_region`: where its
        significance stays within the threshold's Δχ² of its best); for a bright object a
        fraction of the blur, for one near the threshold up to several blurs (its position
        is then flagged unresolved); for an extended object its components' span
    """

    count: int
    positions_mm: NDArray[np.float64]
    brightness_rp: NDArray[np.float64]
    brightness_conventional: NDArray[np.float64]
    resolutions: tuple[Resolution, ...]
    stack: FocalStack
    depth_profiles: NDArray[np.float64]
    depth_interval_mm: NDArray[np.float64]
    quality: tuple[str, ...]
    depth_estimates_mm: NDArray[np.float64]
    depth_open: NDArray[np.bool_] = field(default_factory=lambda: np.zeros((0, 2), bool))
    significance: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    false_alarm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    threshold_sigma: float = float("nan")
    resolution_cells: float = 0.0
    below_positions_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    below_significance: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    notes: tuple[str, ...] = ()
    extent_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    components_mm: tuple[NDArray[np.float64], ...] = ()
    extended_tests: tuple[tuple[float, float, float, float, float, float], ...] = ()
    across_interval_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))


#: Components closer than this many resolution cells to each other (across in δy, in
#: depth in δz/D²) are tested for being one extended object (:mod:`.extended`: a uniform
#: segment against two points, by the data).  Beyond two cells the point responses (main
#: lobe ±1 δy) no longer overlap, so the two are separate whatever their shape.
EXTENDED_RANGE = 2.0

#: Systematic error of the point-response model, as a fraction of the response a bright
#: object leaks into a candidate's (``a_j ⟨K_k, K_j⟩/⟨K_k, K_k⟩``).  On renderer data (3 mm
#: discs, brushed metal, d2 = 100 mm) artefacts beside a bright object — on its line of sight
#: 1.2 δz nearer the wall, or in its ray fan — had amplitudes of 1/7 to 1/11 of that leak;
#: 0.1 puts them below 1.4σ of systematic error alone.
MODEL_MISMATCH = 0.1

#: Candidates below the threshold examined (and counted) before the search stops; each is
#: refined and its response subtracted, so that the search moves past a bright object's
#: residual (masking its cell alone left the peak picker on that residual's ridge).
MAX_BELOW = 8

#: A candidate below the threshold within this many transverse blurs across of a stronger
#: candidate that cleared it (at any depth) lies in that object's shadow: its line of sight
#: and the nearby rays of its fan, where the point model's mismatch leaves its artefacts
#: (beside a bright disc on the 0.5° wall: eight of them within 2 δy across, 8 depth cells
#: either side).  They are examined and counted, but up to :data:`MAX_EXAMINED` in all, not
#: against :data:`MAX_BELOW`, so they cannot end the search before it looks elsewhere (a
#: 1000× dimmer disc 40 mm beside the bright one was never examined: missed silently).
SHADOW_BLURS = 3.0

#: Candidates examined in all (in and out of shadows) before the search stops.
MAX_EXAMINED = 3 * MAX_BELOW

#: Candidates below the threshold by less than this (σ) get their position fitted jointly
#: with the reported objects before they are judged: a candidate is first scored where the
#: residual's matched filter peaks after the greedy subtraction of the brighter objects,
#: and beside a bright object that peak is pulled off the dim one's position by the bright
#: one's model mismatch (behind the brushed metal a 100× dimmer disc scored 4.1σ at
#: (17.8, −208) mm against a 4.5σ threshold; at its true (20, −220) mm the same fit gives
#: 4.7σ, and at (20.1, −215.2) mm, within its cell, 4.8σ).  The move stays inside the
#: candidate's own resolution cell, whose maximum the threshold already counts (one trial a
#: cell), so the false-alarm rate keeps its meaning; a wider move (±1 δy, ±2 δz/D²) let a
#: candidate behind the glossy paper take a dim object's light 15 mm away.
RESCUE_MARGIN = 1.0

#: Objects below this many times the threshold get the region of positions their data
#: allow (:func:`.significance.likelihood_region`) refitted on a grid around them; above
#: it the region lies well inside one cell (at 3 s* the significance may fall only to
#: 0.94 of its best) and the grid would cost fits for nothing.
REGION_SIGMAS = 3.0

#: Half-width of that grid in resolution cells (δy across, δz/D² in inverse depth).
REGION_CELLS = 4.0

#: Residual power over the noise's beyond which the point-source model is not trusted for
#: depths (single points in range fit to 1.1–1.2; a source at −600 mm searched to −400 mm
#: left 20).
MISMATCH_LIMIT = 3.0


def _replace_quality(c: _Candidate, quality: str) -> _Candidate:
    from dataclasses import replace

    return replace(c, quality=quality)


def _parabolic(v: NDArray[Any], i: int) -> float:
    if 0 < i < v.size - 1:
        den = v[i - 1] - 2 * v[i] + v[i + 1]
        if den < 0:
            return float(i + 0.5 * (v[i - 1] - v[i + 1]) / den)
    return float(i)


def _peak_in(v: NDArray[Any], grid: NDArray[Any], allowed: NDArray[np.bool_]) -> float:
    """Sub-sample position of the largest ``v`` where ``allowed`` (parabolic refinement)."""
    j = int(np.argmax(np.where(allowed, v, -np.inf)))
    return float(np.interp(_parabolic(v, j), np.arange(grid.size), grid))


#: A detection whose matched-filter column is this much wider (half maximum, inverse
#: depth) than its fitted point response's is a blend along the line of sight.  Measured on
#: renderer data: single points 0.99–1.11, a 15 mm bar 1.04–1.18, two points 2–3 δz/D²
#: apart on one line of sight 1.43–1.65 (the pearl paint's bar components: 1.39).
BLEND_WIDTH_RATIO = 1.3


def _inv_span(z_far: float, z_near: float) -> float:
    """Width of a depth span in inverse depth (1/mm)."""
    return abs(1.0 / abs(z_near) - 1.0 / abs(z_far))


def _half_max_span(v: NDArray[Any], grid: NDArray[Any]) -> tuple[float, float]:
    """Grid values bounding the contiguous run around ``argmax(v)`` where v ≥ max/2."""
    j = int(np.argmax(v))
    above = v >= 0.5 * v[j]
    lo = j
    while lo > 0 and above[lo - 1]:
        lo -= 1
    hi = j
    while hi < v.size - 1 and above[hi + 1]:
        hi += 1
    return float(grid[lo]), float(grid[hi])


def point_response(
    lf_wall: LightField2D,
    y_mm: float,
    z_mm: float,
    filter_factors: ArrayLike,
) -> LightField2D:
    """Reconstructed field of an ideal point source at (y, z) seen through the filter φ_p.

    Row c sees the point at ``θ*(c) = atan((c − y)/(−z))``; its reconstruction is the
    filtered delta ``G(θ) = Σ_p φ_p φ_p(θ) φ_p*(θ*)`` divided by the obliquity cos θ
    (module :mod:`analysis.lightfield.reconstruct`).  ``filter_factors`` has shape (N,) in
    fftfreq order.
    """
    from .spectral import fourier_orders, synthesize

    th = lf_wall.theta_rad
    a, b = lf_wall.domain_rad
    omega = 2 * np.pi / (b - a)
    centre = 0.5 * (a + b)
    p = fourier_orders(th.size)
    phi = np.atleast_2d(np.asarray(filter_factors, dtype=float)).mean(axis=0)
    t_star = np.arctan((lf_wall.y_mm - y_mm) / (-z_mm))
    coef = phi[None, :] * np.exp(-1j * p[None, :] * omega * (t_star[:, None] - centre))
    g = synthesize(coef, axis=-1).real / (b - a)
    return lf_wall.with_radiance(g / np.cos(th)[None, :])


@dataclass(frozen=True)
class _Stacks:
    """The three stacks the detector works on (all (N_z, N_y), zero outside ``enough``):
    matched filter (peak picking, subtraction), its numerator (depth filter), RP."""

    mf: NDArray[Any]
    num: NDArray[Any]
    rp: NDArray[Any]

    def __sub__(self, other: _Stacks) -> _Stacks:
        return _Stacks(self.mf - other.mf, self.num - other.num, self.rp - other.rp)

    def scaled(self, k: float) -> _Stacks:
        return _Stacks(k * self.mf, k * self.num, k * self.rp)


@dataclass(frozen=True)
class _Candidate:
    y: float
    z: float
    quality: str
    estimates: tuple[float, float, float]
    interval: tuple[float, float]
    profile: NDArray[Any]
    model: _Stacks
    open_ends: tuple[bool, bool] = (False, False)
    #: the data's normalised matched filter along the line of sight (N_z,), profiled over
    #: y within one transverse blur (0 outside the searchable region): the depth evidence
    #: that :func:`.significance.depth_span` turns into a noise-limited interval
    mf_profile: NDArray[Any] = field(default_factory=lambda: np.zeros(0))


def _inseparable_notes(cands: list[_Candidate], res: list[Resolution]) -> list[str]:
    """A note for each pair of reported objects within one transverse blur of each other
    whose depth intervals overlap and of which one or both are not "resolved": two objects
    there, but where along that line of sight each lies the data do not say (a pair one
    blur apart side by side behind the brushed metal came back as two components at
    y = 0, 17 mm apart in depth, both intervals holding the true −200 mm)."""
    out = []
    for i, c in enumerate(cands):
        for j in range(i + 1, len(cands)):
            o = cands[j]
            blur = max(res[i].transverse_mm, res[j].transverse_mm)
            overlap = c.interval[0] <= o.interval[1] and o.interval[0] <= c.interval[1]
            if (abs(c.y - o.y) <= blur and overlap
                    and "resolved" not in (c.quality, o.quality)):
                out.append(
                    f"the objects at ({c.y:.1f}, {c.z:.1f}) and ({o.y:.1f}, {o.z:.1f}) mm lie "
                    f"within one blur across (δy = {blur:.1f} mm) with overlapping depth "
                    f"intervals: two objects, not separable in depth — both lie within "
                    f"y = {min(c.y, o.y) - blur:.1f}…{max(c.y, o.y) + blur:.1f} mm, "
                    f"z = {min(c.interval[0], o.interval[0]):.1f}…"
                    f"{max(c.interval[1], o.interval[1]):.1f} mm, in an order the data do "
                    f"not fix")
    return out


def _side_by_side(
    cands: list[_Candidate], tests: dict[tuple[int, int], Any], blur_at: Any
) -> tuple[list[_Candidate], list[str]]:
    """Flag "unresolved" each pair of components on one line of sight (within one
    transverse blur across, ``blur_at(z)`` at the nearer one's depth, depth intervals
    overlapping) that its test of one against two (:func:`.extended.one_or_two`, ``tests``
    by index pair) judged two points but fitted side by side, more than a blur apart
    across: the search's arrangement is not the data's.  Returns the candidates and one
    note per such pair naming both arrangements."""
    out, notes = list(cands), []
    for (i, j), t in tests.items():
        ci, cj = cands[i], cands[j]
        blur = float(blur_at(max(ci.z, cj.z)))
        on_sight = (abs(ci.y - cj.y) <= blur and ci.interval[0] <= cj.interval[1]
                    and cj.interval[0] <= ci.interval[1])
        if t.extended or not on_sight or abs(t.points_mm[1, 0] - t.points_mm[0, 0]) <= blur:
            continue
        (y1, z1), (y2, z2) = t.points_mm
        notes.append(f"the components at ({ci.y:.1f}, {ci.z:.1f}) and ({cj.y:.1f}, {cj.z:.1f}) "
                     f"mm, on one line of sight, fit better as two points side by side at "
                     f"({y1:.1f}, {z1:.1f}) and ({y2:.1f}, {z2:.1f}) mm: their depths are "
                     f"flagged unresolved")
        out[i] = _replace_quality(out[i], "unresolved")
        out[j] = _replace_quality(out[j], "unresolved")
    return out, notes


def detect_objects(
    lf_wall: LightField2D,
    *,
    p_max: float,
    y_mm: ArrayLike,
    z_mm: ArrayLike,
    solvable_domain_rad: tuple[float, float] | None = None,
    filter_factors: ArrayLike | None = None,
    threshold_rel: float | None = None,
    min_measure_fraction: float = 0.25,
    max_objects: int = 20,
    noise_power: ArrayLike | None = None,
    false_alarm: float = 0.01,
    sample_plan: bool = True,
) -> Detection:
    """Detect objects: count, (y, z), brightness, resolution, depth interval and quality.

    CLEAN-style: the strongest peak of the matched-filter numerator (inside the region
    seen through at least ``min_measure_fraction`` of the solvable domain; the numerator,
    not the normalised statistic, so that regions seen through few rays do not amplify
    reconstruction artefacts) starts a search in its column for three depth estimates:

    * z_MF, the maximum of the normalised matched filter (the point-source likelihood
      statistic of :func:`refocus`, free of the ray-density bias);
    * z_DF, the depth filter (:func:`depth_profile` on the matched-filter numerator,
      window half-width 3 δy, spatial frequencies up to the angular cut-off at that depth
      ``(P + ½)/((B − A)|z|) = 1/(2 δy)``), and z_RP, the RP stack's maximum, both searched
      inside the inverse-depth interval of z_MF (:func:`depth_interval`).

    The depth reported is their median, robust when one of them fails (with few angular
    orders the depth filter's windowed spectra carry little depth information — the old
    detector placed objects behind the semi-matte paper at a third of their distance —
    and it leans ≈ 0.15 δz away from the wall where the solvable domain, not the wall,
    limits the aperture; RP is noisy where few rays are available).  The flag says how
    far they agree, in units of the inverse-depth resolution ``δz/D²``:

    * "resolved" — all three pairwise within one resolution;
    * "two_estimates_agree" — one of them is off;
    * "unresolved" — none agree, or the depth interval (``Detection.depth_interval_mm``)
      is not wholly inside the searched region (the object may lie beyond it, or the
      depth blur has no far end), or the matched-filter column is more than
      :data:`BLEND_WIDTH_RATIO` times wider than the fitted point response's (a blend of
      sources along the line of sight, or one extended object): the depth is only a best
      guess; read the interval.

    y comes from a parabola through the matched-filter row at that depth.  The stacks of
    an ideal point source there (:func:`point_response`, least-squares scaled to the
    matched filter around the peak) are subtracted, which removes its side lobes and the
    ghost crossings of its ray fan with other objects' fans; repeat while the residual
    peak exceeds ``threshold_rel`` × the first peak.  Then every object is refined again
    with the others subtracted (interference removal), and kept only if its own fitted
    response still clears the threshold.  Where objects interact (two within two
    resolution cells), greedy subtraction mis-splits overlapping responses (a pair
    1–1.3 δy apart gave its merged peak plus two shoulders), so instead all responses
    are fitted jointly to the rays of the solvable domain (:func:`_fit_points`: free
    (y, z) and amplitude each, the model whose one-source statistic is the matched
    filter) and, one at a time with a refit after each, components are dropped whose
    fitted strength ``a_k ‖K_k‖²`` is below ``threshold_rel`` × the strongest, that lie
    inside a stronger one's resolution cell, or that the Bayesian information criterion
    does not need (the residual grows by less than ``3 ln n_eff`` noise variances without
    them, ``n_eff = R (2 p̂_max + 1)(B − A)/(b − a)`` independent samples, the variance
    from the full fit's residual); the survivors are refined with the others' jointly
    fitted responses subtracted.  Brightness is the RP value at each object.
    ``filter_factors`` (N,) are those of the reconstruction (default: truncation at p_max).

    Significance (with the reconstruction's ``noise_power`` (N,), ``σ_p²/|S_pp|²`` in
    fftfreq order; :mod:`.significance`): every candidate's amplitude is fitted jointly
    with those found before it, and its significance is the amplitude over its standard
    deviation — the noise propagated through the filter, scaled by the residual's excess
    over the noise, and a systematic share :data:`MODEL_MISMATCH` of the response that
    each other object leaks into it (a point model mismatched by a few per cent leaves
    artefacts in the fan and on the line of sight of a bright object; measured in
    ``benchmarks/bench_lightfield_validation.py``).  A candidate counts as an object when
    its significance exceeds the threshold of a per-scan false-alarm probability
    ``false_alarm`` over the scan's independent resolution cells, and its fitted
    brightness is positive; the others are kept as counted, never silent, candidates
    below the threshold (``Detection.below_*``; up to :data:`MAX_BELOW` are examined).
    Objects are reported in order of significance.  ``threshold_rel`` (fraction of the
    strongest peak) is then off unless given; without ``noise_power`` it defaults to 0.3
    and no significance is computed (NaN).

    The candidates' models (point-response stacks, one per candidate examined) share the
    data's geometry: with ``sample_plan`` their samples are laid out once as sparse
    matrices (:class:`.wall_samples.SamplePlan`, up to :data:`SAMPLE_PLAN_MAX_BYTES`),
    which gives the same stacks to rounding at a fifth of the CPU or less; False sums each over
    the rays' runs, as the data's stack (the reference, and less memory).
    """
    from dataclasses import replace

    from scipy.ndimage import binary_dilation
    from scipy.special import ndtr

    from .edge_light import judged_on_clean_rows, line_of_sight, outside_rows
    from .excursion import expected_euler
    from .significance import (
        amplitude_fit,
        depth_span,
        false_alarm_probability,
        likelihood_region,
        with_leak,
    )
    from .spectral import fourier_orders

    y = np.asarray(y_mm, dtype=float)
    zs = np.atleast_1d(np.asarray(z_mm, dtype=float))
    a, b = lf_wall.domain_rad if solvable_domain_rad is None else solvable_domain_rad
    if filter_factors is None:
        phi = (np.abs(fourier_orders(lf_wall.theta_rad.size)) <= p_max).astype(float)
    else:
        phi = np.atleast_2d(np.asarray(filter_factors, dtype=float)).mean(axis=0)
    conv, rp, meas, num, norm2 = _stacks(lf_wall, y, zs, a, b, phi)
    st = FocalStack(y, zs, conv, rp, meas, (float(a), float(b)), _normalised(num, norm2))
    aperture = float(lf_wall.y_mm[-1] - lf_wall.y_mm[0])
    enough = st.measure_rad >= min_measure_fraction * (b - a)
    data = _Stacks(*(np.where(enough, v, 0.0) for v in (st.matched_filter, num,
                                                          st.radiance_preserving)))
    first = float(data.num.max()) if data.num.size else 0.0
    z_far_limit, z_near_limit = float(zs.min()), float(zs.max())
    noise = (None if noise_power is None
             else np.broadcast_to(np.asarray(noise_power, dtype=float), phi.shape))
    if threshold_rel is None:
        threshold_rel = 0.3 if noise is None else 0.0

    def resolution(depth: float) -> Resolution:
        return theoretical_resolution(p_max, domain_rad=lf_wall.domain_rad,
                                      distance_mm=abs(depth), aperture_mm=aperture,
                                      solvable_domain_rad=(a, b))

    def inv_close(z1: float, z2: float, r_k: Resolution, ref: float) -> bool:
        return abs(1.0 / abs(z1) - 1.0 / abs(z2)) <= r_k.depth_mm / ref**2

    # the models' samples laid out once (.wall_samples.SamplePlan), on the first model
    plan: list[SamplePlan | None] = []

    def model_of(y_ref: float, z_ref: float) -> _Stacks:
        if not plan:
            plan.append(_sample_plan(lf_wall, y, zs, a, b, phi) if sample_plan else None)
        _, rp_m, _, nm, n2 = _stacks(point_response(lf_wall, y_ref, z_ref, phi), y, zs, a, b,
                                     phi, geometry=(meas, norm2), plan=plan[0])
        return _Stacks(*(np.where(enough, v, 0.0) for v in (_normalised(nm, n2), nm, rp_m)))

    def refine(own: _Stacks, y0: float, z0: float) -> _Candidate:
        iy = int(np.argmin(np.abs(y - y0)))
        col = enough[:, iy]
        r0 = resolution(z0)
        far, near = depth_interval(z0, r0, limit_mm=z_far_limit)
        inside = (zs >= far) & (zs <= near) & col
        allowed = inside | (zs == zs[np.argmin(np.abs(zs - z0))])
        z_mf = _peak_in(own.mf[:, iy], zs, allowed)
        r_k = resolution(z_mf)
        # the maximum is a localised depth only if the matched filter was evaluated over
        # the whole interval compatible with it: where the searchable region (or the grid)
        # ends inside it, the object may lie beyond, and the maximum is the border's
        far_u, near = depth_interval(z_mf, r_k)
        open_far = far_u < zs[0] or not col[(zs >= far_u) & (zs <= z_mf)].all()
        open_near = near > zs[-1] or not col[(zs >= z_mf) & (zs <= near)].all()
        far = max(far_u, z_far_limit)
        inside = (zs >= far) & (zs <= near) & col
        fs = FocalStack(y, zs, own.num, own.rp, st.measure_rad, (a, b))
        prof, _ = depth_profile(fs, y0, window_halfwidth_mm=3.0 * r_k.transverse_mm,
                                max_frequency_per_mm=0.5 / r_k.transverse_mm,
                                min_frequency_per_mm=0.1 / r_k.transverse_mm)
        z_odf = _peak_in(prof, zs, inside) if inside.any() else z_mf
        z_rp = _peak_in(own.rp[:, iy], zs, inside) if inside.any() else z_mf
        est = (z_odf, z_mf, z_rp)
        z_ref = float(np.median(est))
        iz = int(np.argmin(np.abs(zs - z_ref)))
        r_ref = resolution(z_ref)
        y_ref = _peak_in(own.mf[iz], y, np.abs(y - y0) <= 0.5 * r_ref.transverse_mm)
        model = model_of(y_ref, z_ref)
        far, near = depth_interval(z_ref, r_ref, limit_mm=z_far_limit)
        hood = ((np.abs(y - y_ref) <= r_ref.transverse_mm)[None, :]
                & ((zs >= far) & (zs <= near))[:, None] & enough)
        mm = float(np.sum(model.mf[hood] ** 2))
        scale = float(np.sum(model.mf[hood] * own.mf[hood])) / mm if mm > 0 else 0.0
        # the interval also holds every estimate (their disagreement is uncertainty too)
        # and the depths where the point response's own column stays above half its peak:
        # parallax grows linearly across the aperture, so that response is ≈ 2.4 δz/D²
        # wide (half width at half maximum, in inverse depth) where a transverse one is
        # ≈ 0.6 δy — the thesis' δz is the resolution of the aperture's edge rays only
        jy = int(np.argmin(np.abs(y - y_ref)))
        z_lo, z_hi = _half_max_span(model.mf[:, jy], zs)
        # the data's own column: broader than a point's (in inverse depth) means more
        # than one source along this line of sight (or one extended in depth), blended
        d_lo, d_hi = _half_max_span(np.where(enough[:, jy], own.mf[:, jy], 0.0), zs)
        broad = (_inv_span(d_lo, d_hi) > BLEND_WIDTH_RATIO * _inv_span(z_lo, z_hi))
        if broad:
            z_lo, z_hi = min(z_lo, d_lo), max(z_hi, d_hi)
        lo, hi = min(far, z_lo, *est), max(near, z_hi, *est)
        open_far |= lo <= zs[0] or not enough[(zs >= lo) & (zs <= z_ref), jy].all()
        open_near |= hi >= zs[-1] or not enough[(zs >= z_ref) & (zs <= hi), jy].all()
        interval = (z_far_limit if open_far else lo, z_near_limit if open_near else hi)
        bounded = not (open_far or open_near)
        agree = [inv_close(est[i], est[j], r_k, z_mf) for i, j in ((0, 1), (0, 2), (1, 2))]
        if broad:
            quality = "unresolved"
        elif bounded and all(agree):
            quality = "resolved"
        elif bounded and any(agree):
            quality = "two_estimates_agree"
        else:
            quality = "unresolved"
        across = np.abs(y - y_ref) <= r_ref.transverse_mm
        across[int(np.argmin(np.abs(y - y_ref)))] = True
        mf_prof = np.where(enough[:, across], own.mf[:, across], 0.0).max(axis=1)
        return _Candidate(y_ref, z_ref, quality, est, interval, prof,
                          model.scaled(scale), (bool(open_far), bool(open_near)), mf_prof)

    def cell(y0: float, z0: float, frac: float) -> NDArray[np.bool_]:
        """The (y, z) samples within ``frac`` resolution cells of (y0, z0) (δy across,
        δz/D² in inverse depth)."""
        r_k = resolution(z0)
        inv = np.abs(1.0 / np.abs(zs) - 1.0 / abs(z0)) <= frac * r_k.depth_mm / z0**2
        return (np.abs(y - y0) <= frac * r_k.transverse_mm)[None, :] & inv[:, None]

    def unresolvable(c: _Candidate, others: list[_Candidate]) -> bool:
        """Closer than one resolution cell to a stronger object: not a separate object
        (what is left there is the stronger one's model mismatch)."""
        return any(cell(o.y, o.z, 1.0)[int(np.argmin(np.abs(zs - c.z))),
                                       int(np.argmin(np.abs(y - c.y)))] for o in others)

    def near(c: _Candidate, o: _Candidate, frac: float) -> bool:
        """Within ``frac`` resolution cells of each other (at the nearer one's depth)."""
        ref = c.z if abs(c.z) < abs(o.z) else o.z
        r_k = resolution(ref)
        return (abs(c.y - o.y) <= frac * r_k.transverse_mm
                and abs(1.0 / abs(c.z) - 1.0 / abs(o.z)) <= frac * r_k.depth_mm / ref**2)

    def sightline(c: _Candidate, o: _Candidate) -> bool:
        """On one line of sight: within one transverse blur across (at the nearer one's
        depth), depth intervals overlapping."""
        blur = resolution(max(c.z, o.z)).transverse_mm
        return (abs(c.y - o.y) <= blur and c.interval[0] <= o.interval[1]
                and o.interval[0] <= c.interval[1])

    use = (lf_wall.theta_rad >= a) & (lf_wall.theta_rad <= b)
    g_rays = (np.asarray(lf_wall.radiance, dtype=float)
              * np.cos(lf_wall.theta_rad)[None, :])[:, use]
    box = ((float(y.min()), float(y.max())), (z_far_limit, z_near_limit))
    # independent samples on the fitted rays: 2 p̂_max + 1 orders per wall point, the
    # fraction (B − A)/(b − a) of them inside the solvable domain
    n_eff = max(lf_wall.y_mm.size * (2.0 * max(p_max, 0.0) + 1.0) * (b - a)
                / (lf_wall.domain_rad[1] - lf_wall.domain_rad[0]), 2.0)

    # independent trials of one scan: the searched (y, z) area in resolution cells
    step_y = float(abs(y[1] - y[0])) if y.size > 1 else 1.0
    step_z = float(abs(zs[1] - zs[0])) if zs.size > 1 else 1.0
    n_cells = 0.0
    for i_z, z_row in enumerate(zs):
        r_row = resolution(float(z_row))
        n_cells += (np.count_nonzero(enough[i_z]) * step_y * step_z
                    / max(r_row.transverse_mm * r_row.depth_mm, 1e-12))
    s_star = float("nan")
    tail = None
    if noise is not None:
        # the per-scan false-alarm rate of the statistic's maximum over the searched region,
        # from the field's own smoothness (expected Euler characteristic, .excursion); the
        # cell count above assumed one independent trial per resolution cell, which the
        # measured null tail did not follow (ADR 0032, amended 2026-11-27)
        tail = expected_euler(lf_wall, use, phi, noise, y, zs, enough)
        s_star = tail.threshold(false_alarm)
        # reported as the number of independent trials with the same tail at s*
        n_cells = false_alarm / max(float(ndtr(-s_star)), 1e-300)

    def assess(pos: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any], float]:
        """Joint amplitudes, significances (σ) and the residual's excess over the noise
        of point responses at ``pos`` (K, 2)."""
        assert noise is not None
        r, _, _ = _ray_model(lf_wall, use, phi, pos)
        fit = amplitude_fit(g_rays, r, use, phi, noise)
        return fit.amplitudes, with_leak(fit, r, MODEL_MISMATCH), fit.mismatch

    def fit_of(pos: NDArray[Any]) -> _JointFit:
        return _fit_points(g_rays, lf_wall, use, phi, pos, box)

    def strengths(f: _JointFit) -> NDArray[Any]:
        """Matched-filter numerator of each fitted response at its own position on the
        rays, ``a_k ‖K_k‖²``: the ray-domain counterpart of the greedy threshold."""
        r, _, _ = _ray_model(lf_wall, use, phi, f.positions)
        return f.amplitudes * np.sum(r.reshape(len(f.amplitudes), -1) ** 2, axis=1)

    def as_cand(p_: NDArray[Any]) -> _Candidate:
        return _Candidate(float(p_[0]), float(p_[1]), "unresolved", (0.0, 0.0, 0.0),
                          (0.0, 0.0), np.zeros(0), data)

    def joint_refit(cs: list[_Candidate]) -> list[_Candidate]:
        fit = fit_of(np.asarray([(c.y, c.z) for c in cs], dtype=float))
        while fit.amplitudes.size > 1:
            s = strengths(fit)
            pts = [as_cand(p_) for p_ in fit.positions]
            # ties broken by position, so the order never follows rounding noise
            weak_first = [int(i) for i in np.lexsort((fit.positions[:, 1],
                                                      fit.positions[:, 0], s))]
            drop, refit = None, None
            for k in weak_first:
                stronger = [pts[j] for j in range(s.size) if s[j] > s[k]]
                if s[k] < threshold_rel * s.max() or any(near(pts[k], o, 1.0)
                                                          for o in stronger):
                    drop = k
                    break
            if drop is None:
                # Bayesian information criterion in the Gaussian approximation: the
                # residual must grow by more than 3 ln n_eff noise variances (three
                # parameters per object) for the object to be needed; tested only where
                # a neighbour could absorb its flux
                sigma2 = fit.rss / max(n_eff - 3 * s.size, 1.0)
                for k in weak_first:
                    if not any(near(pts[k], pts[j], 2.0) for j in range(s.size) if j != k):
                        continue
                    sub = fit_of(np.delete(fit.positions, k, axis=0))
                    if sub.rss - fit.rss < 3.0 * np.log(n_eff) * sigma2:
                        drop, refit = k, sub
                        break
            if drop is None:
                break
            fit = refit or fit_of(np.delete(fit.positions, drop, axis=0))
        models = [model_of(float(p_[0]), float(p_[1])).scaled(float(amp))
                  for p_, amp in zip(fit.positions, fit.amplitudes, strict=True)]
        out = []
        for k, p_ in enumerate(fit.positions):
            own = data
            for j, m in enumerate(models):
                if j != k:
                    own = own - m
            out.append(refine(own, float(p_[0]), float(p_[1])))
        return out

    def shadowed(c: _Candidate, found: list[_Candidate]) -> bool:
        """In the shadow of an object that cleared the threshold (:data:`SHADOW_BLURS`)."""
        return any(abs(c.y - o.y) <= SHADOW_BLURS * resolution(o.z).transverse_mm
                   for o in found)

    def rescue(found: list[_Candidate], weaker: list[tuple[_Candidate, float]]
               ) -> tuple[list[_Candidate], list[tuple[_Candidate, float]]]:
        """Candidates within :data:`RESCUE_MARGIN` below the threshold, their significance
        maximised over their own resolution cell (±½ δy across, ±1 δz/D² in inverse depth;
        the reported objects held where they were found, each still clearing the
        threshold): those that clear it there join the objects, at that position."""
        from scipy.optimize import minimize

        found, rest = list(found), []
        fixed = np.asarray([(o.y, o.z) for o in found], dtype=float).reshape(-1, 2)
        for c, sg in weaker:
            # within two cells of a reported object the two responses overlap: moving the
            # candidate there would share that object's light, not find a second one
            if (not s_star - RESCUE_MARGIN <= sg < s_star
                    or any(near(c, o, EXTENDED_RANGE) for o in found)):
                rest.append((c, sg))
                continue
            # a sub-cell move is judged by the point model only where that model explains
            # the data: where it leaves more than MISMATCH_LIMIT× the noise (the brushed
            # metal's pair one blur apart, fitted as two points on one line of sight: 36×)
            # the significance's ups and downs within a cell follow the misfit, and the
            # move lifted a 4.4σ candidate 20 mm beside the pair to 6.2σ, a phantom
            if assess(np.vstack([fixed, [(c.y, c.z)]]))[2] > MISMATCH_LIMIT:
                rest.append((c, sg))
                continue
            r_c = resolution(c.z)
            cell_q = r_c.depth_mm / c.z**2

            def minus_sig(u: NDArray[Any], c: _Candidate = c, r_c: Resolution = r_c,
                          cell_q: float = cell_q, fixed: NDArray[Any] = fixed) -> float:
                # (u0, u1): offsets in cells, δy across and δz/D² in inverse depth
                yt = c.y + u[0] * r_c.transverse_mm
                zt = -1.0 / (1.0 / abs(c.z) + u[1] * cell_q)
                if not (abs(u[0]) <= 0.5 and abs(u[1]) <= 1.0 and box[0][0] <= yt <= box[0][1]
                        and box[1][0] <= zt <= box[1][1]):
                    return 0.0
                amp_t, sig_t, _ = assess(np.vstack([fixed, [(yt, zt)]]))
                # never by taking a reported object's light: each must still clear it
                if amp_t[-1] <= 0 or np.any(sig_t[:-1] < s_star):
                    return 0.0
                return -float(sig_t[-1])

            # a coarse grid over the cell, then the simplex from its best point (both
            # deterministic)
            grid = [(u0, u1) for u0 in (-0.25, 0.0, 0.25) for u1 in (-0.5, 0.0, 0.5)]
            start = min(grid, key=lambda u: minus_sig(np.asarray(u)))
            opt = minimize(minus_sig, np.asarray(start, dtype=float), method="Nelder-Mead",
                           options={"xatol": 0.02, "fatol": 1e-3, "maxfev": 60,
                                    "initial_simplex": np.asarray(start) + np.array(
                                        [[0.0, 0.0], [0.125, 0.0], [0.0, 0.25]])})
            best = -float(opt.fun)
            y1 = c.y + float(opt.x[0]) * r_c.transverse_mm
            z1 = -1.0 / (1.0 / abs(c.z) + float(opt.x[1]) * cell_q)
            if best < s_star:
                rest.append((c, sg))
                continue
            own = data
            for o in found:
                own = own - o.model
            c1 = refine(own, y1, z1)
            found.append(replace(c1, y=y1, z=z1, interval=(min(c1.interval[0], z1),
                                                          max(c1.interval[1], z1))))
            fixed = np.vstack([fixed, [(y1, z1)]])
        return found, rest

    def position_region(c: _Candidate, others: NDArray[Any]
                        ) -> tuple[NDArray[Any], NDArray[Any], NDArray[np.bool_]]:
        """Trial (y, z) on a grid of ±:data:`REGION_CELLS` resolution cells around ``c``
        (half a cell apart; δy across, δz/D² in inverse depth) and the region of them its
        data allow (:func:`.significance.likelihood_region`): at each, the candidate's
        significance refitted jointly with the ``others`` (K, 2), with their leak share."""
        r_c = resolution(c.z)
        steps = np.arange(-REGION_CELLS, REGION_CELLS + 0.25, 0.5)
        ty = c.y + steps * r_c.transverse_mm
        inv = 1.0 / abs(c.z) + steps * r_c.depth_mm / c.z**2
        tz = np.where(inv > 0, -1.0 / np.where(inv > 0, inv, 1.0), -np.inf)
        sig_t = np.full((tz.size, ty.size), np.nan)
        for i, zt in enumerate(tz):
            if not box[1][0] <= zt <= box[1][1]:
                continue
            for j, yt in enumerate(ty):
                if box[0][0] <= yt <= box[0][1]:
                    sig_t[i, j] = assess(np.vstack([others, [(yt, zt)]]))[1][-1]
        centre = steps.size // 2
        region = likelihood_region(sig_t, (centre, centre), s_star)
        yy, zz = np.meshgrid(ty, tz)
        # samples outside the searched box (NaN significance) are not "next ones out"
        return yy, np.where(np.isfinite(zz), zz, box[1][0]), region

    # pass 1, CLEAN: take the strongest residual peak, subtract its point response
    residual = data
    cands: list[_Candidate] = []
    below: list[tuple[_Candidate, float]] = []
    n_free = 0  # candidates below the threshold outside every shadow
    while (len(cands) < max_objects and first > 0 and n_free < MAX_BELOW
           and len(below) < MAX_EXAMINED):
        iz, iy = np.unravel_index(int(np.argmax(residual.num)), residual.num.shape)
        if residual.num[iz, iy] <= 0 or residual.num[iz, iy] < threshold_rel * first:
            break
        cand = refine(residual, float(y[iy]), float(zs[iz]))
        if unresolvable(cand, cands):
            core = cell(float(y[iy]), float(zs[iz]), 0.5)
        else:
            # subtracted either way, so that the search moves on past it
            residual = residual - cand.model
            core = cell(cand.y, cand.z, 0.5)
            if noise is None:
                cands.append(cand)
            else:
                _, sig, _ = assess(np.asarray([(c.y, c.z) for c in [*cands, cand]]))
                if sig[-1] >= s_star:
                    cands.append(cand)
                else:
                    below.append((cand, float(sig[-1])))
                    n_free += int(not shadowed(cand, cands))
        # clear the core so that the same peak cannot be picked twice
        core[iz, iy] = True
        residual = _Stacks(residual.mf, np.where(core, np.minimum(residual.num, 0.0),
                                                 residual.num), residual.rp)
    # pass 2, interference removal.  Interacting objects (within two resolution cells):
    # greedy subtraction of one point response at a time mis-splits overlapping
    # responses — two sources 1–1.3 δy apart came out as their merged peak plus two
    # shoulders ≈ 1.8× too far out, all three looking like objects — so all responses
    # are fitted jointly on the rays (free positions and amplitudes), and what is not an
    # object is dropped one at a time, refitting after each: a fitted strength below the
    # threshold, a component inside a stronger one's resolution cell, or one the residual
    # does not need (BIC); the survivors are re-refined with the others' jointly fitted
    # responses subtracted.  Otherwise each object is re-refined with the others' greedy
    # responses subtracted.  Either way an object is kept only if its own fitted response
    # still clears the threshold and it did not move into a stronger one's cell.
    if len(cands) > 1 and any(near(c, o, 2.0) for i, c in enumerate(cands)
                              for o in cands[i + 1:]):
        cands = joint_refit(cands)
    elif len(cands) > 1:  # one object: nothing to remove
        for k, cand in enumerate(cands):
            own = data
            for j, other in enumerate(cands):
                if j != k:
                    own = own - other.model
            cands[k] = refine(own, cand.y, cand.z)
    cands.sort(key=lambda c: (-float(c.model.num.max()), c.y, c.z))
    kept: list[_Candidate] = []
    for c in cands:
        if float(c.model.num.max()) >= threshold_rel * first and not unresolvable(c, kept):
            kept.append(c)
    cands = kept
    if noise is not None and np.isfinite(s_star):
        cands, below = rescue(cands, below)
    signif = np.full(len(cands), np.nan)
    #: components on the line of sight of an object partly outside the measured angles,
    #: reported as one object with it (.edge_light), in indices of the reported cands
    sight: list[list[int]] = []
    amps = np.zeros(len(cands))
    notes: list[str] = []
    if noise is not None and cands:
        pos_sig = np.asarray([(c.y, c.z) for c in cands], dtype=float).reshape(-1, 2)
        amps, sig, mismatch = assess(pos_sig)
        order = [int(k) for k in np.lexsort((pos_sig[:, 1], pos_sig[:, 0], -sig))]
        keep = [k for k in order if sig[k] >= s_star and amps[k] > 0]
        # light from outside the solvable angles (.edge_light): the rows a stronger
        # object's unmodelled light reaches are no evidence for a weaker candidate
        pos_all = np.asarray([(c.y, c.z) for c in cands]).reshape(-1, 2)

        def significance_on(rows: NDArray[np.bool_], idx: list[int]) -> NDArray[Any]:
            assert noise is not None
            r, _, _ = _ray_model(lf_wall, use, phi, pos_all[idx])
            return amplitude_fit(g_rays[rows], r[:, rows], use, phi, noise).significance

        keep, attributed = judged_on_clean_rows(keep, lf_wall.y_mm, pos_all, (a, b), s_star,
                                                significance_on)
        below += [(cands[k], float(sig[k])) for k in order if k not in keep]
        partly = [k for k in keep if outside_rows(lf_wall.y_mm, pos_all[k:k + 1], (a, b)).any()]
        along = line_of_sight(pos_all[keep], [keep.index(k) for k in partly],
                              lambda z: resolution(z).transverse_mm)
        along = {keep[s]: [keep[j] for j in js] for s, js in along.items()}
        # flagged only where its outside light disturbed the fit: a candidate attributed
        # to it, or components on its line of sight
        partly = [k for k in partly if k in attributed or k in along]
        for src in sorted({*attributed, *along}, key=keep.index):
            gone, merged_in = attributed.get(src, []), along.get(src, [])
            text = (f"the object at ({cands[src].y:.1f}, {cands[src].z:.1f}) mm is partly "
                    f"outside the measured angles: part of its light reaches the wall beyond "
                    f"the solvable domain ({np.rad2deg(a):.1f}…{np.rad2deg(b):.1f}°), where "
                    f"the reconstruction has no model for it, and its depth is flagged "
                    f"unresolved")
            if gone:
                k0, s0 = gone[0]
                text += (f"; {len(gone)} candidate(s) that only the rows of that light "
                         f"support are attributed to it, not reported (strongest at "
                         f"({cands[k0].y:.1f}, {cands[k0].z:.1f}) mm: {sig[k0]:.1f}σ on all "
                         f"rows, {max(s0, 0.0):.1f}σ on the others)")
            if merged_in:
                text += (f"; {len(merged_in)} more component(s) on its line of sight (at z = "
                         + ", ".join(f"{cands[j].z:.1f}" for j in merged_in)
                         + " mm) are reported as one object with it: two objects there "
                           "would not be separable in depth")
            notes.append(text)
        sight = [[keep.index(src), *(keep.index(j) for j in along.get(src, []))]
                 for src in partly]
        cands = [_replace_quality(c, "unresolved") if k in partly else c for k, c in
                 enumerate(cands)]
        cands = [cands[k] for k in keep]
        signif, amps = sig[keep], amps[keep]
        if mismatch > MISMATCH_LIMIT and cands:
            # point sources in the searched region do not explain the data: light from
            # beyond it, or objects far from point-like; no depth is trusted
            cands = [_replace_quality(c, "unresolved") for c in cands]
            notes.append(f"the fitted point sources leave {mismatch:.1f}× the noise power in "
                         f"the residual: part of the light comes from outside the searched "
                         f"range or from extended objects; depths are flagged unresolved "
                         f"(widen the z range)")
    # one extended object, not several "resolved" points: each pair of components whose
    # responses overlap (within EXTENDED_RANGE cells) is one object larger than the blur
    # when a uniform segment explains its rays as well as two points do, by the Bayesian
    # information criterion (.extended; a 15 mm bar, twice the blur across, fits as two
    # points 1.1 δy apart)
    from .extended import extended_groups

    cands_pos = [(c.y, c.z) for c in cands]
    weight = (np.asarray(amps, dtype=float) if noise is not None
              else np.asarray([float(c.model.num.max()) for c in cands]))
    # and every pair on one line of sight (within a transverse blur across, depth
    # intervals overlapping), however far apart in depth: a disc wider than the blur on a
    # near-mirror wall came out as two points on its line of sight 2.5 depth cells apart
    pairs = [(i, j) for i in range(len(cands)) for j in range(i + 1, len(cands))
             if near(cands[i], cands[j], EXTENDED_RANGE) or sightline(cands[i], cands[j])]
    groups, pair_tests = extended_groups(
        g_rays, lf_wall, use, phi, np.asarray(cands_pos, dtype=float).reshape(-1, 2), pairs,
        n_eff=n_eff, bounds=box,
        across_mm=[resolution(max(cands[i].z, cands[j].z)).transverse_mm for i, j in pairs])
    # two points on one line of sight that fit better side by side (the test's fit started
    # across): the search's arrangement is not the data's — flagged, never "resolved"
    cands, side_notes = _side_by_side(cands, pair_tests,
                                      lambda z: resolution(z).transverse_mm)
    notes += side_notes
    for line in sight:
        if len(line) > 1:
            joined = [gr for gr in groups if set(gr) & set(line)]
            groups = [gr for gr in groups if gr not in joined]
            groups.append(sorted({j for gr in joined for j in gr}))
    groups.sort(key=lambda gr: gr[0])
    on_sight = {line[0] for line in sight if len(line) > 1}
    members = [[(cands[j].y, cands[j].z) for j in gr] for gr in groups]
    merged, extent, group_sig = [], [], []
    for gr in groups:
        c0 = cands[gr[0]]
        w = np.clip(weight[gr], 1e-300, None)
        ys_, zs_ = np.array([cands[j].y for j in gr]), np.array([cands[j].z for j in gr])
        if len(gr) > 1:
            c0 = _Candidate(float(np.average(ys_, weights=w)), float(np.average(zs_, weights=w)),
                            "unresolved" if on_sight & set(gr) else "extended", c0.estimates,
                            (min(cands[j].interval[0] for j in gr),
                             max(cands[j].interval[1] for j in gr)), c0.profile, c0.model,
                            (any(cands[j].open_ends[0] for j in gr),
                             any(cands[j].open_ends[1] for j in gr)))
        merged.append(c0)
        # width of the uniform object the components sample: for a pair the fitted
        # segment's length, for more √12 × their weighted spread (two equal points fitted
        # to a uniform bar of width W sit W/√3 apart)
        spread = [float(np.sqrt(12.0 * np.average((v - np.average(v, weights=w)) ** 2,
                                                  weights=w))) for v in (ys_, zs_)]
        test = pair_tests.get((gr[0], gr[1])) if len(gr) == 2 else None
        extent.append(test.size_mm if test is not None else (spread[0], spread[1]))
        if noise is not None:
            sd = weight[gr] / signif[gr]
            group_sig.append(float(weight[gr].sum() / np.sqrt(np.sum(sd**2))))
        else:
            group_sig.append(float("nan"))
    cands, signif = merged, np.asarray(group_sig)
    # the position a near-threshold object's data allow: its intervals grow to every
    # (y, z) the data do not exclude at the detection's own confidence — in depth along its
    # line of sight (.significance.depth_span) and over the whole trial grid, across too
    # (.significance.likelihood_region): behind the glossy paper a 100× dimmer disc at
    # (20, −220) mm, 5.0σ at its place, was reported at (8.2, −179.0) mm, 4.4σ, where the
    # residual's matched filter peaked after the bright disc's subtraction, 1.03 blurs
    # across from it; a point near the threshold is placed no better than that
    across = [(min(cands_pos[j][0] for j in gr), max(cands_pos[j][0] for j in gr))
              for gr in groups]
    for k, gr in enumerate(groups):
        c = cands[k]
        if len(gr) > 1 or c.mf_profile.size == 0 or not np.isfinite(signif[k]):
            continue
        lo_i, hi_i = depth_span(c.mf_profile, int(np.argmin(np.abs(zs - c.z))),
                                float(signif[k]), s_star)
        z_lo, z_hi = float(zs[lo_i]), float(zs[hi_i])
        r_c = resolution(c.z)
        at_edge = False
        if noise is not None and signif[k] < REGION_SIGMAS * s_star:
            others = np.asarray([cands_pos[j] for i, g in enumerate(groups) if i != k
                                 for j in g], dtype=float).reshape(-1, 2)
            ty, tz, region = position_region(c, others)
            # the region's edge lies between its last sample and the next one out: the
            # interval runs to the next one (a half cell, conservative)
            grown = binary_dilation(region)
            across[k] = (min(float(ty[grown].min()), c.y), max(float(ty[grown].max()), c.y))
            z_lo, z_hi = min(z_lo, float(tz[grown].min())), max(z_hi, float(tz[grown].max()))
            at_edge = bool(region[0].any() or region[-1].any() or region[:, 0].any()
                           or region[:, -1].any())
        # "resolved" claims the depth to one resolution cell (δz/D² in inverse depth) and the
        # position across to one blur
        cell_q = r_c.depth_mm / c.z**2
        too_wide = max(1.0 / abs(z_hi) - 1.0 / abs(c.z), 1.0 / abs(c.z) - 1.0 / abs(z_lo)) > cell_q
        wide_across = max(across[k][1] - c.y, c.y - across[k][0]) > r_c.transverse_mm
        if (not (too_wide or wide_across) and z_lo >= c.interval[0]
                and z_hi <= c.interval[1]):
            continue
        # the run ends at the grid's edge or where the region seen is left: open there
        open_far = (c.open_ends[0] or z_lo <= z_far_limit
                    or (z_lo == zs[lo_i] and lo_i > 0 and c.mf_profile[lo_i - 1] == 0.0))
        open_near = (c.open_ends[1] or z_hi >= z_near_limit
                     or (z_hi == zs[hi_i] and hi_i < zs.size - 1
                         and c.mf_profile[hi_i + 1] == 0.0))
        interval = (z_far_limit if open_far else min(c.interval[0], z_lo),
                    z_near_limit if open_near else max(c.interval[1], z_hi))
        if c.quality != "unresolved" or wide_across:
            what = ("its position" if wide_across and too_wide else
                    "its position across" if wide_across else "its depth")
            notes.append(f"the object at ({c.y:.1f}, {c.z:.1f}) mm ({signif[k]:.1f}σ, threshold "
                         f"{s_star:.1f}σ) is too faint to fix {what} to one resolution "
                         f"cell: its data fit y = {across[k][0]:.1f}…{across[k][1]:.1f} mm, "
                         f"z = {z_lo:.1f}…{z_hi:.1f} mm"
                         + (" (at least: the region reaches the edge of the ±4 cells examined)"
                            if at_edge else "")
                         + f" within the threshold's Δχ² = {s_star**2:.1f}; it is flagged "
                           f"unresolved")
        cands[k] = replace(c, interval=interval, open_ends=(bool(open_far), bool(open_near)),
                           quality="unresolved")
    bright_rp, bright_conv, res, intervals = [], [], [], []
    for k, c in enumerate(cands):
        lf_own = lf_wall
        if noise is not None and len(cands) > 1:
            # brightness of this object alone: the others' fitted responses removed, so a
            # bright neighbour's side lobes do not add to (or subtract from) it
            others = sum(float(amps[j]) * point_response(lf_wall, *cands_pos[j], phi).radiance
                         for i, gr in enumerate(groups) if i != k for j in gr)
            lf_own = lf_wall.with_radiance(np.asarray(lf_wall.radiance) - others)
        row = refocus(lf_own, y_mm=[c.y], z_mm=[c.z], solvable_domain_rad=(a, b))
        bright_rp.append(float(row.radiance_preserving[0, 0]))
        bright_conv.append(float(row.conventional[0, 0]))
        res.append(resolution(c.z))
        intervals.append(c.interval)
    below.sort(key=lambda cs: (-cs[1], cs[0].y, cs[0].z))
    free = [(c, sg) for c, sg in below if not shadowed(c, cands)]
    if free and np.isfinite(s_star):
        c, sg = free[0]
        notes.append(f"{len(free)} candidate(s) below the {s_star:.1f}σ threshold away from the "
                     f"reported objects (beyond {SHADOW_BLURS:g} blurs across), the strongest at "
                     f"y = {c.y:.1f}, z = {c.z:.1f} mm ({sg:.1f}σ): a dim object there would "
                     f"look like this — more exposure or frames would tell"
                     + (f"; {len(below) - len(free)} more in the reported objects' shadows "
                        f"(their model mismatch)" if len(below) > len(free) else ""))
    notes += _inseparable_notes(cands, res)
    n = len(cands)
    m = len(below)
    return Detection(
        count=n,
        positions_mm=np.asarray([(c.y, c.z) for c in cands], dtype=float).reshape(n, 2),
        brightness_rp=np.asarray(bright_rp),
        brightness_conventional=np.asarray(bright_conv),
        resolutions=tuple(res),
        stack=st,
        depth_profiles=np.asarray([c.profile for c in cands], dtype=float).reshape(n, zs.size),
        depth_interval_mm=np.asarray(intervals, dtype=float).reshape(n, 2),
        quality=tuple(c.quality for c in cands),
        depth_estimates_mm=np.asarray([c.estimates for c in cands], dtype=float).reshape(n, 3),
        depth_open=np.asarray([c.open_ends for c in cands], dtype=bool).reshape(n, 2),
        extent_mm=np.asarray(extent, dtype=float).reshape(n, 2),
        components_mm=tuple(np.asarray(mb, dtype=float).reshape(-1, 2) for mb in members),
        significance=np.asarray(signif, dtype=float).reshape(n),
        false_alarm=(false_alarm_probability(signif, n_cells) if tail is None
                     else tail.probability(signif)).reshape(n),
        threshold_sigma=float(s_star),
        resolution_cells=float(n_cells),
        below_positions_mm=np.asarray([(c.y, c.z) for c, _ in below],
                                      dtype=float).reshape(m, 2),
        below_significance=np.asarray([sg for _, sg in below], dtype=float).reshape(m),
        notes=tuple(notes),
        extended_tests=tuple((*cands_pos[i], *cands_pos[j], t.statistic, t.penalty)
                             for (i, j), t in pair_tests.items()),
        across_interval_mm=np.asarray(across, dtype=float).reshape(n, 2),
    )
