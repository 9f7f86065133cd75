"""The plan editor's form, without Qt: fields per plan kind, TOML in and out, validation.

A :class:`PlanForm` holds what the operator typed, field by field (``scan.theta_r`` →
``"-70 to 80 step 10"``). :meth:`PlanForm.to_toml` writes the plan file; validation is
the CLI's own — :func:`instrument.plans.planfile.parse_plan`, then
:func:`instrument.plans.build.build_plan` with the guard — and every problem is put next
to the field it names (:func:`field_for`); problems that name no field (the guard's
rejected points, unreachable angles) are listed for the whole plan.

Text syntax of the list fields, for people:

* numbers: ``20, 40, 60``; a range ``-70 to 80 step 10`` (or ``-70:80:10``), inclusive;
* photon-transfer exposures also ``10 to 100000 n 12 log`` (or ``linear``);
* axis positions: ``detector_theta = 40, sample_theta = 20``;
* detectors: ``camera, power_meter``;
* sphere objects, one per line: ``glossy, 0, phong s=80 ks=1`` (name, station in degrees,
  optionally a known BRDF: a model and its parameters).
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from analysis.brdf.registry import available_models, default_candidates
from instrument.bench.guard import GuardError
from instrument.bench.profile import AXIS_ROLES, BenchProfile
from instrument.plans.build import Plan, build_plan
from instrument.plans.commands import DARK_POLICIES, DETECTORS, MODES, AcquisitionPolicy
from instrument.plans.planfile import (
    KINDS,
    KNOWN_BRDF_MODELS,
    ORDERS,
    SPECTRAL_KINDS,
    SPECTRAL_ORDERS,
    SPHERE_ROLES,
    PlanError,
    PlanSpec,
    parse_plan,
)
from instrument.plans.polarimetry import DEFAULT_STEPS, MIN_STEPS, POLARIMETRY_KINDS

__all__ = ["LOBE_MODELS", "FieldSpec", "PlanForm", "Validation", "field_for", "fields_for",
           "parse_values"]

#: The lobe plan's first-pass model: "" (automatic: the fit's default candidates, the best
#: by information criterion), those candidates, then every registered model.
LOBE_MODELS = ("", *dict.fromkeys((*default_candidates(), *available_models())))

#: What each kind is called in the form's kind chooser.
KIND_TITLES = {
    "brdf_in_plane": "BRDF, in plane", "brdf_hemisphere": "BRDF, hemisphere",
    "lightfield": "light field", "sphere_capture": "sphere capture",
    "dark": "calibration: dark frames", "flat_field": "calibration: flat field",
    "photon_transfer": "calibration: photon transfer",
    "reference": "calibration: reference standard",
    "signature": "calibration: instrument signature",
}


@dataclass(frozen=True)
class FieldSpec:
    """One field of the form.

    ``kind``: ``text``, ``number``, ``integer``, ``bool``, ``choice``, ``values`` (list or
    range), ``list`` (list only), ``ptc_exposures``, ``positions``, ``detectors``,
    ``objects``. ``default`` is what a new form shows (``None``: empty, i.e. left to the
    plan's default). A ``bool`` is written only when it differs from ``absent``, the value
    the plan takes when the key is left out.
    """

    path: str
    label: str
    kind: str
    help: str = ""
    choices: tuple[str, ...] = ()
    default: Any = None
    absent: bool = False

    @property
    def section(self) -> str:
        return self.path.split(".", 1)[0]


def _f(path, label, kind, help="", choices=(), default=None, absent=None):
    if kind == "bool" and absent is None:
        absent = bool(default)
    return FieldSpec(path, label, kind, help, tuple(choices), default, bool(absent))


COMMON = [
    _f("plan.name", "plan name", "text", "a name for this plan, shown in the run browser"),
    _f("plan.order", "point order", "choice", "optimised: shortest travel time", ORDERS,
       "optimised"),
    _f("sample.name", "sample", "text", "required for sample scans"),
    _f("sample.description", "description", "text",
       "free text stored with the run (material, preparation, orientation)"),
]
_POL = AcquisitionPolicy()
ACQUISITION = [
    _f("acquisition.mode", "exposure", "choice", "fixed, or auto-exposure", MODES,
       _POL.mode),
    _f("acquisition.exposure_us", "exposure (µs)", "number", "fixed exposure, or the "
       "first one of auto", default=str(int(_POL.exposure_us))),
    _f("acquisition.min_exposure_us", "min exposure (µs)", "number",
       "auto: the shortest exposure it may choose, in µs"),
    _f("acquisition.max_exposure_us", "max exposure (µs)", "number",
       "auto: the longest exposure it may choose, in µs"),
    _f("acquisition.target_fraction", "target fraction", "number",
       "auto: the brightest pixel's target fraction of saturation"),
    _f("acquisition.hdr", "HDR brackets", "bool", "auto: keep saturated brackets",
       default=False),
    _f("acquisition.hdr_factor", "HDR factor", "number",
       "HDR: ratio between successive bracket exposures (e.g. 8)"),
    _f("acquisition.max_brackets", "max brackets", "integer",
       "HDR: most exposures taken at one point"),
    _f("acquisition.frames", "frames averaged", "integer",
       "frames averaged per exposure (noise falls as 1/√N)"),
    _f("acquisition.dark", "darks", "choice", "every detector with the light off: none, "
       "after every point, before every row of θi, or at the start", DARK_POLICIES,
       _POL.dark),
    _f("acquisition.detectors", "detectors", "detectors", ", ".join(DETECTORS),
       default="camera, power_meter"),
    _f("acquisition.readout_s", "readout (s)", "number", "per-frame overhead (estimates)"),
    _f("acquisition.spin_deg_s", "spin (°/s)", "number",
       "spin the sample about its normal to average a laser's speckle (a bench with a "
       "sample_spin stage; no HDR); empty: still"),
]
CALIBRATION = [
    _f(f"calibration.{k}", f"{k} run", "text",
       f"the {k} calibration: a run id or a run file (empty: none)") for k in
    ("dark", "reference", "signature", "flat")
]
SKIP_BEAM = _f("scan.skip_beam_points", "skip points in the beam", "bool",
               "leave out (and report) points with the detector in the beam", default=True,
               absent=False)
IN_PLANE = [
    _f("scan.theta_i", "θi (deg)", "values", "incidence angles", default="20, 40, 60"),
    _f("scan.theta_r", "θr (deg)", "values", "signed: > 0 specular side, < 0 source side",
       default="-70 to 80 step 10"),
    _f("scan.specular.half_width_deg", "specular half-width (deg)", "number",
       "extra points around specular"),
    _f("scan.specular.step_deg", "specular step (deg)", "number",
       "spacing of the extra points around specular, in degrees"),
    _f("scan.reciprocity", "drop reciprocal points", "bool",
       "leave out (θi, θr) when (θr, θi) is measured: Helmholtz reciprocity",
       default=False),
    SKIP_BEAM,
]
#: A two-pass lobe plan (``[scan] lobe``, ADR 0052): this plan is the coarse first pass.
LOBE = [
    _f("scan.lobe.points", "lobe: second-pass points", "integer",
       "placed by Fisher information after the first pass (empty: one pass)"),
    _f("scan.lobe.step_deg", "lobe: placement grid (deg)", "number",
       "second pass: the θr grid its points are chosen from, in degrees"),
    _f("scan.lobe.search_half_width_deg", "lobe: search half-width (deg)", "number",
       "first pass: extra points around specular"),
    _f("scan.lobe.search_step_deg", "lobe: search step (deg)", "number",
       "first pass: spacing of the search points around specular, in degrees"),
    _f("scan.lobe.prior", "lobe: model", "choice",
       "the BRDF model fitted to the first pass (automatic: the best of the default "
       "candidates)", LOBE_MODELS, ""),
    _f("scan.lobe.target", "lobe: target parameter", "text",
       "the parameter whose σ the second pass reduces"),
]
HEMISPHERE = [
    _f("scan.theta_i", "θi (deg)", "list", "incidence polar angles, in degrees", default="30"),
    _f("scan.phi_i", "φi (deg)", "list", "incidence azimuths, in degrees", default="0"),
    _f("scan.n_directions", "directions", "integer", "cells of equal solid angle",
       default="60"),
    _f("scan.theta_max_deg", "θr max (deg)", "number",
       "largest viewing polar angle, in degrees", default="70"),
    _f("scan.specular.half_width_deg", "specular half-width (deg)", "number",
       "extra rings of points within this angle of specular, in degrees"),
    _f("scan.specular.rings", "specular rings", "integer",
       "number of extra rings around specular"),
    _f("scan.specular.per_ring", "points per ring", "integer",
       "directions on each specular ring"),
    _f("scan.reciprocity", "drop reciprocal points", "bool",
       "leave out a direction pair when its reciprocal is measured", default=False),
    _f("scan.isotropic", "isotropic sample", "bool",
       "the BRDF does not change when the sample turns about its normal", default=True),
    SKIP_BEAM,
]
FRAMES_AT = [
    _f("scan.exposures_us", "exposures (µs)", "values",
       "camera exposures, in µs: list or range", default="100, 1000, 10000"),
    _f("scan.frames", "frames per exposure", "integer",
       "frames taken at each exposure", default="4"),
    _f("scan.positions", "axis positions", "positions", "role = value, …"),
]
SCAN_FIELDS: dict[str, list[FieldSpec]] = {
    "brdf_in_plane": [*IN_PLANE, *LOBE],
    "reference": [*IN_PLANE, _f("scan.reference_name", "standard", "text",
                     "the reference standard's name (e.g. Spectralon 99 %)"),
                  _f("scan.reflectance", "reflectance", "number",
                     "the standard's certified hemispherical reflectance, 0 to 1")],
    "signature": IN_PLANE,
    "brdf_hemisphere": HEMISPHERE,
    "lightfield": [
        _f("scan.camera_z", "camera_z (mm)", "values",
           "camera stage positions, in mm: list or range", default="0 to 20 step 1"),
        _f("scan.sample_theta", "sample_theta (deg)", "number",
           "sample rotation held during the scan, in degrees (empty: as it is)"),
        _f("scan.detector_theta", "detector_theta (deg)", "number",
           "detector arm angle held during the scan, in degrees (empty: as it is)"),
    ],
    "dark": FRAMES_AT,
    "flat_field": FRAMES_AT,
    "photon_transfer": [
        _f("scan.exposures_us", "exposures (µs)", "ptc_exposures",
           "list, range, or 'start to stop n N log'", default="10 to 100000 n 12 log"),
        _f("scan.pairs", "pairs per exposure", "integer",
           "frame pairs per exposure (their difference gives the noise)", default="2"),
        _f("scan.dark", "dark pairs", "bool",
           "also take pairs with the light off (dark offset and noise)", default=True),
        _f("scan.positions", "axis positions", "positions", "role = value, …"),
    ],
    "sphere_capture": [
        _f("scan.selector", "sample changer", "choice",
           "the axis that brings each sphere into place", choices=SPHERE_ROLES,
           default="sample_phi"),
        _f("scan.lighting_role", "lighting axis", "choice",
           "the axis that changes the lighting direction", choices=SPHERE_ROLES,
           default="source_theta"),
        _f("scan.lighting_deg", "lighting positions (deg)", "list",
           "positions of the lighting axis, in degrees", default="0, 90"),
        _f("scan.objects", "objects", "objects",
           "one per line: name, station_deg[, model p=v …]", default="sphere, 0"),
    ],
}


#: The wavelength axis of BRDF plans (``[spectral]``); no filters: one wavelength.
SPECTRAL = [
    _f("spectral.filters", "filters (wavelength axis)", "list",
       "filter-wheel slots, e.g. 1, 2, 3; empty: no wavelength axis"),
    _f("spectral.order", "filter order", "choice",
       "per_filter: every angle per filter; motion: back and forth", SPECTRAL_ORDERS,
       "per_filter"),
]


#: The polarimetry axis of BRDF plans (``[polarimetry]``, instrument.plans.polarimetry);
#: every field empty: no polarimetry.
POLARIMETRY = [
    _f("polarimetry.mode", "polarimetry", "choice",
       "drr: a dual rotating retarder scan at every geometry (the bench's [optics] names "
       "the retarders); pem: a photoelastic modulator read at 1f and 2f by the lock-in at "
       "fixed settings; none: no polarimetry", ("", "drr", "pem")),
    _f("polarimetry.steps", "retarder steps", "integer",
       f"drr: steps per geometry, at least {MIN_STEPS} (default {DEFAULT_STEPS})"),
    _f("polarimetry.ratio", "retarder ratio", "number",
       "drr: the analyser retarder turns this many times as far (default 5)"),
    _f("polarimetry.amplitude_waves", "PEM amplitude (waves)", "number",
       "pem: the modulator's peak retardation (default: the profile's setting)"),
    _f("polarimetry.generator_deg", "PEM source polariser (deg)", "list",
       "pem: the source polariser's settings (default 0, 45)"),
    _f("polarimetry.analyser_deg", "PEM analyser retarder (deg)", "list",
       "pem: the analyser retarder's settings (default -75, -37.5, 37.5, 75)"),
    _f("polarimetry.time_constants", "PEM settle (τ)", "number",
       "pem: lock-in time constants waited before each harmonic (default 15)"),
    _f("polarimetry.reads", "PEM snapshots", "integer",
       "pem: lock-in snapshots per harmonic (default 6)"),
]


def fields_for(kind: str) -> list[FieldSpec]:
    """Every field of a plan of ``kind``: common, scan, acquisition, calibration (and the
    wavelength and polarimetry axes where the kind takes them)."""
    spectral = SPECTRAL if kind in SPECTRAL_KINDS else []
    polarimetry = POLARIMETRY if kind in POLARIMETRY_KINDS else []
    return [_f("plan.kind", "kind", "choice", "what the plan measures", choices=KINDS,
               default=kind), *COMMON,
            *SCAN_FIELDS[kind], *ACQUISITION, *CALIBRATION, *spectral, *polarimetry]


# --------------------------------------------------------------------------- text → values
class _Bad(ValueError):
    """A field's text does not read as its kind."""


_RANGE = re.compile(r"^\s*(\S+)\s*(?:to|:)\s*(\S+)\s*(?:step|:)\s*(\S+)\s*$")
_PTC = re.compile(r"^\s*(\S+)\s+to\s+(\S+)\s+n\s+(\d+)(?:\s+(log|linear))?\s*$")


def _number(text: str) -> int | float:
    t = text.strip().replace("−", "-")
    try:
        return int(t)
    except ValueError:
        pass
    try:
        x = float(t)
    except ValueError:
        raise _Bad(f"{text.strip()!r} is not a number") from None
    if not math.isfinite(x):
        raise _Bad(f"{text.strip()!r} is not a finite number")
    return x


def _integer(text: str) -> int:
    x = _number(text)
    if not isinstance(x, int):
        raise _Bad(f"{text.strip()!r} is not a whole number")
    return x


def parse_values(text: str, *, allow_range: bool = True) -> list | dict:
    """``"20, 40"`` → ``[20, 40]``; ``"-70 to 80 step 10"`` → a range table."""
    m = _RANGE.match(text.replace("−", "-"))
    if m:
        if not allow_range:
            raise _Bad("a list of numbers is needed here (no range)")
        return {"start": _number(m[1]), "stop": _number(m[2]), "step": _number(m[3])}
    parts = [p for p in re.split(r"[,\s;]+", text.strip()) if p]
    if not parts:
        raise _Bad("no numbers")
    return [_number(p) for p in parts]


def _ptc_exposures(text: str) -> list | dict:
    m = _PTC.match(text)
    if m:
        return {"start": _number(m[1]), "stop": _number(m[2]), "n": int(m[3]),
                "log": m[4] != "linear"}
    return parse_values(text)


def _positions(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for part in [p for p in re.split(r"[,;\n]+", text) if p.strip()]:
        if "=" not in part:
            raise _Bad(f"{part.strip()!r}: write role = value")
        role, value = (s.strip() for s in part.split("=", 1))
        if role not in AXIS_ROLES:
            raise _Bad(f"{role!r} is not an axis role ({', '.join(AXIS_ROLES)})")
        out[role] = _number(value)
    return out


def _detectors(text: str) -> list[str]:
    names = [p for p in re.split(r"[,\s]+", text.strip()) if p]
    bad = [n for n in names if n not in DETECTORS]
    if bad or not names:
        raise _Bad(f"detectors are drawn from {', '.join(DETECTORS)}")
    return names


def _objects(text: str) -> list[dict[str, Any]]:
    out = []
    for k, line in enumerate(ln for ln in text.splitlines() if ln.strip()):
        parts = [p.strip() for p in line.split(",")]
        if len(parts) < 2:
            raise _Bad(f"line {k + 1}: write name, station_deg[, model p=v …]")
        obj: dict[str, Any] = {"name": parts[0], "station_deg": _number(parts[1])}
        if len(parts) > 2 and parts[2]:
            words = parts[2].split()
            if words[0] not in KNOWN_BRDF_MODELS:
                raise _Bad(f"line {k + 1}: model {words[0]!r} is not one of "
                           f"{', '.join(KNOWN_BRDF_MODELS)}")
            brdf: dict[str, Any] = {"model": words[0]}
            for w in words[1:]:
                if "=" not in w:
                    raise _Bad(f"line {k + 1}: {w!r}: write parameter=value")
                key, value = w.split("=", 1)
                brdf[key] = _number(value)
            obj["known_brdf"] = brdf
        out.append(obj)
    if not out:
        raise _Bad("at least one object")
    return out


def _to_value(spec: FieldSpec, raw: Any) -> Any:
    """The TOML value of a field, or ``None`` to leave it out."""
    if spec.kind == "bool":
        value = bool(raw)
        return None if value == spec.absent else value
    text = "" if raw is None else str(raw)
    if not text.strip():
        return None
    match spec.kind:
        case "text" | "choice":
            return text.strip()
        case "number":
            return _number(text)
        case "integer":
            return _integer(text)
        case "values":
            return parse_values(text)
        case "list":
            return parse_values(text, allow_range=False)
        case "ptc_exposures":
            return _ptc_exposures(text)
        case "positions":
            return _positions(text)
        case "detectors":
            return _detectors(text)
        case "objects":
            return _objects(text)
    raise ValueError(f"unknown field kind {spec.kind!r}")


# --------------------------------------------------------------------------- values → text
def _num_text(x: Any) -> str:
    if isinstance(x, bool):
        return str(x).lower()
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e15:
        return str(int(x)) if abs(x) >= 1 or x == 0 else repr(x)
    return repr(x) if isinstance(x, float) else str(x)


def _to_text(spec: FieldSpec, value: Any) -> Any:
    if spec.kind == "bool":
        return bool(value)
    match spec.kind:
        case "values" | "list" | "ptc_exposures":
            if isinstance(value, dict):
                if "n" in value:
                    return (f"{_num_text(value.get('start'))} to {_num_text(value.get('stop'))}"
                            f" n {value.get('n')} {'log' if value.get('log', True) else 'linear'}")
                return (f"{_num_text(value.get('start'))} to {_num_text(value.get('stop'))} "
                        f"step {_num_text(value.get('step'))}")
            if isinstance(value, list):
                return ", ".join(_num_text(v) for v in value)
        case "positions":
            if isinstance(value, dict):
                return ", ".join(f"{k} = {_num_text(v)}" for k, v in value.items())
        case "detectors":
            if isinstance(value, list):
                return ", ".join(map(str, value))
        case "objects":
            if isinstance(value, list):
                lines = []
                for o in value:
                    if not isinstance(o, dict):
                        return json.dumps(value)
                    line = f"{o.get('name', '')}, {_num_text(o.get('station_deg', ''))}"
                    b = o.get("known_brdf")
                    if isinstance(b, dict):
                        line += ", " + " ".join([str(b.get("model", ""))] + [
                            f"{k}={_num_text(v)}" for k, v in b.items() if k != "model"])
                    lines.append(line)
                return "\n".join(lines)
        case "number" | "integer":
            return _num_text(value)
    return "" if value is None else str(value)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        if v and all(isinstance(x, dict) for x in v):
            return "[\n" + "".join(f"  {_toml_value(x)},\n" for x in v) + "]"
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def _get(data: dict, path: str) -> Any:
    cur: Any = data
    for part in path.split("."):
        if not isinstance(cur, dict) or part not in cur:
            return None
        cur = cur[part]
    return cur


# --------------------------------------------------------------------------- errors → fields
def _components(path: str) -> list[str]:
    return [p for p in re.split(r"[.\[]", path.replace("]", "")) if p]


def field_for(error_path: str, paths: Iterable[str]) -> str | None:
    """The form field an error path belongs to: the longest field path that is a prefix
    of it (``scan.theta_r.step`` → ``scan.theta_r``, ``scan.objects[1].name`` →
    ``scan.objects``), else the first field inside it (``sample`` → ``sample.name``)."""
    parts = _components(error_path)
    best, best_len = None, 0
    paths = list(paths)
    for p in paths:
        pc = p.split(".")
        if len(pc) <= len(parts) and parts[:len(pc)] == pc and len(pc) > best_len:
            best, best_len = p, len(pc)
    if best is not None:
        return best
    if not parts or parts[0] in ("toml", "file"):
        return None
    if len(parts) == 1 and parts[0] == "scan":
        return None  # build errors about the whole scan (unreachable angles …)
    for p in paths:
        if p.split(".")[:len(parts)] == parts:
            return p
    return None


@dataclass
class Validation:
    """Problems by field path, problems of the whole plan, and the plan if there are none."""

    errors: dict[str, list[str]] = field(default_factory=dict)
    general: list[str] = field(default_factory=list)
    spec: PlanSpec | None = None
    plan: Plan | None = None

    @property
    def ok(self) -> bool:
        return not self.errors and not self.general and self.plan is not None

    def add(self, path: str | None, message: str) -> None:
        if path is None:
            self.general.append(message)
        else:
            self.errors.setdefault(path, []).append(message)

    def count(self) -> int:
        return sum(len(v) for v in self.errors.values()) + len(self.general)


class PlanForm:
    """What the operator typed in the plan editor, for one plan kind."""

    def __init__(self, kind: str = "brdf_in_plane") -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown plan kind {kind!r}")
        self.kind = kind
        self.values: dict[str, Any] = {}
        for spec in fields_for(kind):
            self.values[spec.path] = spec.default if spec.default is not None else (
                False if spec.kind == "bool" else "")
        self.values["plan.name"] = KIND_TITLES.get(kind, kind)
        self.values["plan.kind"] = kind

    def fields(self) -> list[FieldSpec]:
        return fields_for(self.kind)

    def set(self, path: str, value: Any) -> None:
        if path == "plan.kind" and value != self.kind:
            self.set_kind(str(value))
            return
        self.values[path] = value

    def get(self, path: str) -> Any:
        return self.values.get(path)

    def set_kind(self, kind: str) -> None:
        """Change the kind: the common, acquisition and calibration fields are kept, the
        scan fields start from the new kind's defaults."""
        keep = {k: v for k, v in self.values.items() if not k.startswith("scan.")
                and k != "plan.kind"}
        fresh = PlanForm(kind)
        self.kind = kind
        self.values = {**fresh.values, **{k: v for k, v in keep.items()
                                          if k in fresh.values and k != "plan.name"}}
        if keep.get("plan.name") and keep["plan.name"] not in KIND_TITLES.values():
            self.values["plan.name"] = keep["plan.name"]

    # TOML -------------------------------------------------------------------------
    @classmethod
    def from_toml(cls, text: str) -> PlanForm:
        """A form filled from a plan file's text.

        Raises
        ------
        PlanError
            The text is not TOML or names no known kind (it cannot fill a form).
        """
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            from instrument.bench.profile import FieldError

            raise PlanError("plan", [FieldError("toml", f"not valid TOML: {err}")]) from err
        kind = _get(data, "plan.kind")
        if kind not in KINDS:
            from instrument.bench.profile import FieldError

            raise PlanError("plan", [FieldError(
                "plan.kind", f"unknown kind {kind!r}; use one of {', '.join(KINDS)}")])
        form = cls(kind)
        for spec in form.fields():
            value = _get(data, spec.path)
            if value is None:
                form.values[spec.path] = spec.absent if spec.kind == "bool" else ""
            else:
                form.values[spec.path] = _to_text(spec, value)
        if _get(data, "plan.name") is None:
            form.values["plan.name"] = ""
        return form

    def to_data(self) -> tuple[dict[str, Any], dict[str, str]]:
        """(the plan as nested tables, field syntax errors by path)."""
        data: dict[str, Any] = {}
        errors: dict[str, str] = {}
        for spec in self.fields():
            try:
                value = _to_value(spec, self.values.get(spec.path))
            except _Bad as err:
                errors[spec.path] = str(err)
                continue
            if value is None:
                continue
            cur = data
            parts = spec.path.split(".")
            for part in parts[:-1]:
                cur = cur.setdefault(part, {})
            cur[parts[-1]] = value
        for section in ("plan", "sample", "scan"):
            data.setdefault(section, {})
        if not data["sample"]:
            del data["sample"]
        if "filters" not in data.get("spectral", {}):
            data.pop("spectral", None)  # an order alone is no wavelength axis
        if not data.get("polarimetry"):
            data.pop("polarimetry", None)
        return data, errors

    def to_toml(self) -> str:
        """The plan file (fields with syntax errors are left out; see :meth:`validate`)."""
        data, _ = self.to_data()
        lines = [f"# {KIND_TITLES.get(self.kind, self.kind)} plan, written by the "
                 "scatterlab plan editor"]
        for section in ("plan", "sample", "scan", "acquisition", "calibration", "spectral",
                        "polarimetry"):
            table = data.get(section)
            if not table and section not in ("plan", "scan"):
                continue
            lines.append("")
            lines.append(f"[{section}]")
            for key, value in (table or {}).items():
                lines.append(f"{_key(key)} = {_toml_value(value)}")
        return "\n".join(lines) + "\n"

    # validation -------------------------------------------------------------------
    def validate(self, profile: BenchProfile | None) -> Validation:
        """The CLI's validation of this plan (on ``profile``'s bench, when given)."""
        out = Validation()
        _, syntax = self.to_data()
        paths = [f.path for f in self.fields()]
        for path, message in syntax.items():
            out.add(path, message)
        if syntax:
            return out
        try:
            spec = parse_plan(self.to_toml(), source="the plan editor")
        except PlanError as err:
            for e in err.errors:
                out.add(*_placed(e, paths))
            return out
        out.spec = spec
        if profile is None:
            out.general.append("no bench chosen: the guard has not checked the points")
            return out
        try:
            out.plan = build_plan(spec, profile)
        except GuardError as err:
            for v in err.violations[:40]:
                out.general.append(str(v))
            if len(err.violations) > 40:
                out.general.append(f"… and {len(err.violations) - 40} more rejected points")
            hint = str(err).splitlines()[-1]
            if "every point is rejected" in hint:
                out.general.append(hint.strip())
        except PlanError as err:
            for e in err.errors:
                out.add(*_placed(e, paths))
        return out


def _placed(error, paths: list[str]) -> tuple[str | None, str]:
    """(field, message) of a validator's FieldError; the message names what part of the
    field it is about (``step: …`` for ``scan.theta_r.step``). A missing file section
    (all of its fields empty) is said in the form's words, not the file's ("table")."""
    target = field_for(error.path, paths)
    if error.message == "missing table" and target is not None:
        return target, "required for this kind of plan: fill it in"
    if target is None:
        return None, f"{error.path}: {error.message}"
    rest = error.path[len(target):].lstrip(".") if error.path.startswith(target) else ""
    return target, f"{rest}: {error.message}" if rest else error.message
