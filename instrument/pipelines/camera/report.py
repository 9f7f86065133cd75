"""The camera-characterization report: photon-transfer and linearity plots (PNG, Agg).

The panels are those of an EMVA 1288 data sheet (Release 4.0 Linear, §6): the photon
transfer curve σ²_y − σ²_y.dark against μ_y − μ_y.dark with the fitted K and its fit range,
and the linearity μ_y − μ_y.dark against the exposure with the fitted line and the relative
deviation δ that defines LE.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.emva1288 import CameraCharacterization

__all__ = ["characterization_figure"]


def characterization_figure(r: CameraCharacterization, path: str | Path, *,
                            title: str = "") -> Path:
    """Write the three-panel report figure to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    signal = r.mean_dn - r.mean_dark_dn
    excess = r.var_dn2 - r.var_dark_dn2
    t_ms = r.exposures_us * 1e-3
    fig, (ax0, ax1, ax2) = plt.subplots(1, 3, figsize=(15, 4.6), layout="constrained")

    g = r.gain_fit_mask
    ax0.plot(signal[~g], excess[~g], "o", mfc="none", color="0.5", label="not fitted")
    ax0.plot(signal[g], excess[g], "o", color="C0", label="fitted (0–70 % of saturation)")
    x = np.linspace(0.0, float(signal[g].max()), 50)
    ax0.plot(x, r.system_gain_dn_per_e * x, "-", color="C1",
             label=f"K = {r.system_gain_dn_per_e:.4g} ± {r.u_system_gain_dn_per_e:.2g} DN/e⁻")
    ax0.axvline(r.saturation_dn - float(r.mean_dark_dn[np.argmax(r.var_dn2)]), ls=":",
                color="C3", label=f"saturation {r.saturation_capacity_e:.4g} e⁻")
    ax0.set_xlabel("mean signal μ_y − μ_y.dark (DN)")
    ax0.set_ylabel("temporal variance σ²_y − σ²_y.dark (DN²)")
    ax0.set_title("photon transfer")
    ax0.legend(fontsize=8)

    lin = r.linearity_fit_mask
    ax1.plot(t_ms[~lin], signal[~lin], "o", mfc="none", color="0.5", label="not fitted")
    ax1.plot(t_ms[lin], signal[lin], "o", color="C0", label="fitted (5–95 % of saturation)")
    ax1.plot(t_ms, r.linearity_fit_dn, "-", color="C1", label="straight line")
    ax1.set_xlabel("exposure time (ms) ∝ photons per pixel")
    ax1.set_ylabel("mean signal μ_y − μ_y.dark (DN)")
    ax1.set_title("linearity")
    ax1.legend(fontsize=8)

    ax2.axhline(0.0, color="0.6", lw=0.8)
    ax2.plot(signal[lin], r.linearity_deviation_percent[lin], "o-", color="C0")
    ax2.set_xlabel("mean signal μ_y − μ_y.dark (DN)")
    ax2.set_ylabel("deviation from the line δ (%)")
    ax2.set_title(f"linearity error LE = {r.linearity_error_percent:.3g} ± "
                  f"{r.u_linearity_error_percent:.2g} %")
    if title:
        fig.suptitle(title)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
