"""The polarisation mounts' limits against the positions a polarimetric scan gives them
(shared by the dual-rotating-retarder and the PEM plans, so neither imports the other)."""

from __future__ import annotations

from instrument.bench.profile import BenchProfile, FieldError
from instrument.plans.errors import PlanError

__all__ = ["check_mount_limits"]


def check_mount_limits(profile: BenchProfile, targets: list[dict[str, float]]) -> None:
    """Every polarisation mount the scan turns is a device of the bench and holds each of
    its targets (degrees, by role) within its limits.

    Raises
    ------
    PlanError
        A mount that is not a device of the bench, or a target outside its limits; the
        field errors name ``devices.ROLE`` and what to give.
    """

    errors = []
    for role in dict.fromkeys(r for t in targets for r in t):
        spec = profile.devices.get(role)
        if spec is None:
            errors.append(FieldError(f"devices.{role}", "the optical train's mount is not a "
                                     "device of this bench"))
            continue
        values = [t[role] for t in targets if role in t]
        if spec.limits is not None and (min(values) < spec.limits[0]
                                        or max(values) > spec.limits[1]):
            errors.append(FieldError(f"devices.{role}.limits", f"the scan turns this mount "
                                     f"from {min(values):g}° to {max(values):g}°, outside "
                                     f"its limits {list(spec.limits)}: give it at least "
                                     "[0, 360]"))
    if errors:
        raise PlanError(f"bench {profile.name!r}", errors)
