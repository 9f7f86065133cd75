"""Plan files (TOML): parsing and field-level validation.

Like bench profiles, plan files are untrusted: :func:`parse_plan` reports *every* problem
as a :class:`~instrument.bench.profile.FieldError` (``scan.theta_i[2]: ...``) inside a
:class:`PlanError` and never raises anything else for bad input. Schema::

    [plan]
    kind = "brdf_in_plane"        # see KINDS
    name = "grey paint, in-plane"
    order = "optimised"           # "optimised" (travel-time) | "raster" (as generated)

    [sample]
    name = "RAL7040"              # required
    description = ""

    [scan]                        # kind-specific, see below
    ...

    [acquisition]                 # AcquisitionPolicy fields, all optional
    mode = "fixed"                # "fixed" | "auto"
    exposure_us = 10000
    frames = 1                    # frames averaged per point
    hdr = false
    dark = "none"                 # "none" | "per_point" | "start"
    detectors = ["camera", "power_meter"]
    dark_detectors = ["camera"]   # whose dark is read per point (default: all listed,
                                  # the camera alone when detectors is left out)

    [calibration]                 # run ids or file paths of calibration runs (optional)
    dark = "..."; reference = "..."; signature = "..."; flat = "..."; nd = "..."

    [polarimetry]                 # a Mueller-matrix scan at every geometry (optional;
    mode = "drr"                  # brdf_in_plane and brdf_hemisphere plans):
    steps = 36                    # instrument.plans.polarimetry
    ratio = 5                     # (mode = "pem": instrument.plans.polarimetry_pem)
                                  # (with a two-pass ``lobe``: both passes polarimetric,
                                  # instrument.pipelines.polarimetry.lobe, ADR 0106)

[scan] by kind (angles in degrees; a *range* is ``{start, stop, step}`` inclusive, or an
explicit list):

* ``brdf_in_plane`` / ``reference`` / ``signature``: ``theta_i`` (list), ``theta_r``
  (range; signed: > 0 on the specular side of the normal, < 0 on the source side),
  optional ``specular = {half_width_deg, step_deg}`` for extra sampling around the
  specular direction, ``reciprocity = true`` to drop reciprocity-equivalent points;
  or ``points = [[θi, θr], ...]`` (explicit signed pairs) instead of ``theta_i`` and
  ``theta_r``. ``lobe = {points = N, step_deg = 0.25, search_half_width_deg = 5,
  search_step_deg = 1, prior = "MODEL", target = "PARAM"}`` samples the lobe in two passes
  (:mod:`instrument.plans.lobe`): the plan itself is the coarse first pass (the θr grid and
  a search around the mirror direction); ``scatterlab run`` then fits it and runs a second
  plan of N points placed by Fisher information, which names its first pass in
  ``first_pass = "RUN"`` (the analysis reduces both runs together); a polarimetric lobe
  plan over several ``[spectral]`` filters fits the lobe at one of them, ``lobe.
  reference_filter = SLOT`` (default: the filter nearest the centre of the plan's band,
  :func:`instrument.pipelines.polarimetry.lobe.reference_filter`);
  ``reference`` also takes ``reference_name`` and ``reflectance``;
  ``skip_beam_points = true`` leaves out (and reports) the points whose detector would sit
  in the incident beam instead of rejecting the plan.
* ``brdf_hemisphere``: ``theta_i`` (list), ``phi_i`` (list, default [0]),
  ``n_directions`` (cells of the equal-solid-angle grid), ``theta_max_deg`` (≤ 89),
  optional ``specular = {half_width_deg, rings, per_ring}``, ``reciprocity``,
  ``isotropic`` (default true: only φr − φi matters for de-duplication).
* ``lightfield``: ``camera_z`` (range or list, mm), optional ``sample_theta`` and
  ``detector_theta`` (fixed, degrees).
* ``dark`` / ``flat_field``: ``exposures_us`` (list), ``frames`` (per exposure), optional
  fixed axis positions ``positions = {role = value}``.
* ``photon_transfer``: ``exposures_us`` (range or list) or ``{start, stop, n, log}``,
  ``pairs`` (frame pairs per exposure, default 2), ``dark = true`` (dark at each exposure).
* ``sphere_capture``: images of objects × lighting conditions. ``objects``
  (list of ``{name, station_deg, known_brdf}``: the sample-changer position of each sphere
  and, optionally, a BRDF known beforehand, ``{model = "phong", s, ks}``, ``{model =
  "lambertian", albedo}`` or ``{model = "mirror", reflectance}``, which lets the analysis
  estimate the lighting), ``lighting_deg`` (list: positions of the lighting axis, one per
  lighting condition), optional ``selector`` (the sample-changer axis, default
  ``sample_phi``) and ``lighting_role`` (default ``source_theta``: the goniometer moves
  the source/lighting).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from instrument.bench.profile import AXIS_ROLES, FieldError, _Validator
from instrument.plans.commands import DARK_POLICIES, DETECTORS, MODES, AcquisitionPolicy
from instrument.plans.errors import PlanError
from instrument.plans.polarimetry import parse_polarimetry
from instrument.plans.ranges import FloatRange

__all__ = ["KINDS", "PlanError", "PlanSpec", "load_plan", "parse_plan"]

#: The plan kinds a plan file may name (``[plan] kind``).
KINDS = ("brdf_in_plane", "brdf_hemisphere", "lightfield", "dark", "reference", "signature",
         "flat_field", "photon_transfer", "sphere_capture")
#: Rotary roles a sphere capture may use as the sample changer or the lighting axis.
SPHERE_ROLES = ("sample_theta", "sample_phi", "sample_tilt", "source_theta")
#: BRDF models a sphere-capture object may declare as known (lighting estimation).
KNOWN_BRDF_MODELS = ("phong", "lambertian", "mirror")
ORDERS = ("optimised", "raster")
#: The largest point count a plan may expand to (protects against typos like step=1e-6).
MAX_POINTS = 1_000_000


@dataclass(frozen=True)
class PlanSpec:
    kind: str
    name: str
    order: str
    sample_name: str
    sample_description: str
    scan: dict[str, Any]
    acquisition: AcquisitionPolicy
    calibration: dict[str, str] = field(default_factory=dict)
    source_text: str = ""
    #: ``[spectral]``: the wavelength axis, ``{"filters": (slots…), "order": …}`` (see
    #: :data:`SPECTRAL_ORDERS`), or None.
    spectral: dict[str, Any] | None = None
    #: ``[polarimetry]``: ``{"mode": "drr", "steps": K, "ratio": r}``
    #: (:mod:`instrument.plans.polarimetry`), PEM mode's table
    #: (:mod:`instrument.plans.polarimetry_pem`), or None.
    polarimetry: dict[str, Any] | None = None


def load_plan(path: str | Path) -> PlanSpec:
    """Read and validate a plan file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise PlanError(str(p), [FieldError("file", f"cannot read: {err}")]) from err
    return parse_plan(text, source=str(p))


