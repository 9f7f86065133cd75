"""Light that reaches the wall from outside the solvable angles, and what it leaves behind.

The reconstruction recovers the incident field only inside the solvable domain [A, B].
An object close to the wall sends part of its fan in at angles beyond it (a disc 100 mm
before the wall reaches the wall's far edge at 30–52°; the solvable domain of the matte
paper ends at ±17°).  That light is in the measurement, but the reconstruction has no basis
for it: on a noise-free render (matte paper, a 3 mm disc at (−30, −100) mm) it comes back
in exactly the wall rows whose ray from the disc lies outside [A, B], up to three times the
disc's own in-domain peak, piled at the domain's edge and, through the few orders the
matte wall passes (p̂ = 4), spread over the whole row.  The point-source model has nothing
there, so the detector fitted it with further "objects" 70–150 mm away, 4–14σ each, on
four walls of the validation matrix; an 8σ one drew ≈ 0 of its evidence from the edge band
itself and all of it from those rows.

The rule (ADR 0032, amended), :func:`judged_on_clean_rows`: the rows where a stronger
reported object's ray lies outside [A, B] are not evidence for a weaker candidate.  Each
candidate, strongest first, is fitted jointly with the stronger reported ones on the other
rows only; if its significance there is below the threshold it is attributed to that light
— counted and named in a note, not reported.  A real second object keeps every row where
the stronger one's light is modelled (all of its fan, unless it lies in the stronger
one's outside rows); it is never dropped by position alone.  The stronger object is
reported as partly outside the measured angles.

Components on the line of sight of such an object (within its transverse blur) are one
object with it, not separate depths (:func:`line_of_sight`): its fan is cut by the domain
on one side, its depth rests on a one-sided aperture, and a disc of 3 mm at 100 mm spans
1.7°, more than the near-mirror walls' angular blur — the fit hung further point
components 8 mm before and behind it, 12–13σ each.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["judged_on_clean_rows", "line_of_sight", "outside_rows"]


def outside_rows(
    wall_mm: NDArray[Any], positions_mm: NDArray[Any], solvable_rad: tuple[float, float]
) -> NDArray[np.bool_]:
    """(R,) wall rows where the ray from any of ``positions_mm`` (K, 2) arrives outside
    the solvable domain ``solvable_rad``."""
    pos = np.asarray(positions_mm, dtype=float).reshape(-1, 2)
    c = np.asarray(wall_mm, dtype=float)
    t_star = np.arctan((c[None, :] - pos[:, :1]) / (-pos[:, 1:]))
    a, b = solvable_rad
    return ((t_star < a) | (t_star > b)).any(axis=0)


def judged_on_clean_rows(
    order: list[int], wall_mm: NDArray[Any], positions_mm: NDArray[Any],
    solvable_rad: tuple[float, float], threshold: float,
    significance_on: Callable[[NDArray[np.bool_], list[int]], NDArray[Any]],
) -> tuple[list[int], dict[int, list[tuple[int, float]]]]:
    """Split the candidates ``order`` (indices into ``positions_mm``, strongest first, all
    above the threshold on every row) into those reported and those attributed to a
    stronger one's light from outside the solvable angles (module doc).

    ``significance_on(rows, idx)`` returns the significances of the joint fit of the
    candidates ``idx`` on the wall ``rows`` only.  Returns the reported indices and, per
    source (the strongest reported object with outside rows), the attributed candidates
    with their significance on the clean rows.
    """
    pos = np.asarray(positions_mm, dtype=float).reshape(-1, 2)
    reported: list[int] = []
    attributed: dict[int, list[tuple[int, float]]] = {}
    for k in order:
        sources = [s for s in reported
                   if outside_rows(wall_mm, pos[s:s + 1], solvable_rad).any()]
        if sources:
            clean = ~outside_rows(wall_mm, pos[sources], solvable_rad)
            sig = (significance_on(clean, [*reported, k])[-1] if clean.any()
                   else -np.inf)
            if not sig >= threshold:
                attributed.setdefault(sources[0], []).append((k, float(sig)))
                continue
        reported.append(k)
    return reported, attributed


def line_of_sight(
    positions_mm: NDArray[Any], sources: list[int], blur_mm: Callable[[float], float]
) -> dict[int, list[int]]:
    """Per source index, the other candidates on its line of sight: within its transverse
    blur across (``blur_mm(z)`` at the source's depth), at any depth (module doc)."""
    pos = np.asarray(positions_mm, dtype=float).reshape(-1, 2)
    out: dict[int, list[int]] = {}
    taken: set[int] = set()
    for s in sources:
        if s in taken:
            continue
        taken.add(s)
        ys, zs = pos[s]
        for k in range(pos.shape[0]):
            if k not in taken and abs(pos[k, 0] - ys) <= blur_mm(zs):
                out.setdefault(s, []).append(k)
                taken.add(k)
    return out
