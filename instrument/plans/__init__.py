"""Plans: plan files, point generators, point order and the typed commands they yield.

For scripts and notebooks, the builders of :mod:`instrument.plans.scripted` (one per plan
kind, the plan file's keys as keyword arguments) and :func:`load` are the public way in::

    from instrument import plans
    plan = plans.in_plane(theta_i=[20, 40], theta_r=range(-70, 81, 5), sample="grey paint")
"""

from typing import Any

from instrument.plans.adaptive import (
    AdaptivePlan,
    History,
    Measured,
    Proposal,
    Refused,
    register,
)
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
    "AdaptivePlan",
    "Command",
    "History",
    "Measured",
    "Move",
    "Plan",
    "PlanError",
    "PlanEstimate",
    "PlanSpec",
    "PointDone",
    "Proposal",
    "Refused",
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
    "register",
    "sharp_lobe",
    "signature",
    "sphere_capture",
]


def sharp_lobe(theta_i: float = 30.0, **options: Any) -> AdaptivePlan:
    """The sharp-lobe refinement, an adaptive plan
    (:class:`instrument.plans.adaptive_lobe.SharpLobe`: its options as keyword arguments):
    a coarse pass finds the specular peak,
    then batches of points go where the lobe fit's σ(α) drops most, until
    ``target_sigma_alpha`` or ``budget_s`` (estimated seconds) is reached."""
    from instrument.plans.adaptive_lobe import SharpLobe  # scipy: loaded when used

    return SharpLobe(theta_i, **options)