def parse_plan(text: str, *, source: str = "plan") -> PlanSpec:
    """Validate TOML ``text`` into a :class:`PlanSpec` or raise :class:`PlanError`."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise PlanError(source, [FieldError("toml", f"not valid TOML: {err}")]) from err
    v = _Validator()
    v.unknown(data, "", {"plan", "sample", "scan", "acquisition", "calibration", "spectral",
                         "polarimetry"})
    plan = v.table(data, "plan", required=True)
    v.unknown(plan, "plan", {"kind", "name", "order"})
    kind = v.string(plan, "kind", "plan", required=True)
    if kind is not None and kind not in KINDS:
        v.error("plan.kind", f"unknown kind {kind!r}; use one of {', '.join(KINDS)}")
        kind = None
    name = v.string(plan, "name", "plan") or (kind or "plan")
    order = v.string(plan, "order", "plan") or "optimised"
    if order not in ORDERS:
        v.error("plan.order", f"must be one of {', '.join(ORDERS)}")
        order = "optimised"
    sample = v.table(data, "sample", required=kind not in (None, "dark", "signature",
                                                           "flat_field", "photon_transfer"))
    v.unknown(sample, "sample", {"name", "description"})
    sample_name = v.string(sample, "name", "sample",
                           required="sample" in data) or ("(none)" if not sample else "")
    sample_desc = v.string(sample, "description", "sample") or ""
    scan = v.table(data, "scan", required=True)
    if kind is not None:
        _SCAN_CHECKS[kind](v, scan, "scan")
    acq = _acquisition(v, v.table(data, "acquisition"), "acquisition")
    calib = v.table(data, "calibration")
    v.unknown(calib, "calibration", {"dark", "reference", "signature", "flat", "nd"})
    calibration = {}
    for key in list(calib):
        val = v.string(calib, key, "calibration")
        if val is not None:
            calibration[key] = val
    spectral = _spectral(v, data.get("spectral"), kind)
    polarimetry = parse_polarimetry(v, data.get("polarimetry"), kind)
    if isinstance(scan.get("lobe"), dict) and "reference_filter" in scan["lobe"]:
        _reference_filter(v, scan["lobe"], spectral, polarimetry)
    if v.errors or kind is None:
        raise PlanError(source, v.errors or [FieldError("plan.kind", "is required")])
    return PlanSpec(kind, name, order, sample_name, sample_desc, dict(scan), acq,
                    calibration, text, spectral, polarimetry)


#: Point orders of a wavelength axis: every angle with one filter, then the next filter
#: (``per_filter``); or the same, with the angles run forwards and backwards in turn so the
#: axes never travel back between filters (``motion``, cheaper by the motion model).
SPECTRAL_ORDERS = ("per_filter", "motion")
#: Plan kinds that take a wavelength axis.
SPECTRAL_KINDS = ("brdf_in_plane", "brdf_hemisphere", "reference")


def _spectral(v: _Validator, t: Any, kind: str | None) -> dict[str, Any] | None:
    """``[spectral] filters = [slots…]`` (1-based filter-wheel slots, each once, their
    wavelengths from the bench profile) and ``order``."""
    if t is None:
        return None
    if not isinstance(t, dict):
        v.error("spectral", "must be a table")
        return None
    v.unknown(t, "spectral", {"filters", "order"})
    if kind is not None and kind not in SPECTRAL_KINDS:
        v.error("spectral", f"a {kind} plan has no wavelength axis; only "
                f"{', '.join(SPECTRAL_KINDS)} plans take one")
    raw = t.get("filters")
    if (not isinstance(raw, list) or not raw
            or not all(isinstance(x, int) and not isinstance(x, bool) and 1 <= x <= 12
                       for x in raw)):
        v.error("spectral.filters", "must list filter-wheel slots, integers from 1 to 12")
        return None
    if len(set(raw)) != len(raw):
        v.error("spectral.filters", f"lists a slot twice: {raw}")
    order = t.get("order", "per_filter")
    if order not in SPECTRAL_ORDERS:
        v.error("spectral.order", f"must be one of {', '.join(SPECTRAL_ORDERS)}")
    return {"filters": tuple(raw), "order": order}


# --------------------------------------------------------------------------- helpers


def _num(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def number(v: _Validator, t: dict[str, Any], key: str, path: str, *, lo: float, hi: float,
           required: bool = False, integer: bool = False) -> float | None:
    """A number in [lo, hi] (an int if ``integer``), or None with an error recorded."""
    if key not in t:
        if required:
            v.error(f"{path}.{key}", "is required")
        return None
    x = t[key]
    if integer and (not isinstance(x, int) or isinstance(x, bool)):
        v.error(f"{path}.{key}", f"must be an integer from {lo:g} to {hi:g}, got {x!r}")
        return None
    if not _num(x) or not lo <= x <= hi:
        v.error(f"{path}.{key}", f"must be a number from {lo:g} to {hi:g}, got {x!r}")
        return None
    return cast(float, x)  # a number in range: checked above


def values(v: _Validator, t: dict[str, Any], key: str, path: str, *, lo: float, hi: float,
           required: bool = True, allow_range: bool = True) -> Sequence[float] | None:
    """An explicit list of numbers, or an inclusive range table {start, stop, step} (a
    lazy :class:`~instrument.plans.ranges.FloatRange`)."""
    where = f"{path}.{key}"
    if key not in t:
        if required:
            v.error(where, "is required")
        return None
    x = t[key]
    if isinstance(x, list):
        if not x:
            v.error(where, "must not be empty")
            return None
        bad = [i for i, e in enumerate(x) if not _num(e) or not lo <= e <= hi]
        for i in bad[:5]:
            v.error(f"{where}[{i}]", f"must be a number from {lo:g} to {hi:g}, got {x[i]!r}")
        return None if bad else [float(e) for e in x]
    if allow_range and isinstance(x, dict):
        v.unknown(x, where, {"start", "stop", "step"})
        start = number(v, x, "start", where, lo=lo, hi=hi, required=True)
        stop = number(v, x, "stop", where, lo=lo, hi=hi, required=True)
        step = number(v, x, "step", where, lo=1e-6, hi=hi - lo, required=True)
        if start is None or stop is None or step is None:
            return None
        if stop < start:
            v.error(where, f"stop ({stop:g}) must be >= start ({start:g})")
            return None
        values = FloatRange(start, stop, step)  # not expanded: it may be long
        if len(values) > MAX_POINTS:
            v.error(f"{where}.step", f"gives {len(values)} values; at most {MAX_POINTS}")
            return None
        return values
    v.error(where, "must be a list of numbers" + (" or {start, stop, step}" if allow_range
                                                 else ""))
    return None


def _boolean(v: _Validator, t: dict[str, Any], key: str, path: str) -> None:
    if key in t and not isinstance(t[key], bool):
        v.error(f"{path}.{key}", "must be true or false")


def _subtable(v: _Validator, t: dict[str, Any], key: str, path: str, keys: set[str],
              hint: str = "") -> dict[str, Any] | None:
    """``t[key]`` when it is a table of known ``keys`` (errors recorded), else None."""
    if key not in t:
        return None
    sub = t[key]
    if not isinstance(sub, dict):
        v.error(f"{path}.{key}", "must be a table" + (f" {hint}" if hint else ""))
        return None
    v.unknown(sub, f"{path}.{key}", keys)
    return sub


def _specular(v: _Validator, t: dict[str, Any], path: str, keys: set[str]) -> None:
    s = _subtable(v, t, "specular", path, keys)
    if s is None:
        return
    where = f"{path}.specular"
    number(v, s, "half_width_deg", where, lo=0.01, hi=45.0, required=True)
    if "step_deg" in keys:
        number(v, s, "step_deg", where, lo=0.01, hi=45.0, required=True)
    if "rings" in keys:
        number(v, s, "rings", where, lo=1, hi=50, integer=True)
        number(v, s, "per_ring", where, lo=3, hi=360, integer=True)


def _in_plane(v: _Validator, t: dict[str, Any], path: str) -> None:
    v.unknown(t, path, {"theta_i", "theta_r", "specular", "reciprocity", "reference_name",
                        "reflectance", "skip_beam_points", "points", "first_pass", "lobe"})
    _boolean(v, t, "skip_beam_points", path)
    explicit = "points" in t
    if explicit:
        _point_pairs(v, t, path)
        for key in ("theta_i", "theta_r", "specular", "lobe"):
            if key in t:
                v.error(f"{path}.{key}", "cannot be combined with an explicit points list")
    else:
        values(v, t, "theta_i", path, lo=-89.9, hi=89.9, allow_range=True)
        values(v, t, "theta_r", path, lo=-89.9, hi=89.9)
    _specular(v, t, path, {"half_width_deg", "step_deg"})
    _lobe(v, t, path)
    if "first_pass" in t:
        v.string(t, "first_pass", path)
    _boolean(v, t, "reciprocity", path)
    v.string(t, "reference_name", path)
    number(v, t, "reflectance", path, lo=0.0, hi=1.0)


def _point_pairs(v: _Validator, t: dict[str, Any], path: str) -> None:
    """``points = [[θi, θr], ...]``: explicit signed in-plane pairs (degrees)."""
    where = f"{path}.points"
    pts = t["points"]
    if not isinstance(pts, list) or not pts:
        v.error(where, "must be a non-empty list of [theta_i, theta_r] pairs (degrees)")
        return
    if len(pts) > MAX_POINTS:
        v.error(where, f"has {len(pts)} pairs; at most {MAX_POINTS}")
        return
    bad = [i for i, q in enumerate(pts)
           if not (isinstance(q, list) and len(q) == 2 and all(_num(x) for x in q)
                   and all(-89.9 <= x <= 89.9 for x in q))]
    for i in bad[:5]:
        v.error(f"{where}[{i}]", f"must be [theta_i, theta_r] with both in [-89.9, 89.9] "
                f"degrees, got {pts[i]!r}")


def _lobe(v: _Validator, t: dict[str, Any], path: str) -> None:
    """``lobe = {points, step_deg, search_half_width_deg, search_step_deg, prior}``: sample
    the lobe in two passes (:mod:`instrument.plans.lobe`)."""
    lb = _subtable(v, t, "lobe", path, {"points", "step_deg", "search_half_width_deg",
                                        "reference_filter",
                                        "search_step_deg", "prior", "target"},
                   "{points = N, ...}")
    if lb is None:
        return
    where = f"{path}.lobe"
    number(v, lb, "points", where, lo=1, hi=10000, integer=True, required=True)
    number(v, lb, "step_deg", where, lo=0.01, hi=10.0)
    number(v, lb, "search_half_width_deg", where, lo=0.5, hi=45.0)
    number(v, lb, "search_step_deg", where, lo=0.05, hi=10.0)
    v.string(lb, "prior", where)
    v.string(lb, "target", where)
    if "specular" in t:
        v.error(f"{path}.specular", "is replaced by lobe.search_half_width_deg and "
                "lobe.search_step_deg in a two-pass lobe plan")


def _reference_filter(v: _Validator, lobe: dict[str, Any], spectral: dict[str, Any] | None,
                      polarimetry: dict[str, Any] | None) -> None:
    """``lobe.reference_filter``: the ``[spectral]`` slot whose first-pass m00 the lobe of a
    polarimetric plan over several filters is fitted to
    (:mod:`instrument.pipelines.polarimetry.lobe`): one of the plan's filters."""
    where = "scan.lobe.reference_filter"
    slot = lobe["reference_filter"]
    if not isinstance(slot, int) or isinstance(slot, bool) or not 1 <= slot <= 12:
        v.error(where, f"must be a filter-wheel slot, an integer from 1 to 12, got {slot!r}")
    elif polarimetry is None or spectral is None:
        v.error(where, "chooses the wavelength a polarimetric lobe is fitted at: it needs "
                "[polarimetry] and [spectral] filters; leave it out otherwise")
    elif slot not in spectral["filters"]:
        v.error(where, f"slot {slot} is not one of the plan's [spectral] filters "
                f"{list(spectral['filters'])}: name one of them, or leave it out for the "
                "filter nearest the centre of the band")


