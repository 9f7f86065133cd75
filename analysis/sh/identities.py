"""Spherical-harmonic identities, BRDF/lighting transfer and diffuse/specular separation.

Mahajan, Ramamoorthi & Curless, "A theory of frequency domain invariants: spherical harmonic
identities for BRDF/lighting transfer and image consistency", IEEE PAMI 30(2), 2008 (ECCV 2006);
equation tags M4 … M25 are the equation numbers of the ECCV 2006 paper. All images are in the
reflected parameterisation (coefficients of B(R), R the reflected view direction) unless said
otherwise; coefficients use the flat layout of :mod:`analysis.sh.convention`.

Each identity is reported per order l as the normalised error
e_l = ‖X_l − Y_l‖ / (‖X_l‖ + ‖Y_l‖) between its two sides (0 ≤ e_l ≤ 1; taken as 0 with
``defined`` False where both sides vanish), which a consistency test compares with the
error that noise alone produces (:mod:`analysis.sh.consistency`), never with zero.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from analysis.sh.convention import band_slice
from analysis.sh.filters import lambertian_filter
from analysis.sh.transform import analysis, directions_to_angles, evaluate, gl_grid
from analysis.sh.validation import (
    SHInputError,
    check_coefficients,
    check_degree,
    check_finite,
    check_scalar,
)

__all__ = [
    "AlbedoRatio",
    "IdentityError",
    "SeparationResult",
    "TransferResult",
    "albedo_ratio",
    "brdf_transfer",
    "diffuse_plus_specular",
    "four_images",
    "irradiance_reflected",
    "known_lighting",
    "lighting_transfer",
    "one_object_two_lightings",
    "rank_one",
    "render_missing_image",
    "separate_diffuse_specular",
    "two_objects_one_lighting",
]


@dataclass(frozen=True)
class IdentityError:
    """Per-order normalised error of an identity.

    Attributes
    ----------
    name : str
    orders : ndarray of int, shape (n,)
    error : ndarray of shape (n,)
        e_l = ‖X_l − Y_l‖ / (‖X_l‖ + ‖Y_l‖).
    defined : ndarray of bool, shape (n,)
        False where both sides vanish (or the identity has no content at that l).
    estimate : ndarray of shape (n,)
        The per-order quantity the identity determines on the way (A_l for M12, γ_l for
        M16, …), nan where it has none.
    """

    name: str
    orders: np.ndarray
    error: np.ndarray
    defined: np.ndarray
    estimate: np.ndarray


def _checked(**coeffs: np.ndarray) -> tuple[int, list[np.ndarray]]:
    """The band limit shared by finite coefficient vectors, and the vectors as float arrays.

    Raises SHInputError naming the first non-finite, malformed or mismatched argument.
    """
    out, lmax = [], None
    for name, value in coeffs.items():
        arr, l = check_coefficients(name, value)
        if lmax is not None and l != lmax:
            first = next(iter(coeffs))
            raise SHInputError(name, f"has band limit L = {l}, {first} has L = {lmax}: all "
                               "coefficient vectors must have the same band limit")
        lmax = l
        out.append(arr)
    assert lmax is not None  # at least one array was given
    return int(lmax), out


def _normalised(x: np.ndarray, y: np.ndarray) -> tuple[float, bool]:
    den = float(np.linalg.norm(x) + np.linalg.norm(y))
    if den == 0.0:
        return 0.0, False
    return float(np.linalg.norm(x - y) / den), True


def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.triu_indices(n, k=1)
    return i, j


def _collect(name: str, lmin: int, lmax: int,
             per_l: Callable[[int], tuple[float, bool, float]]) -> IdentityError:
    orders = np.arange(lmin, lmax + 1)
    err = np.zeros(orders.size)
    ok = np.zeros(orders.size, dtype=bool)
    est = np.full(orders.size, np.nan)
    for idx, l in enumerate(orders):
        err[idx], ok[idx], est[idx] = per_l(int(l))
    return IdentityError(name, orders, err, ok, est)


def _product_identity(name: str, arrays: dict[str, np.ndarray], lmin: int) -> IdentityError:
    """Per-order normalised error of X_lm Y_lm = U_lm V_lm (the form of M19 and M21);
    ``arrays`` holds X, Y, U, V under their argument names."""
    lmax, (x, y, u, v) = _checked(**arrays)
    check_degree("lmin", lmin)

    def per_l(l: int) -> tuple[float, bool, float]:
        s = band_slice(l)
        e, ok = _normalised(x[s] * y[s], u[s] * v[s])
        return e, ok, np.nan

    return _collect(name, lmin, lmax, per_l)


def known_lighting(image: np.ndarray, lighting: np.ndarray, *, lmin: int = 1) -> IdentityError:
    """Known lighting, unknown radially symmetric BRDF: B_li L_lj − B_lj L_li = 0 (M10).

    Also returns the least-squares A_l = Σ_m B_lm L_lm / Σ_m L_lm² as ``estimate``.
    """
    lmax, (b, lig) = _checked(image=image, lighting=lighting)
    check_degree("lmin", lmin)

    def per_l(l: int) -> tuple[float, bool, float]:
        bl, ll = b[band_slice(l)], lig[band_slice(l)]
        i, j = _pairs(2 * l + 1)
        e, ok = _normalised(bl[i] * ll[j], bl[j] * ll[i])
        den = float(ll @ ll)
        return e, ok and i.size > 0, (bl @ ll) / den if den > 0 else np.nan

    return _collect("M10 known lighting", lmin, lmax, per_l)


def diffuse_plus_specular(
    image: np.ndarray, lighting: np.ndarray, irradiance: np.ndarray, *, lmin: int = 1
) -> IdentityError:
    """Diffuse + specular: B_lm = K_d D_lm + A_l L_lm (M12, consistency form M13).

    M12 gives A_l = (B_li D_lj − B_lj D_li) / (L_li D_lj − L_lj D_li) for every pair
    (i, j) of orders in band l, eliminating the unknown K_d; the least-squares A_l over all
    pairs is returned as ``estimate``, and the error compares the pair numerators with
    A_l times the denominators (M13: the ratio is the same for all pairs).

    Parameters
    ----------
    image, lighting : ndarray of shape ((L+1)²,)
    irradiance : ndarray of shape ((L+1)²,)
        D_lm, the irradiance in the reflected parameterisation
        (:func:`irradiance_reflected` or its image-space counterpart).
    """
    lmax, (b, lig, d) = _checked(image=image, lighting=lighting, irradiance=irradiance)
    check_degree("lmin", lmin)

    def per_l(l: int) -> tuple[float, bool, float]:
        s = band_slice(l)
        bl, ll, dl = b[s], lig[s], d[s]
        i, j = _pairs(2 * l + 1)
        num = bl[i] * dl[j] - bl[j] * dl[i]
        den = ll[i] * dl[j] - ll[j] * dl[i]
        dd = float(den @ den)
        if i.size == 0 or dd == 0.0:
            return 0.0, False, np.nan
        a_l = float(num @ den) / dd
        e, ok = _normalised(num, a_l * den)
        return e, ok, a_l

    return _collect("M12/M13 diffuse + specular", lmin, lmax, per_l)


def two_objects_one_lighting(
    image1: np.ndarray, image2: np.ndarray, *, lmin: int = 1
) -> IdentityError:
    """Two objects (BRDFs) in one lighting: B²_li B¹_lj − B¹_li B²_lj = 0 (M16).

    ``estimate`` is the BRDF transfer γ_l = A²_l/A¹_l averaged over m (M15).
    """
    lmax, (b1, b2) = _checked(image1=image1, image2=image2)
    check_degree("lmin", lmin)

    def per_l(l: int) -> tuple[float, bool, float]:
        s = band_slice(l)
        x1, x2 = b1[s], b2[s]
        i, j = _pairs(2 * l + 1)
        e, ok = _normalised(x2[i] * x1[j], x1[i] * x2[j])
        den = float(x1 @ x1)
        return e, ok and i.size > 0, float(x1 @ x2) / den if den > 0 else np.nan

    return _collect("M16 two objects, one lighting", lmin, lmax, per_l)


def one_object_two_lightings(
    image1: np.ndarray,
    image2: np.ndarray,
    lighting1: np.ndarray,
    lighting2: np.ndarray,
    *,
    lmin: int = 0,
) -> IdentityError:
    """One object in two known lightings: B²_lm L¹_lm − B¹_lm L²_lm = 0 (M19)."""
    return _product_identity("M19 one object, two lightings",
                             {"image2": image2, "lighting1": lighting1, "image1": image1,
                              "lighting2": lighting2}, lmin)


def four_images(
    b11: np.ndarray, b12: np.ndarray, b21: np.ndarray, b22: np.ndarray, *, lmin: int = 0
) -> IdentityError:
    """Two objects × two lightings: B^{1,1} B^{2,2} = B^{1,2} B^{2,1} per (l, m) (M20/M21).

    Superscripts are (lighting, material); the identity needs neither lighting nor BRDF.
    """
    return _product_identity("M21 two objects x two lightings",
                             {"b11": b11, "b22": b22, "b12": b12, "b21": b21}, lmin)


def rank_one(images: np.ndarray, *, lmin: int = 0) -> IdentityError:
    """r lightings × s materials: per band, the matrix B_lm = L_lm A_lᵀ has rank 1 (M25).

    Parameters
    ----------
    images : ndarray of shape (r, s, (L+1)²)
        Image coefficients for lighting i and material j.

    Notes
    -----
    Stacking the 2l+1 orders of a band gives an (r(2l+1)) × s matrix (vec L_l) A_lᵀ, still of
    rank 1. The error is √(Σ_{k≥2} σ_k²) / σ_1 (0 for an exact rank-1 matrix), and
    ``estimate`` is σ_2/σ_1.
    """
    imgs = check_finite("images", images, ndim=3)
    n = imgs.shape[2]
    lmax = int(np.sqrt(n)) - 1
    if lmax < 0 or (lmax + 1) ** 2 != n:
        raise SHInputError("images", f"must have shape (r, s, (L+1)²), got {imgs.shape}")
    check_degree("lmin", lmin)

    def per_l(l: int) -> tuple[float, bool, float]:
        blk = imgs[:, :, band_slice(l)]  # (r, s, 2l+1)
        mat = np.moveaxis(blk, 2, 1).reshape(-1, imgs.shape[1])
        sv = np.linalg.svd(mat, compute_uv=False)
        if sv.size == 0 or sv[0] == 0.0:
            return 0.0, False, np.nan
        tail = float(np.sqrt(np.sum(sv[1:] ** 2)))
        return tail / float(sv[0]), sv.size > 1, float(sv[1] / sv[0]) if sv.size > 1 else 0.0

    return _collect("M25 rank one", lmin, lmax, per_l)


@dataclass(frozen=True)
class TransferResult:
    """A per-band (BRDF) or per-coefficient (lighting) transfer function.

    Attributes
    ----------
    values : ndarray
        γ_l of shape (L+1,) for BRDF transfer; L'_lm of shape ((L+1)²,) for lighting.
    reliable : ndarray of bool, same shape
        False where the source image holds too little signal for the ratio (there the
        value is damped towards 0 by the regularisation ``k``).
    k : float
        Regularisation added to the denominator, in coefficient² units.
    """

    values: np.ndarray
    reliable: np.ndarray
    k: float


def brdf_transfer(image1: np.ndarray, image2: np.ndarray, *, k: float = 0.0) -> TransferResult:
    """BRDF transfer γ_l = A²_l/A¹_l from two objects in one lighting (M15).

    γ_l = Σ_m B²_lm B¹_lm / (Σ_m (B¹_lm)² + k): the least-squares average over m, which
    weights orders by their signal.
    """
    lmax, (b1, b2) = _checked(image1=image1, image2=image2)
    k = check_scalar("k", k, low=0.0)
    g = np.zeros(lmax + 1)
    ok = np.zeros(lmax + 1, dtype=bool)
    for l in range(lmax + 1):
        s = band_slice(l)
        den = float(b1[s] @ b1[s]) + k
        if den > 0:
            g[l] = float(b1[s] @ b2[s]) / den
            ok[l] = float(b1[s] @ b1[s]) > k
    return TransferResult(g, ok, float(k))


def lighting_transfer(
    image1: np.ndarray, image2: np.ndarray, *, k: float = 0.0
) -> TransferResult:
    """Lighting transfer L'_lm = B²_lm/B¹_lm = L²_lm/L¹_lm, one object in two lightings (M18).

    Evaluated as B²B¹/((B¹)² + k) so that a vanishing B¹_lm gives 0, never inf/NaN.
    """
    _, (b1, b2) = _checked(image1=image1, image2=image2)
    k = check_scalar("k", k, low=0.0)
    den = b1 * b1 + k
    vals = np.divide(b2 * b1, den, out=np.zeros_like(b1), where=den > 0)
    return TransferResult(vals, b1 * b1 > k, float(k))


def render_missing_image(
    b11: np.ndarray,
    b12: np.ndarray,
    b21: np.ndarray,
    *,
    route: str = "brdf",
    k: float = 0.0,
) -> np.ndarray:
    """Render B^{2,2} (lighting 2, material 2) from the other three images (M20).

    ``route="brdf"`` (preferred, more robust): γ_l from B^{1,2}/B^{1,1} averaged over m,
    then B^{2,2} = γ_l B^{2,1}. ``route="lighting"``: L'_lm from B^{2,1}/B^{1,1}, then
    B^{2,2} = L'_lm B^{1,2}.

    Returns
    -------
    ndarray of shape ((L+1)²,)
    """
    lmax, (b11, b12, b21) = _checked(b11=b11, b12=b12, b21=b21)
    if route == "brdf":
        gamma = brdf_transfer(b11, b12, k=k).values
        l = np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)
        return b21 * gamma[l]
    if route == "lighting":
        return lighting_transfer(b11, b21, k=k).values * b12
    raise SHInputError("route", f"must be 'brdf' or 'lighting', got {route!r}")


def irradiance_reflected(
    lighting: np.ndarray,
    *,
    lmax: int,
    view: tuple[float, float, float] = (0.0, 0.0, 1.0),
    grid_lmax: int | None = None,
) -> np.ndarray:
    """D_lm: Lambertian irradiance E(n) re-expressed in the reflected parameterisation.

    For a distant viewer v the reflected direction is R = 2(n·v)n − v, so n(R) =
    (R + v)/|R + v|. D(R) = E(n(R)) with E_lm = Â_l L_lm is sampled on a Gauss–Legendre grid
    of degree ``grid_lmax`` (default 4·lmax) and analysed; D is not band-limited in R (the
    map halves angles, and R → −v is the silhouette), so the finer grid keeps aliasing
    out of the degrees ≤ lmax that are returned (M12; Mahajan et al. §5).

    Returns
    -------
    ndarray of shape ((lmax+1)²,)
    """
    lig, ll = check_coefficients("lighting", lighting)
    lmax = check_degree("lmax", lmax)
    if grid_lmax is not None:
        check_degree("grid_lmax", grid_lmax, minimum=lmax)
    gl = grid_lmax if grid_lmax is not None else max(4 * lmax, 2 * ll, 8)
    v = check_finite("view", view)
    if v.shape != (3,) or not np.linalg.norm(v) > 0:
        raise SHInputError("view", f"must be a non-zero 3-vector, got {view!r}")
    v = v / np.linalg.norm(v)
    grid = gl_grid(gl)
    tt, pp = np.meshgrid(grid.theta, grid.phi, indexing="ij")
    r = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1)
    h = r + v
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    n = h / np.where(norm > 0, norm, 1.0)
    a = lambertian_filter(ll).values
    l_idx = np.repeat(np.arange(ll + 1), 2 * np.arange(ll + 1) + 1)
    e_coeffs = lig * a[l_idx]
    nt, nph = directions_to_angles(n)
    d = evaluate(e_coeffs, nt, nph)
    full = analysis(d, grid=grid)
    return full[: (lmax + 1) ** 2]


@dataclass(frozen=True)
class SeparationResult:
    """Diffuse and specular parts of an image in the normal parameterisation.

    Attributes
    ----------
    diffuse : ndarray of shape ((L+1)²,)
        The l ≤ ``lmax_diffuse`` coefficients (zero above).
    specular : ndarray of shape ((L+1)²,)
        The remaining l > ``lmax_diffuse`` coefficients.
    diffuse_energy_fraction : float
        Share of the image energy Σ c² assigned to the diffuse part.
    lmax_diffuse : int
    """

    diffuse: np.ndarray
    specular: np.ndarray
    diffuse_energy_fraction: float
    lmax_diffuse: int


def separate_diffuse_specular(
    image_normal: np.ndarray, *, lmax_diffuse: int = 2
) -> SeparationResult:
    """Split an image (normal parameterisation) into l ≤ 2 diffuse and l > 2 specular parts.

    The Lambertian kernel keeps 99.2 % of its energy in l ≤ 2 (Basri & Jacobs, PAMI 25(2), 2003),
    so in the normal parameterisation those terms are taken as diffuse and the rest as specular
    (Mahajan et al. §6). The specular lobe's own l ≤ 2 content is assigned to the diffuse part: the
    standard approximation of the method.
    """
    c, _ = check_coefficients("image_normal", image_normal)
    cut = (check_degree("lmax_diffuse", lmax_diffuse) + 1) ** 2
    diffuse = np.zeros_like(c)
    diffuse[:cut] = c[:cut]
    specular = c - diffuse
    tot = float(c @ c)
    frac = float(diffuse @ diffuse) / tot if tot > 0 else 0.0
    return SeparationResult(diffuse, specular, frac, lmax_diffuse)


@dataclass(frozen=True)
class AlbedoRatio:
    """ρ₂/ρ₁ and its standard error."""

    ratio: float
    std: float


def albedo_ratio(
    diffuse1: np.ndarray, diffuse2: np.ndarray, *, mask: np.ndarray | None = None
) -> AlbedoRatio:
    """Spatial-domain analogue of γ_l for the diffuse part: the albedo ratio ρ₂/ρ₁.

    Two diffuse images of the same shape in the same lighting differ by the albedo ratio
    only, so ρ₂/ρ₁ = Σ I₁I₂ / Σ I₁² over the pixels in ``mask``.

    Returns
    -------
    AlbedoRatio
        The ratio and its standard error from the scatter of the residuals.
    """
    i1 = np.asarray(diffuse1, dtype=float)
    i2 = np.asarray(diffuse2, dtype=float)
    if i1.shape != i2.shape:
        raise SHInputError("diffuse2", f"must have the shape of diffuse1 {i1.shape}, got "
                           f"{i2.shape}")
    # Non-finite pixels mark unusable data in an image: left out by design.
    use = np.isfinite(i1) & np.isfinite(i2)
    if mask is not None:
        use &= np.asarray(mask, dtype=bool)
    x, y = i1[use], i2[use]
    den = float(x @ x)
    if den == 0.0 or x.size < 2:
        raise SHInputError("diffuse1", "holds no signal in the usable pixels")
    ratio = float(x @ y) / den
    resid = y - ratio * x
    std = float(np.sqrt(resid @ resid / (x.size - 1) / den))
    return AlbedoRatio(ratio, std)
