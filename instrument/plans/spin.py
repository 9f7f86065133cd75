"""Plans that spin the sample: the bench must have a spinner (ADR 0098)."""

from __future__ import annotations

from instrument.bench.profile import SPIN_ROLE, BenchProfile, FieldError
from instrument.plans.planfile import PlanError, PlanSpec

__all__ = ["check_spinner"]


def check_spinner(spec: PlanSpec, profile: BenchProfile) -> None:
    """Refuse a plan whose ``spin_deg_s`` the bench cannot give (PlanError)."""
    rate = spec.acquisition.spin_deg_s
    if rate <= 0.0:
        return
    where = f"plan {spec.name!r} on bench {profile.name!r}"
    device = profile.devices.get(SPIN_ROLE)
    if device is None or not device.is_axis:
        raise PlanError(where, [FieldError(
            "acquisition.spin_deg_s", f"the bench has no sample spinner: add a "
            f"continuous-rotation stage as [devices.{SPIN_ROLE}] to the profile, or remove "
            "spin_deg_s")])