def _hemisphere(v: _Validator, t: dict[str, Any], path: str) -> None:
    v.unknown(t, path, {"theta_i", "phi_i", "n_directions", "theta_max_deg", "specular",
                        "reciprocity", "isotropic", "skip_beam_points"})
    _boolean(v, t, "skip_beam_points", path)
    values(v, t, "theta_i", path, lo=0.0, hi=89.9)
    values(v, t, "phi_i", path, lo=-360.0, hi=360.0, required=False)
    number(v, t, "n_directions", path, lo=1, hi=100000, integer=True, required=True)
    number(v, t, "theta_max_deg", path, lo=1.0, hi=89.0)
    _specular(v, t, path, {"half_width_deg", "rings", "per_ring"})
    _boolean(v, t, "reciprocity", path)
    _boolean(v, t, "isotropic", path)


def _lightfield(v: _Validator, t: dict[str, Any], path: str) -> None:
    v.unknown(t, path, {"camera_z", "sample_theta", "detector_theta"})
    values(v, t, "camera_z", path, lo=-1000.0, hi=1000.0)
    number(v, t, "sample_theta", path, lo=-360.0, hi=360.0)
    number(v, t, "detector_theta", path, lo=-360.0, hi=360.0)


def _positions(v: _Validator, t: dict[str, Any], path: str) -> None:
    if "positions" not in t:
        return
    pos = t["positions"]
    if not isinstance(pos, dict):
        v.error(f"{path}.positions", "must be a table {role = value}")
        return
    for role, x in pos.items():
        if role not in AXIS_ROLES:
            v.error(f"{path}.positions.{role}", f"not an axis role: {', '.join(AXIS_ROLES)}")
        elif not _num(x):
            v.error(f"{path}.positions.{role}", "must be a finite number")


