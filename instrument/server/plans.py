"""Plans sent to the server: validated completely before they enter the queue.

A plan arrives as TOML text. It is parsed and expanded for the server's bench (field
errors and guard violations refuse it), and every file it names — the calibration runs
of ``[calibration]`` and a lobe plan's ``first_pass`` — must resolve inside one of the
allowed folders (the runs folder, and any given with ``--allow``): a remote client may
not make the server read a file anywhere else on its disk.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from instrument.bench.guard import GuardError
from instrument.bench.profile import BenchProfile, FieldError, ProfileError
from instrument.plans import PlanSpec, build_plan, parse_plan

__all__ = ["PlanRefused", "check_plan", "named_files"]

#: The largest plan text accepted, in bytes (a plan of 10⁵ explicit points fits).
MAX_PLAN_BYTES = 4 << 20


@dataclass
class PlanRefused(ValueError):
    """The plan may not be queued; ``errors`` lists every reason (field: message)."""

    message: str
    errors: list[str]

    def __str__(self) -> str:
        return self.message + "".join(f"\n  - {e}" for e in self.errors)


def _looks_like_path(value: str) -> bool:
    return "/" in value or "\\" in value or value.endswith(".h5") or value.startswith("~")


def named_files(spec: PlanSpec) -> dict[str, str]:
    """The plan's fields that name files or runs (field path → value)."""
    out = {f"calibration.{k}": v for k, v in spec.calibration.items()}
    first = spec.scan.get("first_pass")
    if isinstance(first, str):
        out["scan.first_pass"] = first
    return out


def _outside(value: str, allowed: Sequence[Path]) -> bool:
    p = Path(value).expanduser()
    candidates = [p] if p.is_absolute() else [a / p for a in allowed]
    for c in candidates:
        resolved = c.resolve()
        if any(resolved == a or resolved.is_relative_to(a) for a in allowed):
            return False
    return True


def check_plan(text: str, profile: BenchProfile, allowed: Sequence[Path]) -> PlanSpec:
    """Parse, expand and check ``text``; return its spec.

    Raises
    ------
    PlanRefused
        Field errors, guard violations (of a two-pass lobe plan's first pass: the second
        pass is planned, and guarded, after it), or a named file outside the allowed
        folders.
    """
    if len(text.encode("utf-8", "surrogatepass")) > MAX_PLAN_BYTES:
        raise PlanRefused(f"plan text is over {MAX_PLAN_BYTES >> 20} MiB", ["plan: too large"])
    try:
        spec = parse_plan(text, source="plan")
    except ProfileError as err:
        raise PlanRefused("plan is not valid", [str(e) for e in err.errors]) from err
    allowed = [Path(a).resolve() for a in allowed]
    bad = [FieldError(field, f"{value!r} is outside the folders this server may read "
                      f"({', '.join(map(str, allowed))})")
           for field, value in named_files(spec).items()
           if _looks_like_path(value) and _outside(value, allowed)]
    if bad:
        raise PlanRefused("plan names files outside the allowed folders",
                          [str(e) for e in bad])
    try:
        build_plan(spec, profile)
    except GuardError as err:
        raise PlanRefused(f"the guard refuses points of plan {spec.name!r}",
                          [f"point {v.index}: {v.detail}" for v in err.violations[:20]]
                          ) from err
    except ProfileError as err:
        raise PlanRefused(f"plan {spec.name!r} does not fit bench {profile.name!r}",
                          [str(e) for e in err.errors]) from err
    except ValueError as err:
        raise PlanRefused(f"plan {spec.name!r} cannot be expanded", [str(err)]) from err
    return spec
