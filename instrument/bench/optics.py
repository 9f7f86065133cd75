"""The optical train of a polarimetric bench, as the profile's ``[optics]`` table names it.

A polarimeter has a polarisation-state generator (PSG) in the source arm and a
polarisation-state analyser (PSA) in the detector arm. Each arm is a list of elements in
the order the light meets them::

    [[optics.source]]                  # the PSG, from the source towards the sample
    kind = "polariser"                 # "polariser" | "retarder" | "pem"
    mount = "psg_polariser"            # the bench axis that turns it (a motion device)
    orientation_deg = 0.0              # nominal transmission / fast axis at mount 0
    extinction = 1e-5                  # polariser only: datasheet power extinction ratio
    source_dop = 0.98                  # PSG polariser only: the source's polarisation

    [[optics.source]]
    kind = "retarder"
    mount = "psg_retarder"
    orientation_deg = 0.0
    retardance_deg = 90.0              # nominal retardance: one number, or a table
    # retardance_deg = [92.0, 90.0, 88.5] with retardance_nm = [450.0, 550.0, 650.0]

    [[optics.detector]]                # the PSA, from the sample towards the detector
    ...

Orientation convention: angles in degrees, measured in the plane across the beam from
the plane of incidence (the lab x–z plane, "horizontal") towards the lab +y axis
("vertical"), for an observer looking against the light (towards the source). The
element's axis stands at ``orientation_deg + mount position``.

These are the **nominal** values: what the analysis is told. The emulated bench's hidden
truth (misalignments, retardance errors) lives in ``[simulation.optics]``
(``hw_mocks.sim.polarisation``) and is never read by the analysis.

A polariser's ``extinction`` is the power extinction ratio ε of its datasheet (the
transmittance of light polarised across its axis over that along it): about 10⁻⁵ for a
Glan–Taylor or Glan–Thompson prism, 10⁻³ to 10⁻⁴ for a film polariser. It must lie in
[0, 1); left out it is 0, an ideal polariser, which is what the reduction assumed before
the field existed (state the datasheet's value: at ε = 10⁻⁵ an ideal model biases the
calibration by a few of its σ, ADR 0108). The source arm's polariser may also take
``source_dop``, the degree of linear polarisation of the source along its axis (a laser
of polarisation ratio R:1 gives (R − 1)/(R + 1); 0, the default, for an unpolarised
source): a polarised source leaks through the generator less than its extinction says
(:func:`analysis.polarimetry.drr.generator_extinction`).

A photoelastic modulator (``kind = "pem"``) has a fixed orientation; its ``mount`` may be
left out. Its retardation amplitude is set on the modulator, not here.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

__all__ = ["ARMS", "ELEMENT_KINDS", "OpticalElement", "OpticalTrain", "parse_optics"]

#: Arm key → what it is (for messages).
ARMS = {"source": "source arm (PSG)", "detector": "detector arm (PSA)"}
ELEMENT_KINDS = ("polariser", "retarder", "pem")
_ELEMENT_KEYS = {"kind", "mount", "orientation_deg", "retardance_deg", "retardance_nm",
                 "extinction", "source_dop"}


@dataclass(frozen=True)
class OpticalElement:
    """One polarisation element as the profile names it (nominal values).

    ``retardance_deg`` holds one value (any wavelength) or values at
    ``retardance_nm``, interpolated linearly and constant beyond the ends.
    ``extinction`` is a polariser's power extinction ratio (0: ideal) and ``source_dop``
    the source's degree of polarisation along the generator polariser (module docstring).
    """

    kind: str
    mount: str | None
    orientation_deg: float
    retardance_deg: tuple[float, ...] = ()
    retardance_nm: tuple[float, ...] = ()
    extinction: float = 0.0
    source_dop: float = 0.0

    def retardance_at(self, wavelength_nm: float) -> float:
        """Nominal retardance (degrees) at ``wavelength_nm``; NaN for a polariser."""
        if not self.retardance_deg:
            return math.nan
        if len(self.retardance_deg) == 1:
            return self.retardance_deg[0]
        xs, ys = self.retardance_nm, self.retardance_deg
        if wavelength_nm <= xs[0]:
            return ys[0]
        if wavelength_nm >= xs[-1]:
            return ys[-1]
        for (x0, y0), (x1, y1) in itertools.pairwise(zip(xs, ys, strict=True)):
            if x0 <= wavelength_nm <= x1:
                return y0 + (y1 - y0) * (wavelength_nm - x0) / (x1 - x0)
        return ys[-1]  # unreachable: the table is increasing

    def as_dict(self) -> dict[str, Any]:
        """Plain data (run-file provenance)."""
        out: dict[str, Any] = {"kind": self.kind, "orientation_deg": self.orientation_deg}
        if self.mount is not None:
            out["mount"] = self.mount
        if self.retardance_deg:
            out["retardance_deg"] = list(self.retardance_deg)
        if self.retardance_nm:
            out["retardance_nm"] = list(self.retardance_nm)
        if self.kind == "polariser":
            out["extinction"] = self.extinction
            out["source_dop"] = self.source_dop
        return out


@dataclass(frozen=True)
class OpticalTrain:
    """The source-arm (PSG) and detector-arm (PSA) elements, each in beam order."""

    source: tuple[OpticalElement, ...]
    detector: tuple[OpticalElement, ...]

    def retarder(self, arm: str) -> OpticalElement | None:
        """The arm's (first) retarder, the element a dual-rotating-retarder scan turns."""
        return next((e for e in getattr(self, arm) if e.kind == "retarder"), None)

    @property
    def mounts(self) -> tuple[str, ...]:
        return tuple(e.mount for e in (*self.source, *self.detector) if e.mount is not None)

    def extinctions(self) -> dict[str, float]:
        """The polarisers' extinction the instrument matrix takes, as keyword arguments
        (``psg_extinction``, ``psa_extinction``): the generator's lowered by the source's
        own polarisation (:func:`analysis.polarimetry.drr.generator_extinction`), 0 for an
        arm without a polariser. What the planner's κ and σ use, as W and the calibration
        do."""
        from analysis.polarimetry.drr import generator_extinction

        gen = next((e for e in self.source if e.kind == "polariser"), None)
        ana = next((e for e in self.detector if e.kind == "polariser"), None)
        return {"psg_extinction": 0.0 if gen is None else generator_extinction(
                    gen.extinction, gen.source_dop),
                "psa_extinction": 0.0 if ana is None else ana.extinction}

    def as_dict(self) -> dict[str, Any]:
        return {"source": [e.as_dict() for e in self.source],
                "detector": [e.as_dict() for e in self.detector]}


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def parse_optics(t: Any, axes: set[str], error: Any) -> OpticalTrain | None:
    """Validate the ``[optics]`` table; ``axes`` are the profile's motion-device roles and
    ``error(path, message)`` records a field error. Returns None where anything failed
    (every problem is recorded, not only the first)."""
    if not isinstance(t, dict):
        error("optics", "must be a table with [[optics.source]] and [[optics.detector]] "
                        "arrays of elements")
        return None
    for key in t:
        if key not in ARMS:
            error(f"optics.{key}", f"unknown field; expected one of {', '.join(ARMS)}")
    failed = False
    arms: dict[str, tuple[OpticalElement, ...]] = {}
    used: dict[str, str] = {}
    for arm, what in ARMS.items():
        raw = t.get(arm, [])
        if not isinstance(raw, list):
            error(f"optics.{arm}", f"must be an array of tables ([[optics.{arm}]]), the "
                  f"{what} in beam order")
            failed = True
            continue
        elements = []
        for i, e in enumerate(raw):
            path = f"optics.{arm}[{i}]"
            element = _element(e, path, axes, error)
            if element is None:
                failed = True
                continue
            if element.mount is not None:
                if element.mount in used:
                    error(f"{path}.mount", f"{element.mount!r} already turns {used[element.mount]}"
                          "; each element needs its own mount")
                    failed = True
                used[element.mount] = path
            elements.append(element)
        arms[arm] = tuple(elements)
    if failed:
        return None
    if not arms.get("source") and not arms.get("detector"):
        error("optics", "names no element: give [[optics.source]] and/or "
                        "[[optics.detector]] tables")
        return None
    return OpticalTrain(arms.get("source", ()), arms.get("detector", ()))