def _frames_at(v: _Validator, t: dict[str, Any], path: str) -> None:
    v.unknown(t, path, {"exposures_us", "frames", "positions"})
    values(v, t, "exposures_us", path, lo=1.0, hi=60e6)
    number(v, t, "frames", path, lo=1, hi=10000, integer=True)
    _positions(v, t, path)


def _ptc(v: _Validator, t: dict[str, Any], path: str) -> None:
    v.unknown(t, path, {"exposures_us", "pairs", "dark", "positions"})
    x = t.get("exposures_us")
    if isinstance(x, dict) and "n" in x:
        where = f"{path}.exposures_us"
        v.unknown(x, where, {"start", "stop", "n", "log"})
        start = number(v, x, "start", where, lo=1.0, hi=60e6, required=True)
        stop = number(v, x, "stop", where, lo=1.0, hi=60e6, required=True)
        number(v, x, "n", where, lo=2, hi=10000, integer=True, required=True)
        _boolean(v, x, "log", where)
        if start is not None and stop is not None and stop <= start:
            v.error(where, "stop must be greater than start")
    else:
        values(v, t, "exposures_us", path, lo=1.0, hi=60e6)
    number(v, t, "pairs", path, lo=1, hi=1000, integer=True)
    _boolean(v, t, "dark", path)
    _positions(v, t, path)


