"""The relighting figure of a sphere capture (PNG, matplotlib with the Agg backend).

Equation numbers are those of Mahajan, Ramamoorthi & Curless, "A theory of spherical
harmonic identities for BRDF/lighting transfer and image consistency" (ECCV 2006).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from instrument.pipelines.spheres.analyse import SphereAnalysis
from instrument.pipelines.spheres.capture import SphereCapture

__all__ = ["relighting_figure"]


def relighting_figure(capture: SphereCapture, result: SphereAnalysis,
                      path: str | Path) -> Path:
    """The four corner images, the rendered B^{r,s}, its error, and M21 against noise."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, s = capture.radiance.shape[:2]
    unit = (capture.units.replace("m-2", "m⁻²").replace("sr-1", "sr⁻¹")
            .replace("DN/us", "DN/µs"))
    fig, axes = plt.subplots(2, 4, figsize=(14, 7.0), layout="constrained")
    vmax = float(np.nanpercentile(capture.radiance[..., result.observed], 99.5))
    corners = [(0, 0), (0, s - 1), (r - 1, 0), (r - 1, s - 1)]
    for ax, (k, j) in zip(axes[0], corners, strict=True):
        im = ax.imshow(capture.radiance[k, j], cmap="magma", vmin=0, vmax=vmax)
        ax.set_title(f"{capture.objects[j]}, {capture.lighting_role} "
                     f"{capture.lighting_deg[k]:g}°", fontsize=9)
    # the measured images and the rendered one share one colour scale
    fig.colorbar(im, ax=axes[0, :], fraction=0.02, pad=0.01, label=f"radiance ({unit})")
    ax = axes[1, 0]
    im = ax.imshow(np.where(result.observed, result.predicted, np.nan), cmap="magma", vmin=0,
                   vmax=vmax)
    fig.colorbar(im, ax=ax, fraction=0.046, label=f"radiance ({unit})")
    ax.set_title(f"{capture.objects[-1]}, {capture.lighting_role} "
                 f"{capture.lighting_deg[-1]:g}°, rendered\nfrom the other three: L1 error "
                 f"{100 * result.relight_l1:.2f} %", fontsize=9)
    ax = axes[1, 1]
    diff = np.where(result.observed, result.predicted - result.measured, np.nan)
    lim = float(np.nanmax(np.abs(diff))) or 1.0
    im = ax.imshow(diff, cmap="RdBu_r", vmin=-lim, vmax=lim)
    fig.colorbar(im, ax=ax, fraction=0.046, label=f"rendered − measured ({unit})")
    ax.set_title("rendered − measured", fontsize=9)
    ax = axes[1, 2]
    l = np.arange(result.gamma.size)
    ax.plot(l, result.gamma, "o-", ms=3)
    ax.set_xlabel("SH order l")
    ax.set_ylabel("γ_l (dimensionless)")
    ax.set_title(f"BRDF transfer γ_l = B_l({capture.objects[-1]}) / "
                 f"B_l({capture.objects[0]}), eq. 15", fontsize=9)
    ax = axes[1, 3]
    rep = result.consistency
    ax.semilogy(rep.orders, rep.error, "o-", ms=3, label="error of identity eq. 21")
    ax.semilogy(rep.orders, rep.noise_error, "k--", label="noise level")
    ax.set_xlabel("SH order l")
    ax.set_ylabel("normalised error |X − Y|/(|X| + |Y|)")
    verdict = rep.verdict
    ax.set_title(f"consistency: T = {rep.statistic:.3g} (threshold {rep.threshold:.3g}),\n"
                 f"{verdict} at false-alarm rate {rep.false_alarm:g}", fontsize=9)
    ax.legend(fontsize=8)
    for a in axes[0]:
        a.set_xticks([])
        a.set_yticks([])
    for a in axes[1, :2]:
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle("Sphere capture: measured images (top), relighting and consistency (bottom); "
                 "equations of Mahajan, Ramamoorthi & Curless (ECCV 2006)", fontsize=10)
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
