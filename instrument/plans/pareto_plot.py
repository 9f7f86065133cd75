"""The speed/accuracy picture: σ against the scan's duration with the Pareto front, for the
scalar BRDF trade (:mod:`instrument.plans.tradeoff`, drawn by
``benchmarks/bench_brdf_tradeoff.py``) and the polarimetric one
(:mod:`instrument.plans.polarimetric_tradeoff`, drawn by ``scatterlab plan`` beside the
coverage picture).

Both draw the front with :func:`draw_front` on log-log axes of duration (s) and σ.
matplotlib is imported when a picture is drawn, not when this module is imported.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from instrument.plans.tradeoff import Traded, pareto_front

__all__ = ["draw_front", "write_polarimetric_tradeoff_png"]


def draw_front(ax: Any, front: Sequence[Traded], param: str, *, label: str | None = None,
               **style: Any) -> None:
    """The Pareto front (fastest first) as steps on ``ax``: each candidate's σ holds until
    a slower one improves on it."""
    ax.step([r.duration_s for r in front], [r.sigma[param] for r in front], where="post",
            label=label, **({"color": "k", "lw": 1.0} | style))


def write_polarimetric_tradeoff_png(results: Sequence[Any], path: str | Path, *,
                                    title: str = "", chosen: int | None = None) -> Path:
    """The polarimetric trade of ``results``
    (:class:`~instrument.plans.polarimetric_tradeoff.PolarimetricResult`) as a PNG:
    left, the mean and the worst predicted σ of the normalised elements against the
    duration with their Pareto fronts (each point labelled with its steps; ``chosen``, the
    plan's own steps, ringed); right, κ against the steps.

    Raises
    ------
    OSError
        ``path`` does not end in ``.png`` or cannot be written.
    """
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise OSError(f"trade-off picture {path}: the name must end in .png")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10.0, 4.4), layout="constrained",
                                 gridspec_kw={"width_ratios": [1.6, 1.0]})
    for param, marker, name in (("sigma_mean", "o", "mean σ of m_ij/m00"),
                                ("sigma_max", "s", "worst σ of m_ij/m00")):
        t = [r.duration_s for r in results]
        s = [r.sigma[param] for r in results]
        ax.plot(t, s, marker, ls="", ms=6, label=name)
        draw_front(ax, pareto_front(results, param), param)
    for r in results:
        ax.annotate(f"K={r.option.steps}", (r.duration_s, r.sigma["sigma_max"]),
                    textcoords="offset points", xytext=(4, 4), fontsize=7)
        if chosen is not None and r.option.steps == chosen:
            for param in ("sigma_mean", "sigma_max"):
                ax.plot(r.duration_s, r.sigma[param], "o", mfc="none", color="r", ms=13)
    ax.plot([], [], "k-", lw=1.0, label="Pareto front (predicted)")
    if chosen is not None:
        ax.plot([], [], "o", mfc="none", color="r", label=f"this plan ({chosen} steps)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("scan duration, engine estimate (s)")
    ax.set_ylabel("predicted σ of m_ij/m00 (dimensionless)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    bx.plot([r.option.steps for r in results], [r.kappa for r in results], "D-", color="C2")
    bx.set_xlabel("retarder steps per geometry K")
    bx.set_ylabel("condition number κ of W (dimensionless)")
    bx.grid(True, alpha=0.3)
    bx.set_ylim(0.0, 1.2 * max(r.kappa for r in results))
    fig.suptitle(title or "Dual rotating retarder: speed against accuracy", fontsize=10)
    try:
        fig.savefig(path, dpi=100)
    except OSError as err:
        raise OSError(f"could not write the trade-off picture {path} (is the folder "
                      f"writable?): {err}") from err
    finally:
        plt.close(fig)
    return path