def _sphere_capture(v: _Validator, t: dict[str, Any], path: str) -> None:
    v.unknown(t, path, {"objects", "lighting_deg", "selector", "lighting_role"})
    roles = {}
    for key, default in (("selector", "sample_phi"), ("lighting_role", "source_theta")):
        role = v.string(t, key, path) or default
        if role not in SPHERE_ROLES:
            v.error(f"{path}.{key}", f"must be one of {', '.join(SPHERE_ROLES)}")
        roles[key] = role
    if roles["selector"] == roles["lighting_role"]:
        v.error(f"{path}.selector", "must differ from lighting_role")
    lights = values(v, t, "lighting_deg", path, lo=-360.0, hi=360.0, allow_range=False)
    if lights is not None and len(set(lights)) != len(lights):
        v.error(f"{path}.lighting_deg", "lighting positions must be distinct")
    objs = t.get("objects")
    where = f"{path}.objects"
    if not isinstance(objs, list) or not objs:
        v.error(where, "is required: a non-empty list of {name, station_deg} tables")
        return
    names, stations = [], []
    for k, o in enumerate(objs):
        w = f"{where}[{k}]"
        if not isinstance(o, dict):
            v.error(w, "must be a table {name, station_deg}")
            continue
        v.unknown(o, w, {"name", "station_deg", "known_brdf"})
        name = v.string(o, "name", w, required=True)
        station = number(v, o, "station_deg", w, lo=-360.0, hi=360.0, required=True)
        if name is not None:
            names.append(name)
        if station is not None:
            stations.append(station)
        if "known_brdf" in o:
            _known_brdf(v, o["known_brdf"], f"{w}.known_brdf")
    if len(set(names)) != len(names):
        v.error(where, "object names must be distinct")
    if len(set(stations)) != len(stations):
        v.error(where, "station_deg values must be distinct")


