"""Plans: plan files, point generators, point order and the typed commands they yield."""

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
    "build_plan",
    "load_plan",
    "parse_plan",
]
