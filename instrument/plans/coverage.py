"""Coverage pictures of a plan's sampled directions (PNG), drawn with OpenCV.

Goniometer plans: the hemisphere of scattered directions seen from above, in an
azimuthal-equidistant projection (radius ∝ θr, 90° at the rim; φ measured from +x,
counter-clockwise, matching :mod:`instrument.bench.kinematics`). Blue dots are the detector
directions, red crosses the incident directions. Plans without angles (light field,
calibration) draw their axis positions as ticks on a line.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from instrument.plans.build import Plan

__all__ = ["coverage_image", "write_coverage_png"]

SIZE = 640


def coverage_image(plan: Plan) -> np.ndarray:
    """An RGB picture (uint8, shape (SIZE, SIZE, 3) in OpenCV's BGR order)."""
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    angled = [p for p in plan.points if p.angles is not None]
    title = f"{plan.spec.name}: {len(plan.points)} points"
    cv2.putText(img, title[:70], (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1,
                cv2.LINE_AA)
    if angled:
        c = SIZE // 2
        r_max = SIZE // 2 - 40
        for deg in (30, 60, 90):
            cv2.circle(img, (c, c + 10), int(r_max * deg / 90), (200, 200, 200), 1,
                       cv2.LINE_AA)
            cv2.putText(img, f"{deg}", (c + int(r_max * deg / 90) + 2, c + 6),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4, (120, 120, 120), 1, cv2.LINE_AA)
        cv2.line(img, (c - r_max, c + 10), (c + r_max, c + 10), (220, 220, 220), 1)
        cv2.line(img, (c, c + 10 - r_max), (c, c + 10 + r_max), (220, 220, 220), 1)

        def xy(theta: float, phi: float) -> tuple[int, int]:
            r = r_max * theta / 90.0
            return (round(c + r * math.cos(math.radians(phi))),
                    round(c + 10 - r * math.sin(math.radians(phi))))

        for p in angled:
            cv2.circle(img, xy(p.angles.theta_r, p.angles.phi_r), 3, (200, 80, 0), -1,
                       cv2.LINE_AA)
        for ti, pi in {(round(p.angles.theta_i, 6), round(p.angles.phi_i, 6)) for p in angled}:
            x, y = xy(ti, pi)
            cv2.drawMarker(img, (x, y), (0, 0, 220), cv2.MARKER_CROSS, 14, 2)
        cv2.putText(img, "detector (blue), source (red); radius = theta, phi from +x",
                    (10, SIZE - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
        return img
    t = plan.targets_array()
    for k, role in enumerate(plan.axes):
        col = t[:, k][~np.isnan(t[:, k])]
        if col.size == 0:
            continue
        y = 80 + 60 * k
        lo, hi = float(col.min()), float(col.max())
        span = hi - lo or 1.0
        cv2.line(img, (40, y), (SIZE - 40, y), (150, 150, 150), 1)
        for v in col:
            x = int(40 + (SIZE - 80) * (v - lo) / span)
            cv2.line(img, (x, y - 8), (x, y + 8), (200, 80, 0), 1)
        cv2.putText(img, f"{role}: {lo:g} .. {hi:g}", (40, y - 14), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def write_coverage_png(plan: Plan, path: str | Path) -> Path:
    """Write the coverage picture of ``plan`` to ``path`` (PNG; parent folders created).

    Raises
    ------
    OSError
        ``path`` does not end in ``.png`` or cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise OSError(f"coverage picture {path}: the name must end in .png")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        ok = cv2.imwrite(str(path), coverage_image(plan))
    except cv2.error as err:
        raise OSError(f"could not write the coverage picture {path}: {err}") from err
    if not ok:
        raise OSError(f"could not write the coverage picture {path} (is the folder writable?)")
    return path
