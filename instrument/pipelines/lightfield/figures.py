"""Figures of a light-field analysis (PNG, matplotlib with the Agg backend).

Reconstruction: the measured light field L_meas(y_m, θ_m), the reconstructed incident
field at the wall L_obj(c, θ), and the diagnostics (shared filter factors, pooled signal
spectrum against the noise power, the relative noise error Δ_p of Sasaki (2020, PhD thesis,
Univ. of Minnesota) eq. 2-37, and the degree of specularity γ and effective SNR along
the wall).  Localisation: the (y, z) map (RP refocusing) with the detected
objects and their theoretical blur, a focal stack (conventional refocusing at the
detected depths and a few others), and the depth-filter z-profiles.

matplotlib is imported here only, when figures are asked for.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from analysis.lightfield import Detection
from instrument.pipelines.lightfield.results import ReconstructionResult, median_delta_p

__all__ = ["localisation_figures", "reconstruction_figures"]


def _pyplot() -> Any:  # the matplotlib.pyplot module
    try:
        import matplotlib
    except ImportError as err:  # pragma: no cover - depends on the installation
        raise RuntimeError("figures need matplotlib (pip install matplotlib)") from err
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


#: The radiance unit of the light-field analysis: the camera's dark-subtracted signal rate,
#: proportional to radiance (no absolute calibration is needed to locate objects).
RADIANCE_UNIT = "DN/µs"


def _field_image(ax: Any, values: NDArray[Any], y: NDArray[Any], theta: NDArray[Any], title: str,
                 ylabel: str, clabel: str) -> None:
    extent = (float(np.degrees(theta[0])), float(np.degrees(theta[-1])), float(y[0]),
              float(y[-1]))
    im = ax.imshow(values, origin="lower", aspect="auto", extent=extent, cmap="magma")
    ax.set_xlabel("ray angle θ (deg)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.figure.colorbar(im, ax=ax, shrink=0.85, label=clabel)


def reconstruction_figures(r: ReconstructionResult, folder: str | Path) -> list[Path]:
    """Write measured.png, reconstructed.png and diagnostics.png; return their paths."""
    plt = _pyplot()
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    lf = r.measured.field
    rec = r.reconstruction
    paths = []

    fig, ax = plt.subplots(figsize=(7, 5))
    _field_image(ax, lf.radiance, lf.y_mm, lf.theta_rad,
                 f"measured light field, camera {lf.z_mm:g} mm from the wall",
                 "camera position y_m (mm)",
                 f"measured radiance (cos⁴-corrected; {RADIANCE_UNIT}, ∝ radiance)")
    paths.append(out / "measured.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 5))
    f = rec.incident_field
    _field_image(ax, f.radiance, f.y_mm, f.theta_rad,
                 f"reconstructed light field arriving at the wall "
                 f"({rec.regularization.method} filter)",
                 "wall point c (mm)", f"object radiance ({RADIANCE_UNIT}, ∝ radiance)")
    a, b = rec.solvable_domain_rad
    for k, t in enumerate((a, b)):
        ax.axvline(np.degrees(t), color="c", lw=0.8, ls="--",
                   label="solvable angle domain" if k == 0 else None)
    ax.legend(fontsize=8, loc="upper right")
    paths.append(out / "reconstructed.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    reg = rec.regularization
    diag = rec.diagnostics
    p = rec.orders
    order = np.argsort(p)
    fig, axs = plt.subplots(2, 2, figsize=(10, 7))
    phi = np.atleast_2d(reg.filter_factors).mean(axis=0)
    axs[0, 0].plot(p[order], phi[order], ".-")
    axs[0, 0].set_title(f"filter factors (p̂_max = {r.p_hat:g}, dof {reg.effective_dof:.1f})")
    axs[0, 0].set_xlabel("angular Fourier order p")
    axs[0, 0].set_ylabel("filter factor φ_p (1 kept, 0 suppressed)")
    sp = np.where(reg.signal_power > 0, reg.signal_power, np.nan)
    axs[0, 1].semilogy(p[order], sp[order], ".", label="pooled signal power")
    axs[0, 1].semilogy(p[order], reg.noise_power[order], "-", label="noise power σ²/|S|²")
    axs[0, 1].set_xlabel("angular Fourier order p")
    axs[0, 1].set_ylabel(f"power per order (({RADIANCE_UNIT})²)")
    axs[0, 1].legend(fontsize=8)
    axs[0, 1].set_title("signal and noise spectrum (per mode)")
    dp = median_delta_p(diag.delta_p)
    axs[1, 0].semilogy(p[order], dp[order], ".")
    axs[1, 0].axhline(1.0, color="k", lw=0.6)
    axs[1, 0].set_title("relative noise error Δ_p (Sasaki 2020, eq. 2-37)")
    axs[1, 0].set_xlabel("angular Fourier order p")
    axs[1, 0].set_ylabel("Δ_p, median over wall points\n(dimensionless; > 1: noise dominates)")
    c = rec.incident_field.y_mm
    line_g, = axs[1, 1].plot(c, diag.gamma, label="degree of specularity γ (left)")
    ax2 = axs[1, 1].twinx()
    line_s, = ax2.plot(c, diag.snr_eff, "r", label="effective SNR (right)")
    axs[1, 1].set_xlabel("wall point c (mm)")
    axs[1, 1].set_ylabel("γ (dimensionless; 1 specular, 0 diffuse)")
    ax2.set_ylabel("SNR_eff = γ · signal/noise (dimensionless)", color="r")
    axs[1, 1].legend(handles=[line_g, line_s], fontsize=8, loc="lower center")
    axs[1, 1].set_title("degree of specularity and effective SNR")
    fig.suptitle(rec.message, fontsize=8)
    fig.tight_layout()
    paths.append(out / "diagnostics.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)
    return paths


def localisation_figures(det: Detection, p_hat: float, folder: str | Path) -> list[Path]:
    """Write yz_map.png, focal_stack.png and z_profiles.png; return their paths."""
    plt = _pyplot()
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    st = det.stack
    paths = []
    extent = (float(st.y_mm[0]), float(st.y_mm[-1]), float(st.z_mm[0]), float(st.z_mm[-1]))

    fig, axs = plt.subplots(1, 2, figsize=(11, 5), sharey=True)
    for ax, img, title in ((axs[0], st.conventional, "conventional refocusing"),
                           (axs[1], st.radiance_preserving, "radiance-preserving (RP)")):
        im = ax.imshow(img, origin="lower", aspect="auto", extent=extent, cmap="viridis")
        fig.colorbar(im, ax=ax, shrink=0.85,
                     label=f"refocused radiance ({RADIANCE_UNIT}, ∝ radiance)")
        ax.set_xlabel("y (mm)")
        ax.set_title(title)
        for (y, z), res in zip(det.positions_mm, det.resolutions, strict=True):
            ax.plot(y, z, "r+", ms=10)
            ax.add_patch(plt.matplotlib.patches.Ellipse(
                (y, z), res.transverse_mm, res.depth_mm, fill=False, color="r", lw=0.8))
    axs[0].set_ylabel("depth z (mm; wall at 0, unfolded)")
    fig.suptitle(f"(y, z) map: {det.count} object(s) (red +), highest recovered angular "
                 f"order p̂_max = {p_hat:g}; ellipses: theoretical blur")
    paths.append(out / "yz_map.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    objects = {float(z): k for k, z in enumerate(det.positions_mm[:, 1])}
    # a few other depths for comparison, none so close to an object's that its curve
    # would hide under the object's
    gap = 0.08 * float(st.z_mm[-1] - st.z_mm[0])
    extra = [float(z) for z in np.linspace(st.z_mm[0], st.z_mm[-1], 6)[1:-1]
             if all(abs(z - zo) > gap for zo in objects)]
    depths = sorted(set(objects) | set(extra))[:8]
    fig, ax = plt.subplots(figsize=(8, 5))
    for z in depths:
        k = int(np.argmin(np.abs(st.z_mm - z)))
        who = f" (object {objects[z]})" if z in objects else ""
        ax.plot(st.y_mm, st.conventional[k], lw=1.8 if who else 1.0, ls="-" if who else "--",
                label=f"z = {st.z_mm[k]:.0f} mm{who}")
    for y, _ in det.positions_mm:
        ax.axvline(y, color="k", lw=0.5, ls=":")
    ax.set_xlabel("y (mm)")
    ax.set_ylabel(f"refocused radiance, conventional ({RADIANCE_UNIT}, ∝ radiance)")
    ax.set_title("focal stack: refocused at the depths of the objects and a few others "
                 "(dotted: objects' y)", fontsize=10)
    ax.legend(fontsize=8)
    paths.append(out / "focal_stack.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for k in range(det.count):
        y, z = det.positions_mm[k]
        ax.plot(st.z_mm, det.depth_profiles[k],
                label=f"object {k}: y = {y:.1f} mm, z = {z:.1f} mm")
        ax.axvline(z, color="k", lw=0.5, ls=":")
    ax.set_xlabel("depth z (mm; wall at 0)")
    ax.set_ylabel("depth-filter profile (dimensionless, peak 1)")
    ax.set_title("depth profiles of the objects: the peak is the depth estimate (dotted)",
                 fontsize=10)
    if det.count:
        ax.legend(fontsize=8)
    paths.append(out / "z_profiles.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)
    return paths