def _known_brdf(v: _Validator, b: Any, where: str) -> None:
    if not isinstance(b, dict):
        v.error(where, "must be a table {model = ...}")
        return
    model = v.string(b, "model", where, required=True)
    if model is not None and model not in KNOWN_BRDF_MODELS:
        v.error(f"{where}.model", f"must be one of {', '.join(KNOWN_BRDF_MODELS)}")
        return
    if model == "phong":
        v.unknown(b, where, {"model", "s", "ks"})
        number(v, b, "s", where, lo=0.1, hi=1e5, required=True)
        number(v, b, "ks", where, lo=0.0, hi=10.0)
    elif model == "lambertian":
        v.unknown(b, where, {"model", "albedo"})
        number(v, b, "albedo", where, lo=0.0, hi=1.0)
    elif model == "mirror":
        v.unknown(b, where, {"model", "reflectance"})
        number(v, b, "reflectance", where, lo=0.0, hi=1.0)


_SCAN_CHECKS = {
    "brdf_in_plane": _in_plane,
    "reference": _in_plane,
    "signature": _in_plane,
    "brdf_hemisphere": _hemisphere,
    "lightfield": _lightfield,
    "dark": _frames_at,
    "flat_field": _frames_at,
    "photon_transfer": _ptc,
    "sphere_capture": _sphere_capture,
}


