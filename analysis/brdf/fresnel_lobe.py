"""Microfacet lobes whose Fresnel factor carries the refractive index as fitted parameters.

f = F(cos β; n̂) · D_GGX(h; α) · V_Smith(ωi, ωr; α)  (1/sr),

the Cook–Torrance / Walter form of :func:`analysis.brdf.specular.cook_torrance` (Walter et
al., EGSR 2007, eq. 20; height-correlated Smith visibility, Heitz, JCGT 3(2) 2014, eq. 99)
with **no free specular scale**: a surface of smooth facets of relative index
n̂ = n + ik reflects the fraction F of the light that reaches a facet, so the lobe's
absolute level *is* the Fresnel reflectance and fixes n (a measured, absolute BRDF is
needed for that; a relative one only up to its scale).

Fresnel factor: unpolarised R = (R_s + R_p)/2 at the facet's incidence angle β
(cos β = ωi·h), exact for an absorbing medium (Born & Wolf, *Principles of Optics*, 7th
ed., §1.5.2 eq. (21) and §14.2, whose n̂ = n(1 + iκ) is our n + ik with k = nκ; Hecht,
*Optics*, 4th ed., §4.6.2 eqs. (4.34) and (4.40) with μ_i = μ_t). **Sign convention:**
time dependence exp(−iωt), absorbing medium n̂ = n + ik with k ≥ 0 (ellipsometry and
some renderers write n − ik; intensities are the same). Implementation and branch choice:
:mod:`analysis.brdf.fresnel`.

Identities the tests check: R(0) = ((n−1)² + k²)/((n+1)² + k²); R_p = 0 at Brewster's
angle tan θ_B = n (k = 0); the lobe's directional–hemispherical reflectance ≤ R ≤ 1.

Identifiability: with k = 0 (a dielectric), n sets the level and, weakly, the rise towards
grazing; α the width. For an absorber, n and k are strongly correlated in an in-plane scan
(both raise R(0)); the conductor model fits both, and the fit's covariance says how well
they are separated — fix k (``ggx_fresnel``) when it is known to be 0.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from analysis.brdf import microfacet as mf
from analysis.brdf.fresnel import fresnel_unpolarized_dn
from analysis.brdf.geometry import Geometry
from analysis.brdf.model import BRDFModel, ParamSpec

__all__ = ["fresnel_microfacet"]

#: The lowest real index fitted without absorption: at n → 1 the interface vanishes
#: (R → 0) and below 1 total internal reflection makes ∂R/∂n singular at the critical angle.
N_MIN = 1.001


def fresnel_microfacet(*, absorbing: bool = False) -> BRDFModel:
    """GGX microfacet lobe with the exact unpolarised Fresnel factor of n (and k).

    Parameters
    ----------
    absorbing : bool
        False: parameters (n, alpha), k ≡ 0 (registry name ``ggx_fresnel``); True:
        (n, k, alpha) (``ggx_conductor``).

    Returns
    -------
    BRDFModel
        With an analytic Jacobian (∂R/∂n, ∂R/∂k from
        :func:`analysis.brdf.fresnel.fresnel_unpolarized_dn`).
    """
    name = "ggx_conductor" if absorbing else "ggx_fresnel"

    def index(p: NDArray[Any]) -> complex:
        return complex(p[0], p[1]) if absorbing else complex(p[0], 0.0)

    def fres(p: NDArray[Any], g: Geometry) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
        n = index(p)
        key = ("fresnel_dn", n)
        hit = g.cache.get(key)
        if hit is None:
            hit = fresnel_unpolarized_dn(g.cos_beta, n)
            g.cache[key] = hit
        return hit

    def shape_terms(a: float, g: Geometry) -> tuple[NDArray[Any], NDArray[Any]]:
        """(D·V, ∂(D·V)/∂α) at width a."""
        c = g.cos_theta_h
        v, si, sr = mf.ggx_smith_visibility_parts(g.mu_i, g.mu_r, a)
        d = mf.ggx_d(c, a)
        dv = mf.ggx_smith_dv_dalpha(g.mu_i, g.mu_r, a, v, si, sr)
        return d * v, mf.ggx_d_dalpha(c, a) * v + d * dv

    def value(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        r, _, _ = fres(p, g)
        c = g.cos_theta_h
        v, _, _ = mf.ggx_smith_visibility_parts(g.mu_i, g.mu_r, float(p[-1]))
        return r * mf.ggx_d(c, float(p[-1])) * v

    def jac(p: NDArray[Any], g: Geometry) -> NDArray[Any]:
        r, dn, dk = fres(p, g)
        dv, ddv = shape_terms(float(p[-1]), g)
        cols = [dn * dv] + ([dk * dv] if absorbing else []) + [r * ddv]
        return np.stack(np.broadcast_arrays(*cols), axis=-1)

    # an absorber may have n < 1 (metals); without absorption n ≥ N_MIN
    params = [ParamSpec("n", "1", 0.01 if absorbing else N_MIN, 6.0, 1.5,
                        description="real part of the relative refractive index")]
    if absorbing:
        params.append(ParamSpec("k", "1", 0.0, 20.0, 1.0,
                                description="extinction coefficient (n̂ = n + ik)"))
    params.append(ParamSpec("alpha", "1", 1e-3, 2.0, 0.3, log=True,
                            description="GGX roughness α"))
    kind = "absorbing n + ik" if absorbing else "dielectric n (k = 0)"
    return BRDFModel(
        name=name,
        params=tuple(params),
        value_fn=value,
        jac_fn=jac,
        description=f"GGX microfacet lobe with the exact unpolarised Fresnel factor of a "
        f"{kind}; no free scale: the level is the Fresnel reflectance.",
        validity="geometric optics (roughness ≫ wavelength), single scattering; energy "
        "bounded (DHR ≤ R ≤ 1); needs absolute BRDF values to identify n",
        reference="Born & Wolf §1.5.2, §14.2; Hecht §4.6.2; Walter et al. 2007; Heitz 2014",
    )
