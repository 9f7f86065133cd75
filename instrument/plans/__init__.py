"""Plans: plan files, point generators, point order and the typed commands they yield.

For scripts and notebooks, the builders of :mod:`instrument.plans.scripted` (one per plan
kind, the plan file's keys as keyword arguments) and :func:`load` are the public way in::

    from instrument import plans
    plan = plans.in_plane(theta_i=[20, 40], theta_r=range(-70, 81, 5), sample="grey paint")
"""

from instrument.plans.build import Plan, PlanEstimate, build_plan
from instrument.plans.commands import (
    Acquire,
    AcquisitionPolicy,
    Command,
    Move,
    PointDone,
    ScanPoint,
    SetLight,
)
from instrument.plans.planfile import KINDS, PlanError, PlanSpec, load_plan, parse_plan
from instrument.plans.scripted import (
    brdf_hemisphere,
    dark,
    flat_field,
    hemisphere,
    in_plane,
    lightfield,
    load,
    make,
    photon_transfer,
    reference,
    signature,
    sphere_capture,
)

__all__ = [
    "KINDS",
    "Acquire",
    "AcquisitionPolicy",
    "Command",
    "Move",
    "Plan",
    "PlanError",
    "PlanEstimate",
    "PlanSpec",
    "PointDone",
    "ScanPoint",
    "SetLight",
    "brdf_hemisphere",
    "build_plan",
    "dark",
    "flat_field",
    "hemisphere",
    "in_plane",
    "lightfield",
    "load",
    "load_plan",
    "make",
    "parse_plan",
    "photon_transfer",
    "reference",
    "signature",
    "sphere_capture",
]