def _dark_detectors(v: _Validator, t: dict[str, Any], path: str, detectors: tuple[str, ...]
                    ) -> tuple[str, ...] | None:
    """Which detectors read a dark at every point: the list given, else every detector the
    plan names; a plan that leaves ``detectors`` at its default measures with the camera,
    and the power meter read beside it takes no dark of its own (one reading saved per
    point)."""
    if "dark_detectors" in t:
        raw = t["dark_detectors"]
        if not isinstance(raw, list) or not all(isinstance(x, str) and x in detectors
                                                for x in raw):
            v.error(f"{path}.dark_detectors", "must be a list drawn from the plan's "
                    f"detectors ({', '.join(detectors)})")
            return None
        if "camera" in detectors and "camera" not in raw:
            v.error(f"{path}.dark_detectors", "must include the camera when the plan reads "
                    "it (its frames are reduced with their dark frames)")
            return None
        return tuple(dict.fromkeys(raw))
    if "detectors" not in t:
        return ("camera",)
    return None


def _acquisition(v: _Validator, t: dict[str, Any], path: str) -> AcquisitionPolicy:
    d = AcquisitionPolicy()
    v.unknown(t, path, set(d.__dataclass_fields__))
    mode = v.string(t, "mode", path) or d.mode
    if mode not in MODES:
        v.error(f"{path}.mode", f"must be one of {', '.join(MODES)}")
        mode = d.mode
    dark = v.string(t, "dark", path) or d.dark
    if dark not in DARK_POLICIES:
        v.error(f"{path}.dark", f"must be one of {', '.join(DARK_POLICIES)}")
        dark = d.dark
    exp = number(v, t, "exposure_us", path, lo=1.0, hi=60e6)
    emin = number(v, t, "min_exposure_us", path, lo=1.0, hi=60e6)
    emax = number(v, t, "max_exposure_us", path, lo=1.0, hi=60e6)
    target = number(v, t, "target_fraction", path, lo=0.05, hi=0.99)
    factor = number(v, t, "hdr_factor", path, lo=1.5, hi=1000.0)
    brackets = number(v, t, "max_brackets", path, lo=1, hi=16, integer=True)
    frames = number(v, t, "frames", path, lo=1, hi=10000, integer=True)
    readout = number(v, t, "readout_s", path, lo=0.0, hi=60.0)
    # a sample spinner's rate: up to 10 turns a second (a stage's limit is its own)
    spin = number(v, t, "spin_deg_s", path, lo=0.0, hi=3600.0)
    _boolean(v, t, "hdr", path)
    detectors = d.detectors
    if "detectors" in t:
        raw = t["detectors"]
        if (not isinstance(raw, list) or not raw
                or not all(isinstance(x, str) and x in DETECTORS for x in raw)):
            v.error(f"{path}.detectors", f"must be a non-empty list drawn from "
                    f"{', '.join(DETECTORS)}")
        else:
            detectors = tuple(dict.fromkeys(raw))
    dark_detectors = _dark_detectors(v, t, path, detectors)
    emin_v = emin if emin is not None else d.min_exposure_us
    emax_v = emax if emax is not None else d.max_exposure_us
    if emin_v > emax_v:
        v.error(f"{path}.min_exposure_us", "must not exceed max_exposure_us")
    if spin and t.get("hdr", d.hdr) is True:
        # each bracket sees other speckle patterns (the sample turns between frames);
        # merging them pixel by pixel keeps the long bracket where its pattern happens to
        # be dim (not saturated): a selection that biases the value low (ADR 0098)
        v.error(f"{path}.spin_deg_s", "a spinning sample cannot be bracketed: each HDR "
                "bracket sees other speckle patterns, and the per-pixel merge biases the "
                "value low; set hdr = false (frames = N averages without bias)")
    exp_v = exp if exp is not None else d.exposure_us
    if exp is not None and not emin_v <= exp_v <= emax_v:
        v.error(f"{path}.exposure_us", "must lie within [min_exposure_us, max_exposure_us]")
    return AcquisitionPolicy(
        mode=mode, exposure_us=float(exp_v), min_exposure_us=float(emin_v),
        max_exposure_us=float(emax_v),
        target_fraction=float(target if target is not None else d.target_fraction),
        hdr=bool(t.get("hdr", d.hdr)) if isinstance(t.get("hdr", d.hdr), bool) else d.hdr,
        hdr_factor=float(factor if factor is not None else d.hdr_factor),
        max_brackets=int(brackets if brackets is not None else d.max_brackets),
        frames=int(frames if frames is not None else d.frames),
        dark=dark, detectors=detectors, dark_detectors=dark_detectors,
        readout_s=float(readout if readout is not None else d.readout_s),
        spin_deg_s=float(spin if spin is not None else d.spin_deg_s),
    )
