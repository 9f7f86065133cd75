"""Coverage pictures of a plan's sampled directions (PNG), drawn with matplotlib (Agg).

* In-plane plans (every receiver direction in the plane of incidence): one panel per
  incidence direction, the receiver angles on a signed θr axis in degrees (> 0 on the
  specular side of the normal, as in plan files), the specular direction and the incident
  beam marked. Incidence angles are never overlaid on one axis.
* Out-of-plane plans: one polar panel per incidence direction, seen from above the sample
  in an azimuthal-equidistant projection (radius θr in degrees, 90° at the rim; angle φr
  from +x, counter-clockwise, as in :mod:`instrument.bench.kinematics`), the incident
  direction and its specular direction marked.
* Plans without scattering angles (light field, calibration, sphere capture): the axis
  positions of each moved axis, with its unit.

matplotlib is imported when a picture is drawn, not when this module is imported.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from instrument.plans.build import Plan

__all__ = ["coverage_image", "write_coverage_png"]

#: A receiver direction this close to the plane of incidence (deg) counts as in-plane.
_PLANE_TOL_DEG = 0.5
#: More incidence directions than this are drawn on the first panels only (and said so).
_MAX_PANELS = 12
_DPI = 80
#: Linear axes measured in mm; every other axis role is a rotation in degrees.
_LINEAR_ROLES = ("camera_z",)


def _incidences(angled: Sequence[Any]) -> list[tuple[float, float, list[Any]]]:
    """(θi, φi, points) per incidence direction, in increasing θi then φi."""
    groups: dict[tuple[float, float], list[Any]] = {}
    for p in angled:
        a = p.angles
        key = (round(a.theta_i, 3), round(math.fmod(a.phi_i + 360.0, 360.0), 3))
        groups.setdefault(key, []).append(p)
    return [(ti, pi, pts) for (ti, pi), pts in sorted(groups.items())]


def _in_plane(angled: Sequence[Any]) -> bool:
    for p in angled:
        a = p.angles
        off = abs(math.sin(math.radians(a.theta_r)) * math.sin(math.radians(a.phi_r - a.phi_i)))
        if math.degrees(math.asin(min(off, 1.0))) > _PLANE_TOL_DEG:
            return False
    return True


def _signed_theta_r(p: Any) -> float:
    """θr signed as in plan files: > 0 on the far side of the normal from the source."""
    a = p.angles
    dphi = math.fmod(abs(a.phi_r - a.phi_i), 360.0)
    far = 90.0 < dphi < 270.0
    return cast(float, a.theta_r if far else -a.theta_r)  # p: a plan point, typed loosely


def _draw_in_plane(plt: Any, plan: Plan, groups: list[Any], title: str) -> Any:
    bistatic = plan.profile.geometry.min_bistatic_deg
    n = len(groups)
    fig, axes = plt.subplots(n, 1, figsize=(8.0, 1.2 + 1.15 * n), sharex=True, squeeze=False)
    for ax, (ti, pi, pts) in zip(axes[:, 0], groups, strict=True):
        s = np.array([_signed_theta_r(p) for p in pts])
        ax.axvspan(-ti - bistatic, -ti + bistatic, color="0.85", lw=0,
                   label=f"incident beam ± {bistatic:g}° (no detector)")
        ax.plot(s, np.zeros_like(s), "o", ms=4, color="tab:blue", label="detector direction")
        ax.axvline(ti, color="tab:red", lw=1.0, ls="--", label="specular direction")
        ax.axvline(0.0, color="0.5", lw=0.6, ls=":", label="sample normal")
        ax.set_yticks([])
        ax.set_ylim(-1, 1)
        ax.set_xlim(-90, 90)
        phi = f", φi = {pi:g}°" if pi else ""
        ax.set_ylabel(f"θi = {ti:g}°{phi}\n({len(pts)} pts)", rotation=0, ha="right",
                      va="center", fontsize=9)
        ax.grid(True, axis="x", alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=4, loc="lower center", bbox_to_anchor=(0.5, 1.02))
    axes[-1, 0].set_xlabel("signed receiver angle θr (deg; > 0 specular side of the normal)")
    fig.suptitle(title, fontsize=10)
    return fig


def _draw_hemisphere(plt: Any, groups: list[Any], title: str) -> Any:
    n = len(groups)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(max(4.2 * cols, 7.0), 4.2 * rows + 1.2),
                             subplot_kw={"projection": "polar"}, squeeze=False,
                             layout="constrained")
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    for ax, (ti, pi, pts) in zip(axes.flat, groups, strict=False):
        phi = np.radians([p.angles.phi_r for p in pts])
        theta = np.array([p.angles.theta_r for p in pts])
        ax.plot(phi, theta, "o", ms=3, color="tab:blue", label="detector direction")
        ax.plot([math.radians(pi)], [ti], "P", ms=10, color="tab:red",
                label="source direction")
        ax.plot([math.radians(pi + 180.0)], [ti], "x", ms=9, mew=2, color="tab:red",
                label="specular direction")
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60, 90])
        ax.set_yticklabels(["θr 30°", "60°", "90°"], fontsize=7)
        ax.set_title(f"θi = {ti:g}°, φi = {pi:g}° ({len(pts)} points)", fontsize=9)
        ax.tick_params(axis="x", labelsize=7)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, ncol=3, loc="outside lower center")
    fig.suptitle(title + "\nseen from above the sample: radius = receiver polar angle θr "
                 "(deg),\nangle = receiver azimuth φr (deg, from +x)", fontsize=9)
    return fig


def _draw_positions(plt: Any, plan: Plan, title: str) -> Any:
    t = plan.targets_array()
    roles = [r for k, r in enumerate(plan.axes) if np.any(~np.isnan(t[:, k]))]
    n = max(len(roles), 1)
    fig, axes = plt.subplots(n, 1, figsize=(8.0, 1.2 + 1.1 * n), squeeze=False)
    if not roles:
        axes[0, 0].text(0.5, 0.5, "no axis moves in this plan", ha="center", va="center")
        axes[0, 0].set_axis_off()
    for ax, role in zip(axes[:, 0], roles, strict=False):
        col = t[:, plan.axes.index(role)]
        col = col[~np.isnan(col)]
        ax.plot(col, np.zeros_like(col), "|", ms=14, color="tab:blue")
        ax.set_yticks([])
        unit = "mm" if role in _LINEAR_ROLES else "deg"
        ax.set_xlabel(f"{role} position ({unit}); {np.unique(col).size} distinct, "
                      f"{col.size} points")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def _figure(plan: Plan) -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    angled = [p for p in plan.points if p.angles is not None]
    title = f"{plan.spec.name}: {len(plan.points)} points"
    if not angled:
        return _draw_positions(plt, plan, title)
    groups = _incidences(angled)
    if len(groups) > _MAX_PANELS:
        title += f" (first {_MAX_PANELS} of {len(groups)} incidence directions shown)"
        groups = groups[:_MAX_PANELS]
    if _in_plane(angled):
        return _draw_in_plane(plt, plan, groups, title)
    return _draw_hemisphere(plt, groups, title)


def coverage_image(plan: Plan) -> np.ndarray:
    """The coverage picture as an array (uint8, shape (H, W, 3), OpenCV's BGR order)."""
    import matplotlib.pyplot as plt

    fig = _figure(plan)
    try:
        fig.set_dpi(_DPI)
        fig.canvas.draw()
        rgba = np.asarray(fig.canvas.buffer_rgba())
    finally:
        plt.close(fig)
    return np.ascontiguousarray(rgba[..., 2::-1])


def write_coverage_png(plan: Plan, path: str | Path) -> Path:
    """Write the coverage picture of ``plan`` to ``path`` (PNG; parent folders created).

    Raises
    ------
    OSError
        ``path`` does not end in ``.png`` or cannot be written.
    """
    import matplotlib.pyplot as plt

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise OSError(f"coverage picture {path}: the name must end in .png")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OSError(f"could not write the coverage picture {path}: {err}") from err
    fig = _figure(plan)
    try:
        fig.savefig(path, dpi=100, bbox_inches="tight")
    except OSError as err:
        raise OSError(f"could not write the coverage picture {path} (is the folder "
                      f"writable?): {err}") from err
    finally:
        plt.close(fig)
    return path