def _element(e: Any, path: str, axes: set[str], error: Any) -> OpticalElement | None:
    if not isinstance(e, dict):
        error(path, "must be a table (kind, mount, orientation_deg, ...)")
        return None
    ok = True
    for key in e:
        if key not in _ELEMENT_KEYS:
            error(f"{path}.{key}", f"unknown field; expected one of "
                  f"{', '.join(sorted(_ELEMENT_KEYS))}")
            ok = False
    kind = e.get("kind")
    if kind not in ELEMENT_KINDS:
        error(f"{path}.kind", f"must be one of {', '.join(ELEMENT_KINDS)}, got {kind!r}")
        return None
    mount = e.get("mount")
    if mount is None:
        if kind != "pem":
            error(f"{path}.mount", f"a {kind} turns on a rotation mount: name its axis "
                  f"(a motion device of this profile: {', '.join(sorted(axes)) or 'none'})")
            ok = False
    elif not isinstance(mount, str) or mount not in axes:
        error(f"{path}.mount", f"{mount!r} is not a motion device of this profile; "
              f"give one of {', '.join(sorted(axes)) or 'none'}")
        ok = False
    orientation = e.get("orientation_deg", 0.0)
    if not (_number(orientation) and -180.0 <= orientation <= 180.0):
        error(f"{path}.orientation_deg", "must be a number of degrees in [-180, 180]")
        ok = False
    retardance: tuple[float, ...] = ()
    wavelengths: tuple[float, ...] = ()
    if kind == "retarder":
        retardance, wavelengths, good = _retardance(e, path, error)
        ok = ok and good
    else:
        for key in ("retardance_deg", "retardance_nm"):
            if key in e:
                error(f"{path}.{key}", f"only a retarder takes {key!r} (a {kind} has none "
                      "here)")
                ok = False
    extinction = e.get("extinction", 0.0)
    if kind != "polariser" and "extinction" in e:
        error(f"{path}.extinction", f"only a polariser takes 'extinction' (a {kind} has "
              "none here)")
        ok = False
    elif not (_number(extinction) and 0.0 <= extinction < 1.0):
        error(f"{path}.extinction", "must be the polariser's power extinction ratio in "
              "[0, 1) from its datasheet (e.g. 1e-5 for a Glan-Taylor prism, 1e-3 for a "
              f"film polariser; 0 for ideal), got {extinction!r}")
        ok = False
    source_dop = e.get("source_dop", 0.0)
    if "source_dop" in e and not (kind == "polariser" and path.startswith("optics.source")):
        error(f"{path}.source_dop", "only the source arm's polariser (the generator's) "
              "takes 'source_dop', the source's degree of polarisation along its axis")
        ok = False
    elif not (_number(source_dop) and 0.0 <= source_dop <= 1.0):
        error(f"{path}.source_dop", "must be the source's degree of linear polarisation "
              "along the polariser's axis in [0, 1] (a laser of polarisation ratio R:1: "
              f"(R - 1)/(R + 1); 0 for an unpolarised source), got {source_dop!r}")
        ok = False
    if not ok:
        return None
    return OpticalElement(str(kind), None if mount is None else str(mount), float(orientation),
                          retardance, wavelengths, float(extinction), float(source_dop))


