"""Plans written in Python: one builder per plan kind, with the plan file's keys as
keyword arguments.

A builder writes the plan as TOML text and validates it with :func:`parse_plan`, exactly
as a plan file is read. A plan made in a script is therefore the same object, refused for
the same reasons in the same words (``scan.theta_r[3]: ...``), and stored in the run file
as the same text as a plan file that says the same thing: a run made from a notebook can
be re-run from the command line with the text its file holds.

The sections of a plan file map onto the arguments like this::

    [plan]        name=, order=
    [sample]      sample= (its name), description=
    [scan]        the kind's own keyword arguments (theta_i=, theta_r=, ...)
    [acquisition] acquisition={"mode": "auto", "exposure_us": 2000, ...}
    [calibration] calibration={"dark": "RUN", ...}
    [spectral]    spectral={"filters": [1, 2, 3], ...}

Sequences may be lists, tuples, ``range`` objects or NumPy arrays; a ``range`` is taken
as the list of values it yields (so ``range(-70, 81, 5)`` ends at 80, as Python's range
does, not at 81).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from instrument.plans.planfile import PlanSpec, load_plan, parse_plan

__all__ = ["brdf_hemisphere", "dark", "flat_field", "hemisphere", "in_plane", "lightfield",
           "load", "make", "photon_transfer", "reference", "signature", "sphere_capture",
           "to_toml", "toml_value"]


def load(path: str | Path) -> PlanSpec:
    """A plan file, read and validated (:func:`instrument.plans.load_plan`)."""
    return load_plan(path)


def make(kind: str, *, sample: str | None = None, description: str | None = None,
         name: str | None = None, order: str | None = None,
         acquisition: Mapping[str, Any] | None = None,
         calibration: Mapping[str, str] | None = None,
         spectral: Mapping[str, Any] | None = None, **scan: Any) -> PlanSpec:
    """A plan of any ``kind`` (:data:`instrument.plans.KINDS`); ``scan`` holds the
    ``[scan]`` keys. Arguments left as ``None`` are left out of the plan (its defaults
    apply).

    Raises
    ------
    PlanError
        Every field that fails validation, named as in a plan file (``scan.theta_i[1]``).
    TypeError
        A value that no plan file could hold (an object that is not a number, string,
        boolean, sequence or mapping).
    """
    tables: dict[str, dict[str, Any]] = {
        "plan": _present({"kind": kind, "name": name, "order": order}),
        "sample": _present({"name": sample, "description": description}),
        "scan": _present(scan),
        "acquisition": dict(acquisition or {}),
        "calibration": dict(calibration or {}),
        "spectral": dict(spectral or {}),
    }
    text = to_toml({k: v for k, v in tables.items() if v or k in ("plan", "scan")})
    return parse_plan(text, source=f"plans.{kind if isinstance(kind, str) else 'make'}(...)")


def in_plane(theta_i: Any = None, theta_r: Any = None, *, points: Any = None,
             specular: Mapping[str, float] | None = None, reciprocity: bool | None = None,
             lobe: Mapping[str, Any] | None = None, skip_beam_points: bool | None = None,
             **common: Any) -> PlanSpec:
    """An in-plane BRDF plan (``brdf_in_plane``): incidence angles ``theta_i`` (list, deg)
    and signed detector angles ``theta_r`` (deg; > 0 on the specular side of the normal),
    or explicit ``points = [[θi, θr], ...]``. ``specular = {"half_width_deg",
    "step_deg"}`` samples the mirror direction more finely; ``lobe = {...}`` makes it the
    first pass of a two-pass lobe plan (:mod:`instrument.plans.lobe`). ``common``: the
    arguments of :func:`make` (sample, acquisition, ...)."""
    return make("brdf_in_plane", theta_i=theta_i, theta_r=theta_r, points=points,
                specular=specular, reciprocity=reciprocity, lobe=lobe,
                skip_beam_points=skip_beam_points, **common)


def hemisphere(theta_i: Any = None, *, phi_i: Any = None, n_directions: int | None = None,
               theta_max_deg: float | None = None, specular: Mapping[str, Any] | None = None,
               reciprocity: bool | None = None, isotropic: bool | None = None,
               **common: Any) -> PlanSpec:
    """A hemispherical BRDF plan (``brdf_hemisphere``): ``n_directions`` cells of an
    equal-solid-angle grid up to ``theta_max_deg`` for each incidence (``theta_i`` ×
    ``phi_i``)."""
    return make("brdf_hemisphere", theta_i=theta_i, phi_i=phi_i, n_directions=n_directions,
                theta_max_deg=theta_max_deg, specular=specular, reciprocity=reciprocity,
                isotropic=isotropic, **common)


#: The plan kind's own name, for those who think in plan files.
brdf_hemisphere = hemisphere


def reference(theta_i: Any = None, theta_r: Any = None, *, reference_name: str | None = None,
              reflectance: Any = None, **kwargs: Any) -> PlanSpec:
    """A reference-standard run (``reference``): the in-plane keys plus the standard's
    ``reference_name`` and ``reflectance``."""
    return make("reference", theta_i=theta_i, theta_r=theta_r,
                reference_name=reference_name, reflectance=reflectance, **kwargs)


def signature(theta_i: Any = None, theta_r: Any = None, **kwargs: Any) -> PlanSpec:
    """An instrument-signature run (``signature``: no sample in the beam), in-plane keys."""
    return make("signature", theta_i=theta_i, theta_r=theta_r, **kwargs)


def lightfield(camera_z: Any = None, *, sample_theta: float | None = None,
               detector_theta: float | None = None, **common: Any) -> PlanSpec:
    """A light-field scan (``lightfield``): camera positions ``camera_z`` (mm) along the
    stage, with the sample and detector arms fixed."""
    return make("lightfield", camera_z=camera_z, sample_theta=sample_theta,
                detector_theta=detector_theta, **common)


def dark(exposures_us: Any = None, *, frames: int | None = None,
         positions: Mapping[str, float] | None = None, **common: Any) -> PlanSpec:
    """Dark frames (``dark``): ``frames`` per exposure in ``exposures_us``."""
    return make("dark", exposures_us=exposures_us, frames=frames, positions=positions,
                **common)


def flat_field(exposures_us: Any = None, *, frames: int | None = None,
               positions: Mapping[str, float] | None = None, **common: Any) -> PlanSpec:
    """Flat-field frames (``flat_field``): ``frames`` per exposure in ``exposures_us``."""
    return make("flat_field", exposures_us=exposures_us, frames=frames, positions=positions,
                **common)


def photon_transfer(exposures_us: Any = None, *, pairs: int | None = None,
                    dark: bool | None = None, **common: Any) -> PlanSpec:
    """A photon-transfer run (``photon_transfer``): ``pairs`` of frames at each exposure
    (a list, or ``{"start", "stop", "n", "log"}``), with a dark at each when ``dark``."""
    return make("photon_transfer", exposures_us=exposures_us, pairs=pairs, dark=dark,
                **common)


def sphere_capture(objects: Any = None, lighting_deg: Any = None, *,
                   selector: str | None = None, lighting_role: str | None = None,
                   **common: Any) -> PlanSpec:
    """Images of spheres under several lightings (``sphere_capture``): ``objects`` is a
    list of ``{"name", "station_deg", "known_brdf"}``."""
    return make("sphere_capture", objects=objects, lighting_deg=lighting_deg,
                selector=selector, lighting_role=lighting_role, **common)


# ------------------------------------------------------------------------------ TOML
def _present(d: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in d.items() if v is not None}


def to_toml(tables: Mapping[str, Mapping[str, Any]]) -> str:
    """``{section: {key: value}}`` as TOML text: one ``[section]`` per table, nested
    mappings as inline tables. Only what a plan file holds is written: numbers, strings,
    booleans, sequences and mappings of them."""
    lines: list[str] = []
    for section, body in tables.items():
        lines.append(f"[{_key(section)}]")
        lines.extend(f"{_key(k)} = {toml_value(v, f'{section}.{k}')}" for k, v in body.items())
        lines.append("")
    return "\n".join(lines)


def _key(k: Any) -> str:
    k = str(k)
    bare = k and all(c.isalnum() or c in "_-" for c in k) and k.isascii()
    return k if bare else _string(k)


def _string(s: str) -> str:
    """A TOML basic string: JSON's escapes are TOML's, and DEL, which JSON leaves
    as it is, must be escaped too."""
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def toml_value(v: Any, where: str = "value") -> str:
    """One TOML value (``where`` names it in a :class:`TypeError`)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if hasattr(v, "item") and getattr(v, "ndim", None) == 0:  # a NumPy scalar
        v = v.item()
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"  # written as such: validation names the field
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, Path):
        return _string(str(v))
    if isinstance(v, Mapping):
        inner = ", ".join(f"{_key(k)} = {toml_value(x, f'{where}.{k}')}" for k, x in v.items())
        return "{ " + inner + " }" if inner else "{}"
    if hasattr(v, "tolist"):  # a NumPy array
        v = v.tolist()
    if isinstance(v, Sequence):  # lists, tuples, ranges
        return "[" + ", ".join(toml_value(x, f"{where}[{j}]") for j, x in enumerate(v)) + "]"
    raise TypeError(f"{where}: a plan cannot hold {type(v).__name__} values; give a number, "
                    "string, boolean, list or dict")
