"""The error a plan that fails validation raises.

Its own module so that the plan file's parser (:mod:`instrument.plans.planfile`) and the
axes it expands (e.g. :mod:`instrument.plans.polarimetry`) both raise it without importing
each other.
"""

from __future__ import annotations

from instrument.bench.profile import ProfileError

__all__ = ["PlanError"]


class PlanError(ProfileError):
    """A plan file failed validation; ``errors`` lists every offending field."""