def _retardance(e: dict[str, Any], path: str, error: Any
                ) -> tuple[tuple[float, ...], tuple[float, ...], bool]:
    raw = e.get("retardance_deg")
    nm = e.get("retardance_nm")
    if raw is None:
        error(f"{path}.retardance_deg", "a retarder needs its nominal retardance in degrees "
              "(one number, or a list with retardance_nm)")
        return (), (), False
    values = raw if isinstance(raw, list) else [raw]
    if not values or not all(_number(x) and 0.0 < x < 360.0 for x in values):
        error(f"{path}.retardance_deg", "must be degrees in (0, 360): one number or a "
              "non-empty list")
        return (), (), False
    if not isinstance(raw, list):
        if nm is not None:
            error(f"{path}.retardance_nm", "goes with a list of retardances only")
            return (), (), False
        return (float(raw),), (), True
    if (not isinstance(nm, list) or len(nm) != len(values)
            or not all(_number(x) and 100.0 <= x <= 25000.0 for x in nm)
            or any(b <= a for a, b in itertools.pairwise(nm))):
        error(f"{path}.retardance_nm", f"must list {len(values)} increasing wavelengths in "
              "nm (100 to 25000), one per retardance value")
        return (), (), False
    return tuple(float(x) for x in values), tuple(float(x) for x in nm), True
