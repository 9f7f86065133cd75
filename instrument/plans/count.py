"""How many points a plan expands to, counted from its axes before any point is made.

A plan is refused over :data:`~instrument.plans.planfile.MAX_POINTS` points. Counting by
generating would first build every point (a plan of 10 × 10⁶ angles took 70 s and 5.8 GB
before the limit refused it, and ran out of memory under a smaller limit), so the count is
arithmetic on the plan's axes: the product of the lengths of the fields the generator
(:func:`instrument.plans.build.build_plan`) nests, per plan kind. Ranges are never
expanded here (:class:`~instrument.plans.ranges.FloatRange` knows its length).

Where the generator drops points the count cannot know without making them (reciprocity
de-duplication keeps at least half, since each point has one reciprocal; a specular search
adds up to its own width, less what coincides with the θr grid or lies below the horizon),
the count is a lower bound, so a plan is never refused for points it would not have.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from instrument.bench.profile import FieldError
from instrument.plans.grid import equal_solid_angle_count
from instrument.plans.planfile import MAX_POINTS, PlanError, PlanSpec
from instrument.plans.ranges import float_range

__all__ = ["PointCount", "check_point_count", "count_points"]


@dataclass(frozen=True)
class PointCount:
    """Points a plan expands to: ``n`` (a lower bound unless ``exact``), and the fields that
    multiply to it with their lengths, outermost first (``("scan.theta_i", 10)``)."""

    n: int
    factors: tuple[tuple[str, int], ...]
    exact: bool = True

    def words(self) -> str:
        """``scan.theta_i (10) × scan.theta_r (1000000)``."""
        return " × ".join(f"{name} ({k})" for name, k in self.factors)


def _length(x: Any) -> int:
    """Values in a list field or a range table (0 when absent)."""
    if isinstance(x, dict) and {"start", "stop", "step"} <= set(x):
        return len(float_range(x))
    if isinstance(x, dict) and "n" in x:  # photon transfer {start, stop, n, log}
        return int(x["n"])
    return len(x) if isinstance(x, list) else 0


def _distinct(x: Any) -> int:
    """Distinct values of a list or range field, as the in-plane generator keeps them
    (rounded to 10⁻⁹ degrees; a range's values are distinct: its step is ≥ 10⁻⁶)."""
    if isinstance(x, list):
        return len({round(float(e), 9) for e in x})
    return _length(x)


def count_points(spec: PlanSpec) -> PointCount:
    """How many points ``spec`` expands to (:class:`PointCount`), from its axes alone."""
    s, kind = spec.scan, spec.kind
    exact = True
    factors: list[tuple[str, int]]
    if kind in ("brdf_in_plane", "reference", "signature") and "points" in s:
        factors = [("scan.points", len(s["points"]))]
    elif kind in ("brdf_in_plane", "reference", "signature"):
        searched = "lobe" in s or "specular" in s
        # With a search around the mirror direction the θr values are made distinct and
        # the search adds some: at least the distinct θr values per θi (which is also
        # what reciprocity de-duplication keeps of a θr list that repeats a value).
        n_r = (_distinct(s["theta_r"]) if searched or s.get("reciprocity", False)
               else _length(s["theta_r"]))
        exact = not searched
        factors = [("scan.theta_i", _length(s["theta_i"])), ("scan.theta_r", n_r)]
    elif kind == "brdf_hemisphere":
        n_dir = equal_solid_angle_count(int(s["n_directions"]),
                                        float(s.get("theta_max_deg", 85.0)))
        exact = "specular" not in s
        factors = [("scan.theta_i", _length(s["theta_i"])),
                   ("scan.phi_i", _length(s.get("phi_i", [0.0]))),
                   ("scan.n_directions", n_dir)]
    elif kind == "lightfield":
        factors = [("scan.camera_z", _length(s["camera_z"]))]
    elif kind == "sphere_capture":
        factors = [("scan.lighting_deg", _length(s["lighting_deg"])),
                   ("scan.objects", len(s["objects"]))]
    elif kind in ("dark", "flat_field"):
        factors = [("scan.exposures_us", _length(s["exposures_us"])),
                   ("scan.frames", int(s.get("frames", 1)))]
    elif kind == "photon_transfer":
        per = 2 * int(s.get("pairs", 2)) + (2 if s.get("dark", True) else 0)
        factors = [("scan.exposures_us", _length(s["exposures_us"])),
                   ("frames per exposure", per)]
    else:  # parse_plan admits no other kind
        raise ValueError(f"unknown plan kind {kind!r}")
    if spec.spectral is not None:
        factors.append(("spectral.filters", len(spec.spectral["filters"])))
    n = math.prod(k for _, k in factors)
    if s.get("reciprocity", False) and "theta_i" in s:
        n, exact = _reciprocal_bound(s, factors), False
    if spec.acquisition.dark == "start" and kind not in ("dark", "photon_transfer"):
        n += 1
    return PointCount(n, tuple(factors), exact)


def _reciprocal_bound(s: dict[str, Any], factors: list[tuple[str, int]]) -> int:
    """At least this many points stay after reciprocity de-duplication.

    For one |θi| and one φi the generator's points have distinct keys, and a point is
    equivalent to itself and at most its reciprocal, so at least half of them stay; other
    φi (and θi of the other sign, its mirror) may all be equivalent to those.
    """
    x = s["theta_i"]
    n_abs = (len({round(abs(float(e)), 9) for e in x}) if isinstance(x, list)
             else -(-_length(x) // 2))  # a range holds each |θi| at most twice
    rest = math.prod(k for name, k in factors if name not in ("scan.theta_i", "scan.phi_i"))
    return -(-n_abs * rest // 2)


def check_point_count(spec: PlanSpec) -> PointCount:
    """The count of ``spec`` (:func:`count_points`); refuses a plan over the limit.

    Raises
    ------
    PlanError
        The plan expands to more than :data:`MAX_POINTS` points: the error names the
        fields that multiply to the count, the count and the limit.
    """
    count = count_points(spec)
    if count.n > MAX_POINTS:
        field = max(count.factors, key=lambda f: f[1])[0]
        at_least = "" if count.exact else "at least "
        raise PlanError(f"plan {spec.name!r}", [FieldError(
            field, f"the plan expands to {at_least}{count.n} points, {count.words()}; at "
            f"most {MAX_POINTS}: take a larger step or fewer values")])
    return count
