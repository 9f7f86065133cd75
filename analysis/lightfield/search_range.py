"""Localisation over a depth range that grows until no object sits at its far edge.

An object beyond the searched depth range is not absent from the data: its rays still
reach the wall, and the fit puts its best guess on the range's far edge, where the
matched filter is cut off (an object at −600 mm searched to −400 mm came out at −400 mm,
its interval [−400, −276] excluding the truth; searched to −1000 mm, at −597 mm).  Such a
detection is recognised by its open far end (``Detection.depth_open``) and a best guess
within one inverse-depth resolution of the edge; the range is then extended (its far end
and step multiplied by ``factor``, the step because the depth blur grows as D²) and the
search repeated, at most ``max_widenings`` times.  What is still open after that is
reported open.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .field import LightField2D
from .localize import Detection, detect_objects

__all__ = ["at_far_edge", "detect_widening"]


def at_far_edge(det: Detection, z_far_mm: float) -> NDArray[np.bool_]:
    """Objects whose interval is open at the far end and whose depth lies within one
    inverse-depth resolution (``δz/D²``) of the searched range's far edge ``z_far_mm``."""
    out = np.zeros(det.count, dtype=bool)
    for k in range(det.count):
        z = float(det.positions_mm[k, 1])
        r = det.resolutions[k]
        tol = r.depth_mm / max(z * z, 1e-12)
        out[k] = bool(det.depth_open[k, 0]) and abs(1 / abs(z) - 1 / abs(z_far_mm)) <= tol
    return out


def detect_widening(
    lf_wall: LightField2D, *, z_mm: ArrayLike, factor: float = 2.0, max_widenings: int = 2,
    **options: Any,
) -> tuple[Detection, NDArray[np.float64]]:
    """:func:`.localize.detect_objects` on ``z_mm``, widened while an object sits at the far
    edge (module doc).  Returns the detection and the depth grid it was made on."""
    if not factor > 1.0:
        raise ValueError(f"factor {factor:g} must be > 1")
    zs = np.atleast_1d(np.asarray(z_mm, dtype=float))
    det = detect_objects(lf_wall, z_mm=zs, **options)
    for _ in range(max_widenings):
        if not at_far_edge(det, float(zs.min())).any():
            break
        step = (float(zs[1] - zs[0]) if zs.size > 1 else 1.0) * factor
        zs = np.arange(float(zs.min()) * factor, float(zs.max()) + 0.5 * step, step)
        det = detect_objects(lf_wall, z_mm=zs, **options)
    return det, zs
